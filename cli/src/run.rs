//! `hinge run`: simulate a built-in scene with implicit Euler, writing OBJ frames and `summary.json`.
//!
//! Scenes are TOML ([`crate::scene`]); the built-in `drape` (after the paper's §7.1: a square cloth falls onto
//! a sphere; StVK membrane + tan bending with k from Eq. 11 + gravity + sphere contact; no damping) is the
//! default job.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock};
use std::time::Instant;

use clap::Args;
use hinge_core::TriMesh;
use hinge_core::anisotropy::Anisotropic;
use hinge_core::bending::{BendingModel, HessianMode, Method};
use hinge_core::energy::Plasticity;
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::error::{ElementNames, Num};
use hinge_core::meshio::{FileNumbering, MeshFormat, write_mesh};
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::HingePsi;
use hinge_energies::bending::{
    BuiltinBending, PsiConsumer, ViscousDamping, plate_consistent_stiffness,
    stiffness_from_material,
};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::drag::Drag;
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::MembraneModel;
use hinge_energies::motion::Motion;
use hinge_energies::pins::Pins;
use hinge_solver::linear::{
    ChebyshevJacobi, Dense, FaerLlt, FaerLu, LinearSolver, PcgJacobi, default_solver,
};

use crate::checkpoint::Checkpoint;
use crate::scene::Scene;
use hinge_solver::explicit::SymplecticEuler;
use hinge_solver::newton::{
    FrameStats, Globalization, ImplicitEuler, IterationReport, Newton, NewtonParams, NewtonStats,
    Observer, PinMotion, SolverError, SubstepPolicy,
};
use hinge_solver::ordering::FillOrdering;
use hinge_solver::statics::{
    continuation_scales, mean_edge_length, membrane_scales, minimize_continued,
};

/// Arguments of `hinge run`.
#[derive(Args, Default)]
pub struct RunArgs {
    /// Built-in scene name (`hinge scenes` lists them) or a scene TOML file.
    #[arg(default_value = "drape")]
    pub scene: String,
    /// Frames to simulate (default: the scene's; at most 6 000 000, and the frames written must fit on the
    /// output directory's disk).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Mesh resolution; what it means depends on the scene's mesh: for a grid, the cells along x (y scaled
    /// alike); for a scene with listed resolutions (the beams), a level 1, 2, 3, …; for an icosphere, the
    /// subdivision level 0–7 (default: the scene's).
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Worker threads (default: all logical CPUs; a larger count is clamped to them with a warning).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Output directory (default: out/NAME).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Do not write frames or pictures (summary only).
    #[arg(long)]
    pub no_frames: bool,
    /// Continue a time-stepped run from a checkpoint (the `checkpoint.txt` every run writes to its output
    /// directory when it ends, stops or fails: then it holds the last good frame). The frames after the
    /// checkpoint's, up to the scene's `frames` (or `--frames`), are written with their own numbers; with
    /// the scene unchanged they are bitwise those of the run that was not stopped. The scene may change
    /// (a smaller `dt`, a stiffer contact, more frames) as long as its mesh is the checkpoint's.
    #[arg(long, value_name = "FILE")]
    pub resume: Option<PathBuf>,
    /// Also write the checkpoint after every N-th frame (overwriting it), so that a run killed without
    /// Ctrl-C (a crash, a batch system's time limit) resumes from at most N frames back. Default: only
    /// when the run ends, stops or fails.
    #[arg(long, value_name = "N",
          value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=6_000_000))]
    pub checkpoint_every: Option<usize>,
    /// Frame file format: `obj` or `ply` (binary little endian).
    #[arg(long, value_enum, default_value_t = FrameFormat::Obj)]
    pub format: FrameFormat,
    /// Solve for the static equilibrium (Newton on the potential energy, no inertia or damping) instead of
    /// stepping frames; writes one frame, `static.obj` (or `.ply`).
    ///
    /// Frames: `frame_0000.obj` is the rest state, `frame_k.obj` the state after step k; beside them
    /// `animation.png` (an animated PNG of every k-th frame, at most 60), `final.png` (the last frame) and
    /// `obstacles.obj`. Ctrl-C ends the run after the current frame, writes `summary.json` with
    /// `"interrupted": true` and exits with code 130.
    #[arg(long = "static")]
    pub statics: bool,
    /// Print a line after every accepted Newton iteration (`  newton I: F = …, |grad F| = … N, |dx| = … m,
    /// alpha = …, shift = …`: the iteration, F, ‖∇F‖, the step, its length α, the diagonal shift): a frame's
    /// lines come before its frame line; with `--static` they replace the progress lines. Symplectic Euler
    /// has no Newton iterations to show.
    #[arg(long)]
    pub trace: bool,
}

/// The file format of written frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum FrameFormat {
    /// Wavefront OBJ (17 significant digits).
    #[default]
    Obj,
    /// Binary little-endian PLY (doubles).
    Ply,
}

impl FrameFormat {
    /// The mesh format it writes.
    pub fn mesh_format(self) -> MeshFormat {
        match self {
            FrameFormat::Obj => MeshFormat::Obj,
            FrameFormat::Ply => MeshFormat::Ply,
        }
    }
}

/// What a run produced.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// Frames simulated.
    pub frames: usize,
    /// Newton iterations, summed (with an interrupted run's abandoned frame: the work counters
    /// `newton_iterations`, `line_search_steps`, `factorizations`, `definite_iterations`,
    /// `accelerated_iterations` and the seconds
    /// count every iteration spent, `substeps` and the norms only the frames completed).
    pub newton_iterations: usize,
    /// Line-search trials after the first (halvings and extrapolation doublings), summed.
    pub line_search_steps: usize,
    /// Seconds in bending evaluation + assembly.
    pub bending_seconds: f64,
    /// Seconds in the other energies.
    pub other_energy_seconds: f64,
    /// Seconds in factorizations and solves.
    pub linear_solve_seconds: f64,
    /// Wall time of the whole run.
    pub total_seconds: f64,
    /// Smallest signed distance of a vertex to a sphere obstacle at the end (negative: inside).
    pub min_clearance: Option<f64>,
    /// Vertex count.
    pub n_vertices: usize,
    /// Mean drop (rest z − z) of the vertices at the largest rest x: a cantilever's tip deflection.
    pub far_end_drop: f64,
    /// Largest vertex speed at the end (0 for a static solve): how close a damped run is to equilibrium.
    pub max_speed: f64,
    /// ‖∇F‖ over the free degrees of freedom after the last Newton solve.
    pub final_gradient_norm: f64,
    /// Numeric factorizations attempted (failed shifted ones included), over every substep.
    pub factorizations: usize,
    /// Newton iterations that stepped with the definite Hessian (project on demand).
    pub definite_iterations: usize,
    /// Newton iterations whose step was corrected by geodesic acceleration.
    pub accelerated_iterations: usize,
    /// Accepted substeps (one per frame when no step failed).
    pub substeps: usize,
    /// The largest final ‖∇F‖ over all steps.
    pub max_final_gradient_norm: f64,
    /// The smallest accepted substep as a fraction of the frame's dt.
    pub smallest_substep_fraction: f64,
    /// The run was stopped (Ctrl-C) before its last frame; `frames` counts the frames completed.
    pub interrupted: bool,
    /// The largest accumulated plastic angle (rad) of a run with `[bending.plasticity]`.
    pub max_plastic_angle: Option<f64>,
    /// Newton iterations of each completed frame (its substeps and failed attempts summed; empty for a
    /// static solve).
    pub frame_newton_iterations: Vec<usize>,
    /// Factorizations of each completed frame.
    pub frame_factorizations: Vec<usize>,
    /// Accepted substeps of each completed frame (1 when it took none).
    pub frame_substeps: Vec<usize>,
}

impl RunSummary {
    /// Adds a solve's work counters and linear-solve seconds (not its norms).
    fn add_work(&mut self, stats: &NewtonStats) {
        self.newton_iterations += stats.iterations;
        self.line_search_steps += stats.line_search_steps;
        self.factorizations += stats.factorizations;
        self.definite_iterations += stats.definite_iterations;
        self.accelerated_iterations += stats.accelerated_iterations;
        self.linear_solve_seconds += stats.factor_seconds + stats.solve_seconds;
    }

    /// Adds the system's per-term evaluation times (taken, so they are counted once).
    fn add_timings(&mut self, system: &mut System) {
        for (name, sec) in system.take_timings() {
            if name == "bending" {
                self.bending_seconds += sec;
            } else {
                self.other_energy_seconds += sec;
            }
        }
    }
}

/// The system a scene simulates, with its masses, pins, solver and Newton parameters.
pub struct Built {
    /// Bending + membrane + gravity + contact.
    pub system: System,
    /// Lumped masses.
    pub masses: Vec<f64>,
    /// Pinned vertices.
    pub pins: Pins,
    /// The linear solver.
    pub solver: Box<dyn LinearSolver>,
    /// Newton parameters.
    pub params: NewtonParams,
    /// The obstacles at t = 0 with their motions (for the clearance report and the pictures).
    pub obstacles: Vec<(Obstacle, Option<Motion>)>,
    /// Rest hinges at least [`STIFF_REST`] times stiffer than flat, if any (a set-up warning, and the
    /// likely cause when a step then fails).
    pub stiff_rest: Option<StiffRest>,
    /// The membrane's model (`material.membrane`), whose stiffness a static solve's continuation scales.
    pub membrane: MembraneModel,
}

/// A rest stiffening `ψ″(θ̄) / ψ″(0)` ([`BendingModel::rest_stiffening`]) from which the scene gets a
/// set-up warning: a million, the tan energy's at |θ̄| = 3.09 rad (a crease folded to 3° of flat). The
/// public `cow` mesh has such hinges: its hardest frames take over 1 000 Newton iterations.
pub const STIFF_REST: f64 = 1e6;

/// The rest hinges a scene's bending makes at least [`STIFF_REST`] times stiffer than flat.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StiffRest {
    /// How many.
    pub count: usize,
    /// The stiffest one's vertices `[x0, x1, x2, x3]` (the edge x1–x2, 0-based in the mesh).
    pub vertices: [usize; 4],
    /// Its rest angle θ̄ (rad).
    pub theta_bar: f64,
    /// Its stiffening (∞ when ψ″(θ̄) is not finite).
    pub stiffening: f64,
}

impl StiffRest {
    /// The stiff rest hinges of `model`, if any.
    pub fn of<P: HingePsi>(model: &BendingModel<P>) -> Option<Self> {
        let ratios = model.rest_stiffening();
        let stiff = |r: &Option<f64>| r.is_some_and(|r| r >= STIFF_REST);
        let count = ratios.iter().filter(|r| stiff(r)).count();
        let (hinge, stiffening) = ratios
            .iter()
            .enumerate()
            .filter_map(|(i, r)| r.filter(|&r| r >= STIFF_REST).map(|r| (i, r)))
            .fold(None, |best: Option<(usize, f64)>, (i, r)| match best {
                Some((_, b)) if b >= r => best,
                _ => Some((i, r)),
            })?;
        Some(Self {
            count,
            vertices: model.topology().hinges().get(hinge)?.vertices,
            theta_bar: model.hinge_quantities(hinge)?.theta_bar,
            stiffening,
        })
    }

    /// One line naming the stiffest hinge by its vertices (with `names`, as the mesh file counts them).
    pub fn describe(&self, names: Option<&FileNumbering>) -> String {
        let v = |i: usize| names.map_or_else(|| i.to_string(), |n| n.vertex_number(i));
        format!(
            "{} rest {} at least {:.0e} times stiffer than flat, by ψ″(θ̄)/ψ″(0): the stiffest, {:.1e} times, is \
             the hinge on the edge between vertices {} and {} at θ̄ = {:.4} rad",
            self.count,
            if self.count == 1 {
                "hinge is"
            } else {
                "hinges are"
            },
            STIFF_REST,
            self.stiffening,
            v(self.vertices[1]),
            v(self.vertices[2]),
            self.theta_bar
        )
    }
}

/// Builds the energies of `scene` on `rest` (with the scene's viscous damping when `damped`).
///
/// # Errors
/// A one-line message naming the energy or key at fault.
pub fn build(scene: &Scene, rest: &TriMesh, damped: bool) -> Result<Built, String> {
    let n = rest.n_vertices();
    let m = &scene.material;
    let k = if scene.bending.calibration == "plate" {
        plate_consistent_stiffness(m.young, m.thickness, m.poisson)
    } else {
        stiffness_from_material(m.young, m.thickness, m.poisson)
    };
    // Each value may be in range while the stiffnesses they make (∝ Y·h³ and Y·h) underflow to zero or
    // to subnormals, or overflow: a shell without stiffness, not a scene to run.
    let membrane = m.young * m.thickness / (1.0 - m.poisson * m.poisson);
    for (what, v) in [("bending stiffness", k), ("membrane stiffness", membrane)] {
        if !(v.is_normal() && v > 0.0) {
            return Err(format!(
                "material: young {} and thickness {} make a {what} of {}, outside the positive normal f64 range",
                Num(m.young),
                Num(m.thickness),
                Num(v)
            ));
        }
    }
    let kd = if damped { scene.bending.damping } else { 0.0 };
    let factors = anisotropy_factors(scene, rest)?;
    let rest_angles = match &scene.bending.rest_angles {
        Some(path) => Some(read_rest_angles(
            &scene.base.as_deref().map_or(path.clone(), |b| b.join(path)),
        )?),
        None => None,
    };
    let f = HingeOptions {
        damping: kd,
        anisotropy: factors.as_deref(),
        rest_angles: rest_angles.as_deref(),
        plasticity: scene.bending.plasticity.as_ref().map(|p| Plasticity {
            yield_angle: p.yield_angle,
            hardening: p.hardening,
        }),
        hessian: scene.bending.hessian_mode()?,
    };
    let (bending, stiff_rest) = match scene.bending.energy.as_str() {
        "custom" => match scene.custom_psi(k)? {
            crate::scene::CustomPsi::Small(p) => bending_term(rest, p, f)?,
            crate::scene::CustomPsi::Large(p) => bending_term(rest, p, f)?,
        },
        other => {
            let builtin = other
                .parse::<BuiltinBending>()
                .map_err(|_| crate::scene::unknown_bending_energy(other))?;
            builtin.with_psi(k, BendingTermOf { rest, options: f })?
        }
    };
    let masses = lumped_masses(rest, m.density);
    let membrane = m.model()?;
    let mut terms: Vec<Box<dyn Energy>> = vec![
        bending,
        membrane
            .build(rest, m.young, m.poisson, m.thickness)
            .map_err(|e| e.to_string())?,
        Box::new(
            Gravity::new(masses.clone(), Vector3::from(scene.gravity))
                .map_err(|e| e.to_string())?,
        ),
    ];
    if damped && scene.drag > 0.0 {
        terms.push(Box::new(
            Drag::new(masses.clone(), scene.drag).map_err(|e| format!("drag: {e}"))?,
        ));
    }
    let mut obstacles = Vec::new();
    let motions = scene.obstacle_motions()?;
    for ((i, o), motion) in scene.obstacles.iter().enumerate().zip(motions) {
        let obstacle = match (o.center, o.radius, o.point, o.normal) {
            (Some(c), Some(r), _, _) => Obstacle::Sphere {
                center: Vector3::from(c),
                radius: r,
            },
            (_, _, Some(p), Some(nrm)) => Obstacle::Plane {
                point: Vector3::from(p),
                normal: Vector3::from(nrm),
            },
            _ => return Err(format!("obstacles[{i}]: incomplete")),
        };
        let mut contact = Contact::new(n, obstacle, o.stiffness, o.margin)
            .map_err(|e| format!("obstacles[{i}]: {e}"))?
            .with_smoothing(o.smoothing)
            .map_err(|e| format!("obstacles[{i}].smoothing: {e}"))?;
        match o.model.as_str() {
            "penalty" => {}
            "barrier" => {
                contact = contact
                    .with_barrier()
                    .map_err(|e| format!("obstacles[{i}].model: {e}"))?;
            }
            other => {
                return Err(format!(
                    "obstacles[{i}].model: unknown contact model {other:?} (penalty | barrier)"
                ));
            }
        }
        if let Some(m) = &motion {
            contact = contact
                .with_motion(m.clone())
                .map_err(|e| format!("obstacles[{i}].motion: {e}"))?;
        }
        // The contact normalises a plane's normal: keep its obstacle.
        obstacles.push((contact.obstacle(), motion));
        terms.push(Box::new(contact));
    }
    // Vertices of no face (kept by modelling tools) have no mass and no stiffness: held where they are.
    let mut pinned = scene.pinned(rest)?;
    pinned.extend(rest.unreferenced_vertices());
    let pins = Pins::new(n, pinned).map_err(|e| format!("pins: {e}"))?;
    let system = System::new(n, terms).map_err(|e| e.to_string())?;
    let params = NewtonParams {
        gradient_tolerance: scene.solver.gradient_tolerance,
        step_tolerance: 1e-9,
        max_iterations: scene.solver.max_iterations,
        globalization: Globalization::from_name(&scene.solver.globalization).unwrap_or_default(),
        relative_gradient_tolerance: scene.solver.relative_gradient_tolerance.unwrap_or(0.0),
        relative_step_tolerance: scene.solver.relative_step_tolerance.unwrap_or(0.0),
        length_scale: mean_edge_length(rest),
        extrapolate: scene.solver.extrapolate,
        remember_shift: scene.solver.remember_shift,
        geodesic_acceleration: scene.solver.geodesic_acceleration,
        definite_shift_ratio: scene.solver.definite_shift_ratio,
        definite_hold: scene.solver.definite_hold,
        ..NewtonParams::default()
    };
    let solver = linear_solver(scene);
    Ok(Built {
        system,
        masses,
        pins,
        solver,
        params,
        obstacles,
        stiff_rest,
        membrane,
    })
}

/// The mean drop of the vertices at the largest rest x (of the vertices in a face).
fn far_end_drop(rest: &TriMesh, x: &[Vector3<f64>]) -> f64 {
    let r = rest.positions();
    let used = rest.vertices_in_faces();
    let xmax = (0..r.len())
        .filter(|&v| used[v])
        .map(|v| r[v].x)
        .fold(f64::NEG_INFINITY, f64::max);
    let end: Vec<usize> = (0..r.len())
        .filter(|&v| used[v] && r[v].x >= xmax)
        .collect();
    end.iter().map(|&v| r[v].z - x[v].z).sum::<f64>() / end.len().max(1) as f64
}

/// The smallest signed distance of any vertex to a sphere obstacle (`None` when there is none): the summary's
/// `min_clearance_to_sphere`.
fn min_clearance(obstacles: &[Obstacle], x: &[Vector3<f64>]) -> Option<f64> {
    obstacles
        .iter()
        .filter(|o| matches!(o, Obstacle::Sphere { .. }))
        .map(|o| {
            x.iter()
                .map(|p| o.distance(p))
                .fold(f64::INFINITY, f64::min)
        })
        .reduce(f64::min)
}

/// Newton iteration budget of a static solve (at least; the scene's when larger).
pub const STATIC_ITERATIONS: usize = 2000;

/// The membrane parameter a static solve of `scene` scales, and the scales, ascending and below 1, it passes
/// through before the scene's own (membrane continuation: [`hinge_solver::statics`]; no scales: none):
/// `membrane.young` with [`hinge_solver::statics::membrane_scales`] for the StVK membrane, and
/// `corotational-membrane.stiffness` (k = Y h / (1 + ν), proportional to Y) or `neo-hookean-membrane.young`
/// with [`hinge_solver::statics::continuation_scales`] of the scene's Y and h for the co-rotational and
/// neo-Hookean ones ([`MembraneModel::stiffness_parameter`]); none when `solver.membrane_continuation` is
/// false.
///
/// # Errors
/// [`SolverError::Eval`] if the system cannot be evaluated at rest.
pub fn membrane_stages(
    scene: &Scene,
    model: MembraneModel,
    rest: &TriMesh,
    system: &mut System,
) -> Result<(&'static str, Vec<f64>), SolverError> {
    if !scene.solver.membrane_continuation {
        return Ok((model.stiffness_parameter(), Vec::new()));
    }
    let m = &scene.material;
    let parameter = model.stiffness_parameter();
    match model {
        MembraneModel::Corotational | MembraneModel::NeoHookean => {
            continuation_scales(system, rest, m.young, m.thickness)
        }
        MembraneModel::Stvk => membrane_scales(system, rest),
    }
    .map(|s| (parameter, s))
}

/// The one-line message of a static solve that failed: the solver's, with a hint when nothing can hold the
/// mesh still (`unsupported`: no pins, non-zero gravity) and the failure is one that explains.
fn static_failure(e: &SolverError, unsupported: bool, names: Option<&FileNumbering>) -> String {
    let hint = if unsupported
        && matches!(
            e,
            SolverError::NotConverged { .. }
                | SolverError::LineSearch { .. }
                | SolverError::Stalled { .. }
        ) {
        "; no vertex is pinned, so under gravity the mesh rests only where obstacles hold it \
         still (frictionless contact cannot hold it on a curved obstacle's side: it slides off)"
    } else {
        ""
    };
    format!("static solve: {}{hint}", solver_message(e, names))
}

/// Solves `scene` for its static equilibrium from the rest state (no inertia, no damping); writes
/// `static.obj` (or the output's format) and, when asked, its pictures to `out` when given.
///
/// With `names` (the rest mesh file's numbering), an evaluation error names its vertices and faces as the
/// file counts them. When `stop` is raised during the solve (Ctrl-C), the solve ends before its next Newton
/// iteration and the summary, marked [`RunSummary::interrupted`], counts the work done; nothing is written.
///
/// # Errors
/// A one-line message with the solver's diagnostics.
pub fn equilibrium(
    scene: &Scene,
    rest: &TriMesh,
    out: Option<Output<'_>>,
    stop: Option<&Arc<AtomicBool>>,
    names: Option<&FileNumbering>,
) -> Result<RunSummary, String> {
    equilibrium_observed(scene, rest, out, Hooks::new(stop, names))
}

/// [`equilibrium`] with [`Hooks`]: `stop` and `names` as there, the observer called after every accepted
/// Newton iteration of every continuation stage ([`Newton::set_observer`]; [`static_progress`] prints
/// progress lines from it), and the set-up warnings.
///
/// # Errors
/// As [`equilibrium`].
pub fn equilibrium_observed(
    scene: &Scene,
    rest: &TriMesh,
    out: Option<Output<'_>>,
    hooks: Hooks<'_>,
) -> Result<RunSummary, String> {
    let Hooks {
        stop,
        names,
        observer,
        mut warn,
        checkpoint: _,
        checkpoint_every: _,
        resume,
    } = hooks;
    if resume.is_some() {
        return Err(
            "--resume continues a time-stepped run; a static solve (--static) starts from rest"
                .into(),
        );
    }
    let start = Instant::now();
    let Built {
        mut system,
        pins,
        solver,
        params,
        obstacles,
        stiff_rest,
        membrane,
        ..
    } = build(scene, rest, false)?;
    warn_stiff_rest(
        stiff_rest.as_ref(),
        &scene.bending.energy,
        names,
        warn.as_deref_mut(),
    );
    // From the flat state, thin strips with a stiff membrane (membrane/bending stiffness ratio 12/h², about
    // 1e9 at h = 0.1 mm) take hundreds of damped Newton steps to swing down: statics gets a larger budget.
    let params = NewtonParams {
        max_iterations: params.max_iterations.max(STATIC_ITERATIONS),
        ..params
    };
    let mut newton = Newton::new(&system, &pins, solver, params).map_err(|e| e.to_string())?;
    newton.set_stop(stop.cloned());
    newton.set_observer(observer);
    let mut x = rest.positions().to_vec();
    check_initial_state(&mut system, &x, names)?;
    // After the check: a state the energies refuse is the one line, without a warning before it.
    let mut watch = ContactWatch::start(
        scene,
        &obstacles,
        rest,
        (rest.positions(), 0.0, &[]),
        names,
        warn.as_deref_mut(),
    );
    let (parameter, stages) = membrane_stages(scene, membrane, rest, &mut system)
        .map_err(|e| format!("static solve: {}", solver_message(&e, names)))?;
    let unsupported = pins.vertices().is_empty() && scene.gravity.iter().any(|g| *g != 0.0);
    let (stats, interrupted) =
        match minimize_continued(&mut newton, &mut system, &mut x, parameter, &stages) {
            Ok(stats) => (stats, false),
            // Stopped on request: the summary says so, and no equilibrium is written (`x` is the start).
            Err(SolverError::Interrupted { stats }) => (*stats, true),
            Err(e) => {
                return Err(with_stiff_rest(
                    static_failure(&e, unsupported, names),
                    stiff_rest.as_ref(),
                    &scene.bending.energy,
                    names,
                ));
            }
        };
    if !interrupted {
        watch.check(&obstacles, 0.0, (&x, &[]), None, warn.as_deref_mut());
    }
    let mut summary = RunSummary {
        frames: 0,
        newton_iterations: 0,
        line_search_steps: 0,
        bending_seconds: 0.0,
        other_energy_seconds: 0.0,
        linear_solve_seconds: 0.0,
        total_seconds: 0.0,
        min_clearance: min_clearance(&obstacles_at(&obstacles, 0.0), &x),
        n_vertices: rest.n_vertices(),
        far_end_drop: far_end_drop(rest, &x),
        max_speed: 0.0,
        final_gradient_norm: stats.gradient_norms.last().copied().unwrap_or(f64::NAN),
        factorizations: 0,
        definite_iterations: 0,
        accelerated_iterations: 0,
        substeps: 0,
        max_final_gradient_norm: stats.gradient_norms.last().copied().unwrap_or(f64::NAN),
        smallest_substep_fraction: 1.0,
        interrupted,
        max_plastic_angle: None,
        frame_newton_iterations: Vec::new(),
        frame_factorizations: Vec::new(),
        frame_substeps: Vec::new(),
    };
    summary.add_work(&stats);
    summary.add_timings(&mut system);
    if let Some(o) = out.filter(|_| !interrupted) {
        let name = format!("static.{}", o.format.extension());
        write_mesh(o.dir.join(name), &x, rest.triangles()).map_err(|e| e.to_string())?;
        if o.pictures {
            write_pictures(
                o.dir,
                &obstacles,
                std::slice::from_ref(&x),
                &[0.0],
                rest.triangles(),
                1.0,
            )?;
        }
    }
    summary.total_seconds = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// The obstacles where they are at time `t` (moving ones along their motion).
pub fn obstacles_at(obstacles: &[(Obstacle, Option<Motion>)], t: f64) -> Vec<Obstacle> {
    obstacles
        .iter()
        .map(|(o, m)| m.as_ref().map_or(*o, |m| Contact::moved(o, m, t)))
        .collect()
}

/// Writes `animation.png` (the sampled frames, each shown for `seconds` of simulated time, looping),
/// `final.png` (the last sample) and `obstacles.obj` (the obstacles at t = 0) to `dir`. `times` are the
/// samples' times: moving obstacles are drawn where they are then.
///
/// # Errors
/// A one-line message naming the file.
pub fn write_pictures(
    dir: &std::path::Path,
    obstacles: &[(Obstacle, Option<Motion>)],
    samples: &[Vec<Vector3<f64>>],
    times: &[f64],
    triangles: &[[usize; 3]],
    seconds: f64,
) -> Result<(), String> {
    let scene_box = crate::view::scene_box(samples);
    // Meshed once for fixed obstacles, once per picture for moving ones.
    let at_rest = crate::view::obstacle_meshes(&obstacles_at(obstacles, 0.0), scene_box)?;
    let meshes = if obstacles.iter().any(|(_, m)| m.is_some()) {
        times
            .iter()
            .map(|&t| crate::view::obstacle_meshes(&obstacles_at(obstacles, t), scene_box))
            .collect::<Result<Vec<_>, _>>()?
    } else {
        vec![at_rest.clone()]
    };
    let pictures = crate::view::render(samples, triangles, &meshes);
    let Some(last) = pictures.last() else {
        return Ok(());
    };
    // Real time, but at least 40 ms per picture (a browser's floor is about 20 ms).
    let delay = (seconds * 1e3).round().clamp(40.0, 2000.0) as u16;
    crate::view::write_apng(&dir.join("animation.png"), &pictures, delay)?;
    crate::view::write_png(&dir.join("final.png"), last)?;
    crate::view::write_obstacles(&dir.join("obstacles.obj"), &at_rest)
}

/// The per-hinge factors of `[bending.anisotropy]` (none when the scene has no such table).
///
/// # Errors
/// A one-line message naming the key, hinge or triangle.
pub fn anisotropy_factors(scene: &Scene, rest: &TriMesh) -> Result<Option<Vec<f64>>, String> {
    use hinge_core::anisotropy::{Anisotropy, MaterialDirection};
    let Some(spec) = &scene.bending.anisotropy else {
        return Ok(None);
    };
    let law =
        Anisotropy::new(spec.warp, spec.weft).map_err(|e| format!("bending.anisotropy: {e}"))?;
    let err = |e: hinge_core::anisotropy::AnisotropyError| format!("bending.anisotropy: {e}");
    Ok(Some(match &spec.direction {
        crate::scene::DirectionSpec::Vector(d) => law
            .hinge_factors(rest, &MaterialDirection::Constant(Vector3::from(*d)))
            .map_err(err)?,
        crate::scene::DirectionSpec::Name(_) => {
            let uvs = scene.rest_uvs(rest)?;
            law.hinge_factors(rest, &MaterialDirection::Uv(&uvs))
                .map_err(err)?
        }
    }))
}

/// The scene's linear-solver backend.
fn linear_solver(scene: &Scene) -> Box<dyn LinearSolver> {
    match scene.solver.backend.as_str() {
        "faer-lu" => Box::new(FaerLu::default()),
        "pcg-jacobi" => Box::new(PcgJacobi::new(1e-10, 10_000)),
        "chebyshev-jacobi" => Box::new(ChebyshevJacobi::new(1e-10, 100_000)),
        "dense" => Box::new(Dense::default()),
        _ => match FillOrdering::from_name(&scene.solver.ordering) {
            Some(o) => Box::new(FaerLlt::with_ordering(o)),
            None => default_solver(),
        },
    }
}

/// Reads per-hinge rest angles: whitespace-separated numbers.
fn read_rest_angles(path: &Path) -> Result<Vec<f64>, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("bending.rest_angles: {}: {e}", path.display()))?;
    text.split_whitespace()
        .enumerate()
        .map(|(i, w)| {
            w.parse::<f64>().map_err(|_| {
                format!(
                    "bending.rest_angles: {}: value {i} (hinge {i}) `{w}` is not a number",
                    path.display()
                )
            })
        })
        .collect()
}

/// What the scene adds to its ψ: damping, anisotropy factors, rest angles, plasticity.
#[derive(Clone, Copy)]
struct HingeOptions<'a> {
    damping: f64,
    anisotropy: Option<&'a [f64]>,
    rest_angles: Option<&'a [f64]>,
    plasticity: Option<Plasticity>,
    /// `bending.hessian`.
    hessian: HessianMode,
}

/// A scene's bending term, with its stiff rest hinges ([`StiffRest`]).
type BendingTerm = (Box<dyn Energy>, Option<StiffRest>);

/// Builds [`bending_term`] of the ψ [`BuiltinBending::with_psi`] hands it.
struct BendingTermOf<'a> {
    rest: &'a TriMesh,
    options: HingeOptions<'a>,
}

impl PsiConsumer for BendingTermOf<'_> {
    type Output = Result<BendingTerm, String>;
    fn consume<P>(self, psi: P) -> Self::Output
    where
        P: HingePsi + Clone + Send + Sync + std::fmt::Debug + 'static,
    {
        bending_term(self.rest, psi, self.options)
    }
}

fn bending_term<P: HingePsi + Send + 'static>(
    rest: &TriMesh,
    psi: P,
    o: HingeOptions<'_>,
) -> Result<BendingTerm, String>
where
    P::Params: Send + Sync,
{
    match o.anisotropy {
        Some(f) => hinge_term(rest, Anisotropic::new(psi, f.to_vec()), o),
        None => hinge_term(rest, psi, o),
    }
}

fn hinge_term<P: HingePsi + Send + 'static>(
    rest: &TriMesh,
    psi: P,
    o: HingeOptions<'_>,
) -> Result<BendingTerm, String>
where
    P::Params: Send + Sync,
{
    fn finish<Q: HingePsi + Send + 'static>(
        mut model: BendingModel<Q>,
        o: HingeOptions<'_>,
    ) -> Result<BendingTerm, String>
    where
        Q::Params: Send + Sync,
    {
        if let Some(t) = o.rest_angles {
            model
                .set_rest_angles(t)
                .map_err(|e| format!("bending.rest_angles: {e}"))?;
        }
        model
            .set_hessian_mode(o.hessian)
            .map_err(|e| format!("bending.hessian: {e}"))?;
        let stiff = StiffRest::of(&model);
        let term = HingeTerm::new("bending", model, Method::Refactored);
        let term: Box<dyn Energy> = Box::new(match o.plasticity {
            Some(p) => term
                .with_plasticity(p)
                .map_err(|e| format!("bending.plasticity: {e}"))?,
            None => term,
        });
        Ok((term, stiff))
    }
    let err = |e: hinge_core::EvalError| e.to_string();
    if o.damping > 0.0 {
        finish(
            BendingModel::new(rest, (psi, ViscousDamping { kd: o.damping })).map_err(err)?,
            o,
        )
    } else {
        finish(BendingModel::new(rest, psi).map_err(err)?, o)
    }
}

/// Where and how a run writes its output.
#[derive(Debug, Clone, Copy)]
pub struct Output<'a> {
    /// The directory.
    pub dir: &'a std::path::Path,
    /// The frames' format (OBJ, OFF or PLY).
    pub format: MeshFormat,
    /// Also write `animation.png`, `final.png` and `obstacles.obj` ([`crate::view`]).
    pub pictures: bool,
}

/// Simulates `scene` from rest `rest` with implicit Euler; writes OBJ frames and the pictures to `out`
/// when given (`frame_0000.obj` the rest state, `frame_k.obj` the state after step k).
///
/// # Errors
/// A one-line message (a failed step names the frame and the solver's diagnostics).
pub fn simulate(
    scene: &Scene,
    rest: &TriMesh,
    out: Option<&std::path::Path>,
    progress: impl FnMut(usize, &FrameStats, f64, &[Vector3<f64>]),
) -> Result<RunSummary, String> {
    let out = out.map(|dir| Output {
        dir,
        format: MeshFormat::Obj,
        pictures: true,
    });
    simulate_until(scene, rest, out, None, None, progress)
}

/// No solve can start from a state whose energy cannot be evaluated (a vertex on or inside a barrier's
/// obstacle, a hinge at the pole of its ψ, …), and no substep changes that state: said before the first step
/// (naming the element as the mesh file counts it), not as a failed frame after every substep was tried.
fn check_initial_state(
    system: &mut System,
    x: &[Vector3<f64>],
    names: Option<&FileNumbering>,
) -> Result<(), String> {
    system
        .evaluate(
            x,
            hinge_core::bending::Request::VALUE,
            hinge_core::bending::Parallelism::Rayon,
        )
        .map(|_| ())
        .map_err(|source| {
            let e = SolverError::Eval {
                source,
                stats: Box::default(),
            };
            format!("initial state: {}", solver_message(&e, names))
        })
}

/// Prepares a run resumed from checkpoint `c` (whose positions and velocities the caller starts from):
/// checks it against the scene (vertex count, frame within the scene's frames, finite values, plasticity
/// on both sides or neither) and hands the plastic state to `system` and the shift memory to the implicit
/// stepper.
fn resume_state(
    c: &Checkpoint,
    scene: &Scene,
    rest: &TriMesh,
    system: &mut System,
    stepper: &mut Stepper,
) -> Result<(), String> {
    let n = rest.n_vertices();
    if c.positions.len() != n || c.velocities.len() != n {
        return Err(format!(
            "--resume: the checkpoint has {} vertices, the scene's mesh {n}",
            c.positions.len()
        ));
    }
    if c.frame >= scene.frames {
        return Err(format!(
            "--resume: the checkpoint is at frame {} and the scene has {} frames: nothing to run \
             (--frames sets more)",
            c.frame, scene.frames
        ));
    }
    for (what, values) in [("position", &c.positions), ("velocity", &c.velocities)] {
        if let Some(i) = values.iter().position(|p| !p.iter().all(|x| x.is_finite())) {
            return Err(format!("--resume: vertex {i}: {what} is not finite"));
        }
    }
    match (&c.plastic, system.plastic_state().is_some()) {
        (Some((theta_bar, alpha)), true) => system
            .set_plastic_state(theta_bar, alpha)
            .map_err(|e| format!("--resume: plastic state: {e}"))?,
        (None, false) => {}
        (Some(_), false) => {
            return Err(
                "--resume: the checkpoint has a plastic state but the scene has no \
                 [bending.plasticity]"
                    .into(),
            );
        }
        (None, true) => {
            return Err(
                "--resume: the scene has [bending.plasticity] but the checkpoint no plastic state"
                    .into(),
            );
        }
    }
    if let Stepper::Implicit(s) = stepper {
        s.newton_mut()
            .restore_shift_memory(c.shift_memory)
            .map_err(|e| format!("--resume: {e}"))?;
    }
    Ok(())
}

/// The set-up warning of a scene with stiff rest hinges ([`StiffRest`]), one line: to `warn`, or on stderr
/// as `hinge: warning: …` without one.
fn warn_stiff_rest(
    stiff: Option<&StiffRest>,
    energy: &str,
    names: Option<&FileNumbering>,
    warn: Option<&mut (dyn FnMut(&str) + '_)>,
) {
    if let Some(s) = stiff {
        let line = format!(
            "{}{}; Newton may need many iterations and substeps",
            s.describe(names),
            tan_note(energy)
        );
        match warn {
            Some(w) => w(&line),
            None => eprintln!("hinge: warning: {line}"),
        }
    }
}

/// How many of the vertices that lie in a face (`in_a_face`) are more than `depth` (≥ 0) inside `obstacle`'s
/// surface at `x`, and the deepest of them with its (negative) distance; `None` when none is.
fn inside(
    obstacle: &Obstacle,
    x: &[Vector3<f64>],
    in_a_face: &[bool],
    depth: f64,
) -> Option<(usize, (usize, f64))> {
    let mut count = 0usize;
    let mut deepest = (0usize, 0.0f64);
    for (v, p) in x.iter().enumerate() {
        let d = obstacle.distance(p);
        if in_a_face[v] && d < -depth {
            count += 1;
            if d < deepest.1 {
                deepest = (v, d);
            }
        }
    }
    (count > 0).then_some((count, deepest))
}

/// Hands a warning line to `warn`, or prints it on stderr as `hinge: warning: …`.
fn emit(warn: Option<&mut (dyn FnMut(&str) + '_)>, line: &str) {
    match warn {
        Some(w) => w(line),
        None => eprintln!("hinge: warning: {line}"),
    }
}

/// How far below a penalty obstacle's surface, as a fraction of the rest mesh's mean edge length, a vertex
/// must be at the end of a frame (or at a static equilibrium) for `hinge run` to warn that the contact let
/// it through (once per obstacle and run; Python `run_scene` raises it as a `MeshWarning`). A penalty
/// contact holds a vertex with a force of its stiffness times its depth below the margin, so a resting
/// vertex lies below the margin by its load over the stiffness (with the default margin 0, below the
/// surface: 5e-7 m for the drape's vertices on a 2e3 N/m contact); the warning is for depths that show,
/// not for that.
pub const LET_THROUGH_DEPTH: f64 = 0.01;

/// Positions and their time: a point on a run's path (an accepted substep's end).
type Waypoint = (Vec<Vector3<f64>>, f64);

/// The warnings of vertices inside penalty obstacles (barrier obstacles refuse such states with errors of
/// their own), one line per obstacle and run at most, to `warn` or on stderr as `hinge: warning: …`:
/// [`ContactWatch::start`] for a mesh that starts inside an obstacle, [`ContactWatch::check`] for vertices
/// a penalty contact let through later.
struct ContactWatch<'a> {
    /// Whether each vertex lies in a face (where unreferenced vertices lie says nothing).
    in_face: Vec<bool>,
    /// [`LET_THROUGH_DEPTH`] times the rest mesh's mean edge length.
    depth: f64,
    /// Per obstacle: the stiffness and margin of a penalty obstacle that has not warned yet, else `None`.
    pending: Vec<Option<(f64, f64)>>,
    /// The rest mesh file's numbering, for the vertices the lines name.
    names: Option<&'a FileNumbering>,
    /// The positions at the last frame end checked (at first the rest positions) and its time, for the
    /// paths through spheres ([`passed_through`]); `None` once no penalty sphere is pending.
    last: Option<(Vec<Vector3<f64>>, f64)>,
}

impl<'a> ContactWatch<'a> {
    /// The set-up warning of a scene whose mesh starts inside an obstacle: one line per such penalty
    /// obstacle (how many vertices of a face are more than [`ContactWatch::depth`] inside its surface, the
    /// deepest and by how much). A penalty contact pushes them out at once, with a force of its stiffness
    /// times that depth (the cloth is thrown off). Depths below that are not warned of: a cloth laid on a
    /// floor whose height is computed differently from the cloth's lies a rounding error inside it. An
    /// obstacle that warned here does not warn again, nor does one listed in `warned` (a checkpoint's
    /// [`Checkpoint::warned_obstacles`]: it warned before the run was resumed). `(x0, t0)`: the run's start
    /// state and its time (the rest state at 0, or a checkpoint's), with the obstacles placed at `t0`.
    fn start(
        scene: &Scene,
        obstacles: &[(Obstacle, Option<Motion>)],
        rest: &TriMesh,
        (x0, t0, warned): (&[Vector3<f64>], f64, &[usize]),
        names: Option<&'a FileNumbering>,
        mut warn: Option<&mut (dyn FnMut(&str) + '_)>,
    ) -> Self {
        let mut watch = ContactWatch {
            in_face: rest.vertices_in_faces(),
            depth: LET_THROUGH_DEPTH * mean_edge_length(rest),
            pending: (0..obstacles.len())
                .map(|i| {
                    scene
                        .obstacles
                        .get(i)
                        .filter(|o| o.model != "barrier" && !warned.contains(&i))
                        .map(|o| (o.stiffness, o.margin))
                })
                .collect(),
            names,
            last: None,
        };
        for (i, obstacle) in obstacles_at(obstacles, t0).iter().enumerate() {
            if watch.pending[i].is_none() {
                continue;
            }
            let Some((count, deepest)) = inside(obstacle, x0, &watch.in_face, watch.depth) else {
                continue;
            };
            let line = format!(
                "obstacles[{i}]: {count} {} {} inside it, the deepest (vertex {}) {:.3e} m below its \
                 surface; the contact pushes {} out at once",
                if count == 1 {
                    "vertex starts"
                } else {
                    "vertices start"
                },
                watch.beyond(),
                watch.vertex(deepest.0),
                -deepest.1,
                if count == 1 { "it" } else { "them" },
            );
            emit(warn.as_deref_mut(), &line);
            watch.pending[i] = None;
        }
        if watch.watches_a_sphere(obstacles) {
            watch.last = Some((x0.to_vec(), t0));
        }
        watch
    }

    /// The depth a warning counts from, as the lines give it: "more than 1.897e-3 m (1 % of the mean edge)".
    fn beyond(&self) -> String {
        format!(
            "more than {:.3e} m ({:.0} % of the mean edge)",
            self.depth,
            100.0 * LET_THROUGH_DEPTH
        )
    }

    /// Vertex `v` as the lines name it: in the mesh file's numbering when there is one.
    fn vertex(&self, v: usize) -> String {
        self.names
            .map_or_else(|| v.to_string(), |n| n.vertex_number(v))
    }

    /// The obstacles that no longer warn (they warned, or never do): a checkpoint's
    /// [`Checkpoint::warned_obstacles`].
    fn silent(&self) -> Vec<usize> {
        (0..self.pending.len())
            .filter(|&i| self.pending[i].is_none())
            .collect()
    }

    /// Whether a penalty sphere that has not warned yet is watched (its paths need the last positions).
    fn watches_a_sphere(&self, obstacles: &[(Obstacle, Option<Motion>)]) -> bool {
        obstacles
            .iter()
            .zip(&self.pending)
            .any(|((o, _), p)| p.is_some() && matches!(o, Obstacle::Sphere { .. }))
    }

    /// The run-time warning of a penalty obstacle that let vertices through: at `when` (`Some(k)`: the end
    /// of frame k; `None`: a static equilibrium), vertices of `x` more than [`ContactWatch::depth`] inside
    /// the surface of an obstacle that has not warned yet, the obstacles placed at `time`. A fast impact, a
    /// moving obstacle or a load beyond what the penalty carries pushes vertices through the surface, which
    /// nothing else reports (the run goes on, and they may pass right through).
    ///
    /// At a frame end it also warns of vertices that went through a penalty sphere since the last frame end
    /// and came out again, which the depth at the two ends does not show ([`passed_through`]): the contact
    /// acts on where a step ends, so a vertex whose step carries it across the sphere is never held (a large
    /// dt, a fast fall, a small sphere).
    fn check(
        &mut self,
        obstacles: &[(Obstacle, Option<Motion>)],
        time: f64,
        (x, substeps): (&[Vector3<f64>], &[Waypoint]),
        when: Option<usize>,
        mut warn: Option<&mut (dyn FnMut(&str) + '_)>,
    ) {
        if self.pending.iter().all(Option::is_none) {
            return;
        }
        // At a frame end, the path since the last one: its positions, then those at the ends of the
        // frame's substeps before the last (whose end is `x`), then `x`; with the obstacles placed at
        // each waypoint's time.
        let before = match (when, &self.last) {
            (Some(k), Some((last, last_time))) => {
                let inner = &substeps[..substeps.len().saturating_sub(1)];
                let mut points: Vec<&[Vector3<f64>]> = vec![last.as_slice()];
                let mut placed = vec![obstacles_at(obstacles, *last_time)];
                for (p, t) in inner {
                    points.push(p);
                    placed.push(obstacles_at(obstacles, *t));
                }
                points.push(x);
                Some((k, points, placed))
            }
            _ => None,
        };
        for (i, obstacle) in obstacles_at(obstacles, time).iter().enumerate() {
            let Some(contact) = self.pending[i] else {
                continue;
            };
            let line = if let Some(found) = inside(obstacle, x, &self.in_face, self.depth) {
                self.let_through_line(i, when, found, contact)
            } else if let Some((k, points, placed)) = &before
                && let Some(found) = {
                    let spheres: Vec<&Obstacle> = placed
                        .iter()
                        .map(|o| &o[i])
                        .chain(std::iter::once(obstacle))
                        .collect();
                    passed_through(points, &spheres, &self.in_face)
                }
            {
                self.passed_through_line(i, *k, points.len() - 1, found, contact)
            } else {
                continue;
            };
            emit(warn.as_deref_mut(), &line);
            self.pending[i] = None;
        }
        if when.is_some() {
            if self.watches_a_sphere(obstacles) {
                if let Some((last, last_time)) = &mut self.last {
                    last.copy_from_slice(x);
                    *last_time = time;
                }
            } else {
                self.last = None;
            }
        }
    }

    /// The line of obstacle `i`, whose penalty contact (`(stiffness, margin)`) left `count` vertices more
    /// than [`ContactWatch::depth`] inside it at `when` (`None`: a static equilibrium), the deepest vertex
    /// with its distance.
    fn let_through_line(
        &self,
        i: usize,
        when: Option<usize>,
        (count, deepest): (usize, (usize, f64)),
        (stiffness, margin): (f64, f64),
    ) -> String {
        let them = if count == 1 { "it" } else { "them" };
        format!(
            "{}: {count} {} {} inside obstacles[{i}], the deepest \
             (vertex {}) {:.3e} m below its surface: its penalty contact (stiffness {stiffness:e} N/m, margin \
             {margin:e} m) let {them} through; a stiffer contact{} or model = \"barrier\" keeps {them} out",
            when.map_or_else(|| "the equilibrium".to_string(), |k| format!("frame {k}")),
            if count == 1 {
                "vertex is"
            } else {
                "vertices are"
            },
            self.beyond(),
            self.vertex(deepest.0),
            -deepest.1,
            if when.is_some() { ", a smaller dt" } else { "" },
        )
    }

    /// The line of sphere `i`, through which `count` vertices went between frames k − 1 and k
    /// ([`passed_through`]), the closest to its centre with its distance.
    fn passed_through_line(
        &self,
        i: usize,
        k: usize,
        substeps: usize,
        (count, closest): (usize, (usize, f64)),
        (stiffness, margin): (f64, f64),
    ) -> String {
        let one = count == 1;
        let them = if one { "it" } else { "them" };
        format!(
            "frame {k}: {count} {} through obstacles[{i}] since frame {} ({} {} relative to the \
             sphere {} within half its radius of its centre; the closest, vertex {}, {:.3e} m from it): its \
             penalty contact (stiffness {stiffness:e} N/m, margin {margin:e} m) acts where a step ends and \
             never held {them}; a smaller dt or model = \"barrier\" keeps {them} out",
            if one { "vertex went" } else { "vertices went" },
            k - 1,
            if one { "its" } else { "their" },
            match (substeps > 1, one) {
                (false, true) => "straight path".to_string(),
                (false, false) => "straight paths".to_string(),
                (true, true) => format!("path through the frame's {substeps} substeps"),
                (true, false) => format!("paths through the frame's {substeps} substeps"),
            },
            if one { "passes" } else { "pass" },
            self.vertex(closest.0),
            closest.1,
        )
    }
}

/// How many of the vertices that lie in a face went through a sphere between two frame ends, and the one
/// closest to its centre with that distance; `None` when none did or the obstacle is not a sphere (a plane
/// needs no such test: a straight path between two points outside a half-space stays outside it, so a
/// vertex that went through a plane ends beyond it, where [`inside`] sees it). The path runs through the
/// waypoints `points` (the last frame end, the ends of the frame's substeps, this frame end), straight
/// between consecutive ones, each taken relative to the sphere's centre at that waypoint (`spheres`, one
/// per waypoint); a vertex went through when it passes within half the radius of the centre. The steps of
/// implicit Euler move each vertex along such straight paths, and a path that starts and ends outside the
/// sphere and comes that close to its centre crosses it; a vertex sliding over the sphere stays far from
/// that (its path's chord dips a distance L²/(8R) below the surface for a move L, a tenth of the radius at
/// L = 0.9 R within one step).
fn passed_through(
    points: &[&[Vector3<f64>]],
    spheres: &[&Obstacle],
    in_a_face: &[bool],
) -> Option<(usize, (usize, f64))> {
    let mut centres = Vec::with_capacity(spheres.len());
    let mut radius = 0.0;
    for o in spheres {
        let Obstacle::Sphere {
            center, radius: r, ..
        } = o
        else {
            return None;
        };
        centres.push(*center);
        radius = *r;
    }
    if points.len() < 2 || points.len() != centres.len() {
        return None;
    }
    let mut count = 0usize;
    let mut closest = (0usize, f64::INFINITY);
    for v in 0..points[0].len() {
        if !in_a_face[v] {
            continue;
        }
        // The closest approach over the segments between consecutive waypoints.
        let mut d = f64::INFINITY;
        for w in 0..points.len() - 1 {
            let (a, b) = (points[w][v] - centres[w], points[w + 1][v] - centres[w + 1]);
            let ab = b - a;
            let len2 = ab.norm_squared();
            let t = if len2 > 0.0 {
                (-a.dot(&ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            d = d.min((a + ab * t).norm());
        }
        if d < 0.5 * radius {
            count += 1;
            if d < closest.1 {
                closest = (v, d);
            }
        }
    }
    (count > 0).then_some((count, closest))
}

/// What a caller hooks into a run ([`simulate_observed`], [`equilibrium_observed`]); the default hooks
/// nothing and prints set-up warnings on stderr.
#[derive(Default)]
pub struct Hooks<'a> {
    /// Raised (Ctrl-C), it ends the run after the current frame, or the solve at its next Newton iteration.
    pub stop: Option<&'a Arc<AtomicBool>>,
    /// The rest mesh file's numbering: errors and warnings name vertices and faces as the file counts them.
    pub names: Option<&'a FileNumbering>,
    /// Called after every accepted Newton iteration ([`Newton::set_observer`]).
    pub observer: Option<Observer>,
    /// Receives each warning as one line without the `hinge: warning: ` prefix (set-up: stiff rest hinges,
    /// [`StiffRest`], a mesh that starts inside an obstacle; during a run or at a static equilibrium: vertices
    /// a penalty contact let through its obstacle's surface, once per obstacle); without it they are printed
    /// on stderr with that prefix.
    pub warn: Option<Warn<'a>>,
    /// A time-stepped run writes its [`Checkpoint`] to this file when it ends: after its last frame, when
    /// stopped, and when a frame fails (then the last good frame's). Static solves write none.
    pub checkpoint: Option<&'a Path>,
    /// With [`Hooks::checkpoint`]: also write it after every `checkpoint_every`-th frame (0: only at the
    /// end).
    pub checkpoint_every: usize,
    /// A time-stepped run starts from this checkpoint instead of the rest state (its frame, time,
    /// positions, velocities, shift memory and plastic state) and steps the frames after it up to the
    /// scene's `frames`. A static solve refuses it.
    pub resume: Option<&'a Checkpoint>,
}

impl<'a> Hooks<'a> {
    /// Hooks with the stop flag and the file numbering only (no observer; set-up warnings on stderr).
    #[must_use]
    pub fn new(stop: Option<&'a Arc<AtomicBool>>, names: Option<&'a FileNumbering>) -> Self {
        Self {
            stop,
            names,
            ..Self::default()
        }
    }
}

/// A receiver of set-up warnings ([`Hooks::warn`]).
pub type Warn<'a> = Box<dyn FnMut(&str) + 'a>;

/// A failed solve's one-line `message`, with the scene's stiff rest hinges as the likely cause when it has
/// any: a solve that stalls or gets stuck there otherwise says only what it saw (short steps, a collapsed
/// triangle?).
fn with_stiff_rest(
    message: String,
    stiff: Option<&StiffRest>,
    energy: &str,
    names: Option<&FileNumbering>,
) -> String {
    match stiff {
        Some(s) => format!(
            "{message}; the rest state may be why: {}{}",
            s.describe(names),
            tan_note(energy)
        ),
        None => message,
    }
}

/// Why a scene's `energy` makes a folded rest hinge stiff, where the reason is known.
fn tan_note(energy: &str) -> &'static str {
    if energy.parse() == Ok(BuiltinBending::TanBending) {
        ", where tan bending stiffens as 1/cos⁴(θ̄/2)"
    } else {
        ""
    }
}

/// A solver error's message; with `names` (a mesh file's numbering), an evaluation error names its vertices
/// and faces as the file counts them ([`hinge_core::EvalError::describe`]).
///
/// A solve that stopped short of convergence (line search, iteration limit, stalled, stuck, linear
/// solve) also says where its residual is: `…; the largest residual force, 2.345e-1 N, is at vertex 7`
/// ([`NewtonStats::largest_residual`]; with `names`, the vertex as the file counts it, with its line).
pub fn solver_message(e: &SolverError, names: Option<&FileNumbering>) -> String {
    match (e, names) {
        (SolverError::Eval { source, .. }, Some(n)) => {
            format!("evaluation failed: {} {}", source.describe(n), n.note())
        }
        (
            SolverError::LineSearch { stats }
            | SolverError::NotConverged { stats }
            | SolverError::Stalled { stats }
            | SolverError::Stuck { stats }
            | SolverError::Linear { stats, .. },
            _,
        ) => match stats.largest_residual {
            Some((v, force)) => format!(
                "{e}; the largest residual force, {force:.3e} N, is at {}",
                name_vertex(v, names)
            ),
            None => e.to_string(),
        },
        _ => e.to_string(),
    }
}

/// Vertex `v` in a message: `vertex 7 (line 12)` in the mesh file's numbering with `names`, `vertex 7`
/// (from 0) without.
fn name_vertex(v: usize, names: Option<&FileNumbering>) -> String {
    names.map_or_else(|| format!("vertex {v}"), |n| n.vertex(v))
}

/// [`simulate`] with the output's format chosen, stopping when `stop` is raised: after the current frame, or,
/// for implicit Euler, within it (its Newton solver checks the flag before every iteration; the frame is
/// then abandoned, the state is that of the last completed frame). The summary is then marked
/// [`RunSummary::interrupted`] and counts the frames completed; with
/// `names` (the rest mesh file's numbering), a step's evaluation error names its vertices and faces as the
/// file counts them.
///
/// # Errors
/// As [`simulate`].
pub fn simulate_until(
    scene: &Scene,
    rest: &TriMesh,
    out: Option<Output<'_>>,
    stop: Option<&Arc<AtomicBool>>,
    names: Option<&FileNumbering>,
    progress: impl FnMut(usize, &FrameStats, f64, &[Vector3<f64>]),
) -> Result<RunSummary, String> {
    simulate_observed(scene, rest, out, Hooks::new(stop, names), progress)
}

/// [`simulate_until`] with [`Hooks`]: `stop` and `names` as there, the observer called after every accepted
/// Newton iteration of every implicit step ([`Newton::set_observer`]; [`trace_line`] formats one; it sees
/// the iterations of every attempt, those of substeps and of attempts that fail included, and cannot
/// change the run), and the set-up warnings.
///
/// # Errors
/// As [`simulate`].
pub fn simulate_observed(
    scene: &Scene,
    rest: &TriMesh,
    out: Option<Output<'_>>,
    hooks: Hooks<'_>,
    mut progress: impl FnMut(usize, &FrameStats, f64, &[Vector3<f64>]),
) -> Result<RunSummary, String> {
    let Hooks {
        stop,
        names,
        observer,
        mut warn,
        checkpoint,
        checkpoint_every,
        resume,
    } = hooks;
    // Shared by the steppers a run makes (a new one when pins are released).
    let observer = observer.map(|o| Arc::new(std::sync::Mutex::new(o)));
    let start = Instant::now();
    let n = rest.n_vertices();
    let Built {
        mut system,
        masses,
        pins,
        solver,
        params,
        obstacles,
        stiff_rest,
        ..
    } = build(scene, rest, true)?;
    warn_stiff_rest(
        stiff_rest.as_ref(),
        &scene.bending.energy,
        names,
        warn.as_deref_mut(),
    );
    let groups = scene.pin_groups(rest)?;
    let mut fixed: Vec<usize> = scene.fixed_pins(rest)?;
    fixed.extend(rest.unreferenced_vertices());
    // The accepted substep ends of the frame being stepped (positions, time), for the path test through
    // penalty spheres ([`ContactWatch::check`]); recorded only when there is such a sphere.
    type Path = Arc<std::sync::Mutex<Vec<Waypoint>>>;
    let path: Option<Path> = scene
        .obstacles
        .iter()
        .any(|o| o.kind == "sphere" && o.model != "barrier")
        .then(Path::default);
    let make_stepper = |system: &hinge_core::energy::System,
                        active: &[bool],
                        solver: Box<dyn LinearSolver>|
     -> Result<Stepper, String> {
        let mut pinned = fixed.clone();
        for (g, on) in groups.iter().zip(active) {
            if *on {
                pinned.extend_from_slice(&g.vertices);
            }
        }
        pinned.sort_unstable();
        pinned.dedup();
        let pins = hinge_energies::pins::Pins::new(n, pinned).map_err(|e| format!("pins: {e}"))?;
        Ok(if scene.solver.integrator == "symplectic-euler" {
            let mut stepper = SymplecticEuler::new(
                system,
                scene.dt,
                scene.solver.substeps,
                masses.clone(),
                &pins,
            )
            .map_err(|e| e.to_string())?;
            stepper.set_stop(stop.cloned());
            Stepper::Explicit(stepper)
        } else {
            let mut stepper = ImplicitEuler::new(
                system,
                scene.dt,
                masses.clone(),
                pins,
                solver,
                params.clone(),
            )
            .map_err(|e| e.to_string())?;
            stepper.newton_mut().set_stop(stop.cloned());
            if let Some(path) = &path {
                let path = Arc::clone(path);
                stepper.set_substep_observer(Some(Box::new(move |x: &[Vector3<f64>], t: f64| {
                    if let Ok(mut p) = path.lock() {
                        p.push((x.to_vec(), t));
                    }
                })));
            }
            if let Some(shared) = &observer {
                let shared = Arc::clone(shared);
                stepper
                    .newton_mut()
                    .set_observer(Some(Box::new(move |r: &IterationReport| {
                        // A poisoned lock (an observer that panicked) just ends the tracing.
                        if let Ok(mut o) = shared.lock() {
                            o(r);
                        }
                    })));
            }
            Stepper::Implicit(Box::new(stepper))
        })
    };
    drop(pins);
    let active_at = |t: f64| -> Vec<bool> {
        groups
            .iter()
            .map(|g| g.release.is_none_or(|r| t < r))
            .collect()
    };
    // Where the run starts: the rest state at t = 0, or a checkpoint's frame. Frame k ends at
    // `origin + k dt`, with `origin` = 0 unless a checkpoint taken with another dt is resumed.
    let first_frame = resume.map_or(0, |c| c.frame);
    let origin = resume.map_or(0.0, |c| c.time - c.frame as f64 * scene.dt);
    let t_start = origin + first_frame as f64 * scene.dt;
    // The pins of the frame the run starts after (of its start, for a run from rest): a group released
    // at the first frame stepped here leaves the pins in the loop below, with a new stepper, as it did
    // in the run that was not stopped.
    let mut active = active_at(resume.map_or(0.0, |c| c.time - c.dt));
    let mut stepper = make_stepper(&system, &active, solver)?;
    let (mut x, mut v) = match resume {
        Some(c) => {
            resume_state(c, scene, rest, &mut system, &mut stepper)?;
            (c.positions.clone(), c.velocities.clone())
        }
        None => (rest.positions().to_vec(), vec![Vector3::zeros(); n]),
    };
    match &mut stepper {
        Stepper::Implicit(s) => s.set_time(&mut system, t_start),
        Stepper::Explicit(s) => s.set_time(&mut system, t_start),
    }
    .map_err(|e| format!("frame {first_frame}: {e}"))?;
    check_initial_state(&mut system, &x, names)?;
    // After the check: a state the energies refuse is the one line, without a warning before it.
    let warned = resume.map_or(&[][..], |c| &c.warned_obstacles[..]);
    let mut watch = ContactWatch::start(
        scene,
        &obstacles,
        rest,
        (&x, t_start, warned),
        names,
        warn.as_deref_mut(),
    );
    let save = |frame: usize,
                x: &[Vector3<f64>],
                v: &[Vector3<f64>],
                stepper: &Stepper,
                system: &System,
                watch: &ContactWatch|
     -> Result<(), String> {
        let Some(path) = checkpoint else {
            return Ok(());
        };
        Checkpoint {
            scene: scene.name.clone(),
            frame,
            time: origin + frame as f64 * scene.dt,
            dt: scene.dt,
            shift_memory: match stepper {
                Stepper::Implicit(s) => s.newton().shift_memory(),
                Stepper::Explicit(_) => 0.0,
            },
            positions: x.to_vec(),
            velocities: v.to_vec(),
            plastic: system
                .plastic_state()
                .map(|(t, a)| (t.to_vec(), a.to_vec())),
            warned_obstacles: watch.silent(),
        }
        .write(path)
    };
    let mut summary = RunSummary {
        frames: scene.frames.saturating_sub(first_frame),
        newton_iterations: 0,
        line_search_steps: 0,
        bending_seconds: 0.0,
        other_energy_seconds: 0.0,
        linear_solve_seconds: 0.0,
        total_seconds: 0.0,
        min_clearance: None,
        n_vertices: n,
        far_end_drop: 0.0,
        max_speed: 0.0,
        final_gradient_norm: f64::NAN,
        factorizations: 0,
        definite_iterations: 0,
        accelerated_iterations: 0,
        substeps: 0,
        max_final_gradient_norm: 0.0,
        smallest_substep_fraction: 1.0,
        interrupted: false,
        max_plastic_angle: None,
        frame_newton_iterations: Vec::new(),
        frame_factorizations: Vec::new(),
        frame_substeps: Vec::new(),
    };
    // Every `every`-th frame (and the last) goes into the animation.
    let every = (scene.frames + 1)
        .div_ceil(crate::view::MAX_ANIMATION_FRAMES)
        .max(1);
    let mut samples: Vec<Vec<Vector3<f64>>> = Vec::new();
    let mut sample_times: Vec<f64> = Vec::new();
    let mut write_frame = |k: usize, x: &[Vector3<f64>], last: bool| -> Result<(), String> {
        let Some(o) = out else { return Ok(()) };
        if o.pictures && ((k - first_frame).is_multiple_of(every) || last) {
            samples.push(x.to_vec());
            sample_times.push(origin + k as f64 * scene.dt);
        }
        let name = format!("frame_{k:04}.{}", o.format.extension());
        write_mesh(o.dir.join(name), x, rest.triangles()).map_err(|e| e.to_string())
    };
    // Evolving (plastic) rest angles beside the frames: `[bending] rest_angles` restarts from them.
    let write_rest_angles = |k: usize, system: &hinge_core::energy::System| -> Result<(), String> {
        let (Some(o), Some(angles)) = (out, system.evolving_rest_angles()) else {
            return Ok(());
        };
        let mut text = String::with_capacity(24 * angles.len());
        for a in angles {
            text.push_str(&format!("{a:.17e}\n"));
        }
        let path = o.dir.join(format!("rest_angles_{k:04}.txt"));
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))
    };
    write_frame(first_frame, &x, false)?;
    write_rest_angles(first_frame, &system)?;
    let policy = SubstepPolicy {
        max_halvings: scene.solver.max_substep_halvings,
    };
    for frame in first_frame..scene.frames {
        let t = Instant::now();
        let t0 = origin + frame as f64 * scene.dt;
        // Released groups leave the pins at the first frame that starts at or after their release time.
        let now = active_at(t0);
        if now != active {
            active = now;
            stepper = make_stepper(&system, &active, linear_solver(scene))?;
        }
        // The frame starts at t0 (moving obstacles); set every frame, so the time does not drift.
        match &mut stepper {
            Stepper::Implicit(s) => s.set_time(&mut system, t0),
            Stepper::Explicit(s) => s.set_time(&mut system, t0),
        }
        .map_err(|e| format!("frame {}: {e}", frame + 1))?;
        let targets = |fraction: f64, y: &mut [Vector3<f64>]| {
            let time = t0 + fraction * scene.dt;
            for (g, on) in groups.iter().zip(&active) {
                if *on {
                    for &vtx in &g.vertices {
                        y[vtx] = g.motion.target(rest.positions()[vtx], time);
                    }
                }
            }
        };
        let motion: Option<&dyn PinMotion> = (!groups.is_empty()).then_some(&targets);
        if let Some(Ok(mut p)) = path.as_ref().map(|p| p.lock()) {
            p.clear();
        }
        let result = match &mut stepper {
            Stepper::Implicit(s) => s.advance_with(&mut system, &mut x, &mut v, policy, motion),
            Stepper::Explicit(s) => s.advance_with(&mut system, &mut x, &mut v, motion),
        };
        let fs = match result {
            Ok(fs) => fs,
            // Stopped within the frame: `x`, `v` and the system are the last completed frame's; the work
            // spent on the abandoned frame counts.
            Err(SolverError::Interrupted { stats }) => {
                summary.add_work(&stats);
                summary.add_timings(&mut system);
                summary.frames = frame - first_frame;
                summary.interrupted = true;
                if !(frame - first_frame).is_multiple_of(every) {
                    // The animation ends on the last frame done (rewritten: the same positions).
                    write_frame(frame, &x, true)?;
                }
                break;
            }
            Err(e) => {
                // The state is the last good frame's: a checkpoint to resume from.
                let saved = match save(frame, &x, &v, &stepper, &system, &watch) {
                    Ok(()) => checkpoint.map_or(String::new(), |p| {
                        format!("; frame {frame} is in {} for --resume", p.display())
                    }),
                    Err(e) => format!("; no checkpoint: {e}"),
                };
                let message = match stepper {
                    Stepper::Implicit(_) => format!(
                        "frame {}: {} (also in substeps down to dt/{}; {frame} frames completed{saved})",
                        frame + 1,
                        solver_message(&e, names),
                        1u64 << policy.max_halvings.min(30)
                    ),
                    Stepper::Explicit(_) => format!(
                        "frame {}: {} ({frame} frames completed; written up to frame_{frame:04}{saved})",
                        frame + 1,
                        solver_message(&e, names)
                    ),
                };
                return Err(with_stiff_rest(
                    message,
                    stiff_rest.as_ref(),
                    &scene.bending.energy,
                    names,
                ));
            }
        };
        let stats = &fs.newton;
        summary.add_work(stats);
        summary.final_gradient_norm = stats.gradient_norms.last().copied().unwrap_or(f64::NAN);
        summary.substeps += fs.substeps;
        summary.frame_newton_iterations.push(stats.iterations);
        summary.frame_factorizations.push(stats.factorizations);
        summary.frame_substeps.push(fs.substeps);
        summary.max_final_gradient_norm = summary
            .max_final_gradient_norm
            .max(fs.max_final_gradient_norm);
        summary.smallest_substep_fraction =
            summary.smallest_substep_fraction.min(fs.smallest_fraction);
        summary.add_timings(&mut system);
        let interrupted =
            stop.is_some_and(|s| s.load(Ordering::SeqCst)) && frame + 1 < scene.frames;
        // The animation ends on the last frame done.
        let last = interrupted || frame + 1 == scene.frames;
        write_frame(frame + 1, &x, last)?;
        write_rest_angles(frame + 1, &system)?;
        if checkpoint_every > 0 && (frame + 1).is_multiple_of(checkpoint_every) && !last {
            save(frame + 1, &x, &v, &stepper, &system, &watch)?;
        }
        summary.max_plastic_angle = system.max_plastic_angle();
        let substeps = path
            .as_ref()
            .and_then(|p| p.lock().ok().map(|mut p| std::mem::take(&mut *p)))
            .unwrap_or_default();
        watch.check(
            &obstacles,
            t0 + scene.dt,
            (&x, &substeps),
            Some(frame + 1),
            warn.as_deref_mut(),
        );
        progress(frame, &fs, t.elapsed().as_secs_f64(), &x);
        if interrupted {
            summary.frames = frame + 1 - first_frame;
            summary.interrupted = true;
            break;
        }
    }
    // The last frame done (all of them, or where Ctrl-C stopped the run): `x`, `v` and the system are its.
    let last_frame = first_frame + summary.frames;
    save(last_frame, &x, &v, &stepper, &system, &watch)?;
    if let Some(o) = out.filter(|o| o.pictures) {
        write_pictures(
            o.dir,
            &obstacles,
            &samples,
            &sample_times,
            rest.triangles(),
            scene.dt * every as f64,
        )?;
    }
    let end_time = origin + last_frame as f64 * scene.dt;
    if let Some(o) = out
        && obstacles.iter().any(|(_, m)| m.is_some())
    {
        // Moving obstacles beside each frame, for viewers of the frame sequence.
        let scene_box = crate::view::scene_box(if samples.is_empty() {
            std::slice::from_ref(&x)
        } else {
            &samples
        });
        for k in first_frame..=last_frame {
            let meshes = crate::view::obstacle_meshes(
                &obstacles_at(&obstacles, origin + k as f64 * scene.dt),
                scene_box,
            )?;
            crate::view::write_obstacles(&o.dir.join(format!("obstacles_{k:04}.obj")), &meshes)?;
        }
    }
    summary.min_clearance = min_clearance(&obstacles_at(&obstacles, end_time), &x);
    summary.far_end_drop = far_end_drop(rest, &x);
    summary.max_speed = v.iter().map(|w| w.norm()).fold(0.0, f64::max);
    summary.total_seconds = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// The observer of `hinge run --trace`: [`trace_line`] on standard output.
fn tracer(names: Option<FileNumbering>) -> Observer {
    Box::new(move |r: &IterationReport| {
        println!("{}", trace_line(r, names.as_ref()));
        let _ = std::io::stdout().flush();
    })
}

/// How often [`static_progress`] reports in `hinge run --static`.
pub const STATIC_PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(5);

/// A Newton observer for long static solves: after an accepted iteration that ends at least `every` after
/// the last report (or the observer's creation), `emit` gets one line, `static: I Newton iterations, gradient
/// norm G, S s`, with I the accepted iterations so far (over every continuation stage), G the latest ‖∇F‖
/// and S the seconds since the observer was made; during a membrane continuation
/// ([`membrane_stages`]) the line starts `static: membrane stage k/n, …` (stage n is the solve at the
/// scene's own stiffness). `every = 0` reports every iteration.
pub fn static_progress(
    every: std::time::Duration,
    mut emit: impl FnMut(String) + Send + 'static,
) -> Observer {
    let start = Instant::now();
    let (mut last, mut done) = (start, 0usize);
    Box::new(move |r: &IterationReport| {
        done += 1;
        let now = Instant::now();
        if now.duration_since(last) >= every {
            last = now;
            let stage = r
                .stage
                .map(|(k, n)| format!("membrane stage {k}/{n}, "))
                .unwrap_or_default();
            emit(format!(
                "static: {stage}{done} Newton iterations, gradient norm {:.2e}, {:.0} s",
                r.gradient_norm,
                now.duration_since(start).as_secs_f64()
            ));
        }
    })
}

/// One line of `hinge run --trace`: `  newton I: F = …, |grad F| = … N, |dx| = … m, alpha = …, shift = …`,
/// with `, definite` for a step of the definite Hessian ([`Globalization::ProjectOnDemand`]),
/// `, accelerated` for a full step corrected by geodesic acceleration
/// ([`NewtonParams::geodesic_acceleration`]) and `, stage k/n` in a membrane continuation. I counts from 1 in each solve (each substep, each attempt).
/// The line ends with where the residual is, `, largest at vertex V (… N)`
/// ([`IterationReport::largest_residual`]; V in the mesh file's numbering with `names`, from 0 without).
pub fn trace_line(r: &IterationReport, names: Option<&FileNumbering>) -> String {
    let mut line = format!(
        "  newton {}: F = {:.10e}, |grad F| = {:.3e} N, |dx| = {:.3e} m, alpha = {}, shift = {:.3e}",
        r.iteration, r.energy, r.gradient_norm, r.step_norm, r.step_length, r.shift
    );
    if r.definite {
        line.push_str(", definite");
    }
    if r.accelerated {
        line.push_str(", accelerated");
    }
    if let Some((k, n)) = r.stage {
        line.push_str(&format!(", stage {k}/{n}"));
    }
    if let Some((v, force)) = r.largest_residual {
        let v = names.map_or_else(|| v.to_string(), |n| n.vertex_number(v));
        line.push_str(&format!(", largest at vertex {v} ({force:.3e} N)"));
    }
    line
}

/// The time integrator of a run.
enum Stepper {
    Implicit(Box<ImplicitEuler>),
    Explicit(SymplecticEuler),
}

/// How `hinge run` ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Completion {
    /// Every frame (or the static solve) was done.
    Finished,
    /// Ctrl-C stopped the run (dynamics: the frames completed are written; statics: no equilibrium);
    /// `summary.json` says `"interrupted": true`.
    Interrupted,
}

/// Set by the Ctrl-C handler: the run stops before its next Newton iteration (or after the current frame
/// of an explicit integrator).
static INTERRUPTED: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// Installs the Ctrl-C handler (once per process): the first Ctrl-C asks the run to stop (dynamics: the
/// frames completed are kept; statics: nothing is written), a second one exits at once with code 130.
fn install_interrupt_handler() {
    // `set_handler` also replaces an inherited "ignore" (a shell starts background jobs of scripts with
    // SIGINT ignored): an explicit `kill -INT` then still ends the run cleanly. An error means this process
    // has installed the handler already (an earlier run): keep it.
    let _ = ctrlc::set_handler(|| {
        if INTERRUPTED.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    });
}

/// Runs `hinge run`.
///
/// # Errors
/// A one-line message (scene, arguments, disk space, a failed frame).
pub fn run(args: RunArgs) -> Result<Completion, String> {
    let (mut scene, base) = crate::scene::load(&args.scene)?;
    if let Some(f) = args.frames {
        scene.frames = crate::limits::frames(f)?;
    }
    if let Some(r) = args.resolution {
        scene.set_resolution(r)?;
    }
    let resume = match &args.resume {
        Some(path) => Some(Checkpoint::read(path).map_err(|e| format!("--resume: {e}"))?),
        None => None,
    };
    let (rest, names) = scene.rest_mesh_numbered(base.as_deref())?;
    let names = names.as_ref();
    let format = args.format.mesh_format();
    let (threads, warning) = crate::limits::threads(args.threads)?;
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(&scene.name));
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    // What the run writes: frame files (and, with plasticity, a rest-angle file per frame of at most 26
    // bytes per hinge, `{:.17e}` and a newline; hinges ≤ 3/2 of the triangles), obstacle frames, and for
    // a time-stepped run its checkpoint, twice while a new one replaces the old.
    let plastic_hinges = if scene.bending.plasticity.is_some() {
        (3 * rest.n_triangles()).div_ceil(2)
    } else {
        0
    };
    let mut bytes = 0_u64;
    let mut parts = Vec::new();
    if !args.no_frames {
        let files = if args.statics { 1 } else { scene.frames + 1 };
        bytes = (files as u64).saturating_mul(
            crate::limits::frame_bytes(format, rest.n_vertices(), rest.n_triangles())
                .saturating_add(26 * plastic_hinges as u64),
        );
        if !args.statics && scene.obstacles.iter().any(|o| o.motion.is_some()) {
            // `obstacles_k.obj` beside every frame.
            let (nv, nt) = scene.obstacles.iter().fold((0, 0), |(nv, nt), o| {
                let (v, t) = crate::view::obstacle_mesh_size(o.kind == "sphere");
                (nv + v, nt + t)
            });
            bytes = bytes.saturating_add(
                (files as u64).saturating_mul(crate::limits::obj_frame_bytes(nv, nt)),
            );
        }
        parts.push(format!("{files} frame files"));
    }
    if !args.statics {
        bytes = bytes.saturating_add(
            2 * Checkpoint::max_bytes(
                rest.n_vertices(),
                plastic_hinges,
                scene.obstacles.len(),
                &scene.name,
            ),
        );
        parts.push("a checkpoint and its replacement".to_string());
    }
    if bytes > 0 {
        crate::limits::disk_space(&out, bytes, &parts.join(" and "))?;
    }
    install_interrupt_handler();
    INTERRUPTED.store(false, Ordering::SeqCst);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    let mut what = if args.statics {
        "static equilibrium (Newton on the potential energy)".to_string()
    } else if (1e-3..1e5).contains(&scene.dt) {
        format!("{} frames of {:.4} s", scene.frames, scene.dt)
    } else {
        format!("{} frames of {} s", scene.frames, Num(scene.dt))
    };
    if let Some(c) = &resume {
        what.push_str(&format!(", resumed after frame {}", c.frame));
    }
    println!(
        "hinge run {}: {} vertices, {} triangles, {what}, {threads} threads → {}",
        scene.name,
        rest.n_vertices(),
        rest.n_triangles(),
        out.display()
    );
    let frames_dir = (!args.no_frames).then_some(Output {
        dir: out.as_path(),
        format,
        pictures: true,
    });
    let frames = scene.frames;
    let checkpoint = out.join("checkpoint.txt");
    let summary = if args.statics {
        // A static solve of a large soft shell takes minutes: a line every few seconds shows it moving.
        let progress = if args.trace {
            tracer(names.cloned())
        } else {
            static_progress(STATIC_PROGRESS_EVERY, |line| {
                println!("{line}");
                let _ = std::io::stdout().flush();
            })
        };
        pool.install(|| {
            equilibrium_observed(
                &scene,
                &rest,
                frames_dir,
                Hooks {
                    stop: Some(&*INTERRUPTED),
                    names,
                    observer: Some(progress),
                    // Refused by the static solve, with the reason.
                    resume: resume.as_ref(),
                    ..Hooks::default()
                },
            )
        })?
    } else {
        pool.install(|| {
            simulate_observed(
                &scene,
                &rest,
                frames_dir,
                Hooks {
                    stop: Some(&*INTERRUPTED),
                    names,
                    observer: args.trace.then(|| tracer(names.cloned())),
                    warn: None,
                    checkpoint: Some(&checkpoint),
                    checkpoint_every: args.checkpoint_every.unwrap_or(0),
                    resume: resume.as_ref(),
                },
                |frame, fs, seconds, _| {
                    println!(
                        "frame {:>4}/{frames}: {} Newton iterations, {} factorizations, {} substep{}, {:.1} ms",
                        frame + 1,
                        fs.newton.iterations,
                        fs.newton.factorizations,
                        fs.substeps,
                        if fs.substeps == 1 { "" } else { "s" },
                        seconds * 1e3
                    );
                    let _ = std::io::stdout().flush();
                },
            )
        })?
    };
    let json = serde_json::json!({
        "scene": scene.name,
        "frames": summary.frames,
        "resumed_after_frame": resume.as_ref().map(|c| c.frame),
        "n_vertices": summary.n_vertices,
        "newton_iterations": summary.newton_iterations,
        "line_search_steps": summary.line_search_steps,
        "factorizations": summary.factorizations,
        "definite_iterations": summary.definite_iterations,
        "accelerated_iterations": summary.accelerated_iterations,
        "substeps": summary.substeps,
        "smallest_substep_fraction": summary.smallest_substep_fraction,
        "max_final_gradient_norm": summary.max_final_gradient_norm,
        "seconds": {
            "bending_evaluation_and_assembly": summary.bending_seconds,
            "other_energies": summary.other_energy_seconds,
            "linear_solve": summary.linear_solve_seconds,
            "total": summary.total_seconds,
        },
        "min_clearance_to_sphere": summary.min_clearance,
        "far_end_drop": summary.far_end_drop,
        "max_speed": summary.max_speed,
        "static": args.statics,
        "interrupted": summary.interrupted,
        "max_plastic_angle": summary.max_plastic_angle,
        "frame_newton_iterations": summary.frame_newton_iterations,
        "frame_factorizations": summary.frame_factorizations,
        "frame_substeps": summary.frame_substeps,
    });
    let path = out.join("summary.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?,
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    let done = if args.statics && summary.interrupted {
        "static solve interrupted (no equilibrium written)".to_string()
    } else if args.statics {
        "static equilibrium".to_string()
    } else if summary.interrupted {
        format!("interrupted after {} of {frames} frames", summary.frames)
    } else {
        format!("{} frames", summary.frames)
    };
    println!(
        "done: {done}, {} Newton iterations ({} line-search steps, {} factorizations, {} substeps, largest final gradient norm {:.2e}); time: bending {:.3} s, other energies {:.3} s, linear solve {:.3} s, total {:.3} s{}",
        summary.newton_iterations,
        summary.line_search_steps,
        summary.factorizations,
        summary.substeps,
        summary.max_final_gradient_norm,
        summary.bending_seconds,
        summary.other_energy_seconds,
        summary.linear_solve_seconds,
        summary.total_seconds,
        summary.min_clearance.map_or(String::new(), |c| format!(
            "; min clearance to the sphere {c:.2e} m"
        ))
    );
    println!(
        "far end dropped {:.4e} m; largest speed {:.2e} m/s",
        summary.far_end_drop, summary.max_speed
    );
    Ok(if summary.interrupted {
        Completion::Interrupted
    } else {
        Completion::Finished
    })
}

#[cfg(test)]
mod tests {
    use super::{build, equilibrium, equilibrium_observed, static_progress};
    use crate::scene::{Scene, load};
    use hinge_core::TriMesh;

    fn membrane_stages(scene: &Scene, rest: &TriMesh) -> Result<Vec<f64>, String> {
        let built = build(scene, rest, false)?;
        let mut system = built.system;
        super::membrane_stages(scene, built.membrane, rest, &mut system)
            .map(|(_, s)| s)
            .map_err(|e| e.to_string())
    }

    /// The clamped strip of `hinge stability` with Young's modulus `young` and thickness `h`.
    fn strip(young: f64, h: f64) -> Scene {
        let (mut scene, _) = load("beam5").unwrap();
        scene.material.young = young;
        scene.material.thickness = h;
        scene.material.density = 1000.0 * h;
        scene
    }

    #[test]
    fn membrane_stages_soften_by_the_stiffness_ratio_in_steps_of_at_most_100() {
        // 0.1 mm: ratio 12 ℓ²/h² ≈ 2e4 (ℓ ≈ 4.3 mm), so the softest stage is about its inverse.
        let scene = strip(1e10, 1e-4);
        let rest = scene.rest_mesh(None).unwrap();
        let l = hinge_solver::statics::mean_edge_length(&rest);
        let stages = membrane_stages(&scene, &rest).unwrap();
        assert!(stages.len() >= 2, "{stages:?}");
        let softest = stages[0];
        assert!(
            (softest * 12.0 * l * l / 1e-8 - 1.0).abs() < 1e-12,
            "{stages:?}"
        );
        for w in stages
            .windows(2)
            .chain(std::iter::once(&[stages[stages.len() - 1], 1.0][..]))
        {
            assert!(
                w[0] < w[1] && w[1] / w[0] <= 100.0 * (1.0 + 1e-12),
                "{stages:?}"
            );
        }
        // A soft material: the loads bound the softening (strain 1% at the softest stage): weight per area
        // q = 0.1 kg/m² · 9.81 m/s², extent D = the strip's diagonal, ε = q D / (Y h).
        let s = membrane_stages(&strip(1e8, 1e-4), &rest).unwrap();
        let extent = (0.3f64.powi(2) + 0.0125f64.powi(2)).sqrt();
        let bound = 0.1 * 9.81 * extent / (1e8 * 1e-4) / hinge_solver::statics::STAGE_STRAIN;
        assert!(
            bound > 1e-4 / 12.0 * 1e-4 / (l * l) && bound < 0.1,
            "{bound}"
        );
        assert!(
            !s.is_empty() && (s[0] / bound - 1.0).abs() < 1e-9,
            "{s:?} vs {bound}"
        );
        // Too soft to need it (the bound is above 0.1): no stages.
        assert!(
            membrane_stages(&strip(1e6, 1e-3), &rest)
                .unwrap()
                .is_empty()
        );
        // Thick plates and the scene key: no stages. The co-rotational membrane: the same stages (its
        // stiffness is scaled instead of Young's modulus).
        assert!(
            membrane_stages(&strip(1e10, 1e-2), &rest)
                .unwrap()
                .is_empty()
        );
        let mut corot = strip(1e10, 1e-4);
        corot.material.membrane = "corotational".into();
        let mut system = build(&corot, &rest, false).unwrap().system;
        let (parameter, corot_stages) = super::membrane_stages(
            &corot,
            super::MembraneModel::Corotational,
            &rest,
            &mut system,
        )
        .unwrap();
        assert_eq!(parameter, "corotational-membrane.stiffness");
        assert!(system.parameter(parameter).is_ok());
        assert!(
            corot_stages.len() == stages.len()
                && corot_stages
                    .iter()
                    .zip(&stages)
                    .all(|(a, b)| (a / b - 1.0).abs() < 1e-12),
            "{corot_stages:?} vs {stages:?}"
        );
        let mut off = strip(1e10, 1e-4);
        off.solver.membrane_continuation = false;
        assert!(membrane_stages(&off, &rest).unwrap().is_empty());
    }

    #[test]
    fn membrane_continuation_reaches_the_same_equilibrium_in_fewer_iterations() {
        // A 1 mm strip of Y = 1e8 Pa bends down by most of its length: plain Newton needs 90 iterations.
        for membrane in ["stvk", "corotational"] {
            continued_and_plain_agree(membrane);
        }
    }

    /// `hinge run --static`'s progress lines, reporting every iteration (`every = 0`): one per accepted
    /// Newton iteration of every continuation stage, counting up, each naming its stage, the last with the
    /// final gradient norm; the solve is bitwise the one without an observer.
    #[test]
    fn static_progress_reports_each_iteration_and_leaves_the_solve_as_it_is() {
        use std::sync::{Arc, Mutex};
        // A stiff thin strip: several membrane stages.
        let scene = strip(1e10, 1e-4);
        let rest = scene.rest_mesh(None).unwrap();
        assert!(membrane_stages(&scene, &rest).unwrap().len() >= 2);
        let lines = Arc::new(Mutex::new(Vec::new()));
        let sink = lines.clone();
        let progress = static_progress(std::time::Duration::ZERO, move |line| {
            sink.lock().unwrap().push(line);
        });
        let observed = equilibrium_observed(
            &scene,
            &rest,
            None,
            super::Hooks {
                observer: Some(progress),
                ..super::Hooks::default()
            },
        )
        .unwrap();
        let plain = equilibrium(&scene, &rest, None, None, None).unwrap();
        assert_eq!(
            (
                observed.newton_iterations,
                observed.factorizations,
                observed.far_end_drop.to_bits(),
                observed.final_gradient_norm.to_bits()
            ),
            (
                plain.newton_iterations,
                plain.factorizations,
                plain.far_end_drop.to_bits(),
                plain.final_gradient_norm.to_bits()
            )
        );
        let lines = lines.lock().unwrap();
        assert_eq!(lines.len(), plain.newton_iterations, "{lines:?}");
        // Each line names its membrane stage: from 1 up, never back, the last at the scene's stiffness.
        let n = membrane_stages(&scene, &rest).unwrap().len() + 1;
        let mut stage = 1;
        for (k, line) in lines.iter().enumerate() {
            while stage < n && !line.starts_with(&format!("static: membrane stage {stage}/{n}, ")) {
                stage += 1;
            }
            assert!(
                line.starts_with(&format!(
                    "static: membrane stage {stage}/{n}, {} Newton iterations, gradient norm ",
                    k + 1
                )),
                "{line}"
            );
        }
        assert!(lines[0].starts_with(&format!("static: membrane stage 1/{n}, ")));
        assert!(
            lines[lines.len() - 1].starts_with(&format!("static: membrane stage {n}/{n}, ")),
            "{lines:?}"
        );
        let last = lines.last().unwrap();
        assert!(
            last.contains(&format!(
                "gradient norm {:.2e}, ",
                plain.final_gradient_norm
            )),
            "{last} vs {:e}",
            plain.final_gradient_norm
        );
    }

    /// A Newton step of the shell's implicit Euler (contact with the plane, a closed mesh of 7 686
    /// unknowns) gives the same bits in pools of 1 and 2 threads with the default linear solver. faer's
    /// rayon-parallel factorization (`FaerLlt::parallel`, the default before) does not on this matrix
    /// (printed), which made `hinge run shell-drop` depend on `--threads`.
    #[test]
    fn a_shell_drop_step_gives_the_same_bits_on_any_thread_count() {
        use hinge_core::nalgebra::Vector3;
        use hinge_solver::linear::{FaerLlt, LinearSolver};
        use hinge_solver::newton::{Inertia, Newton};
        let (scene, _) = load("shell-drop").unwrap();
        let rest = scene.rest_mesh(None).unwrap();
        let step = |threads: usize, parallel: bool| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let b = build(&scene, &rest, true).unwrap();
                let mut system = b.system;
                let solver: Box<dyn LinearSolver> = if parallel {
                    Box::new(FaerLlt::parallel())
                } else {
                    Box::new(FaerLlt::default())
                };
                // One Newton step (a factorization of the contact-stiffened, shifted Hessian) shows it.
                let params = hinge_solver::newton::NewtonParams {
                    single_iteration: true,
                    ..b.params
                };
                let mut newton = Newton::new(&system, &b.pins, solver, params).unwrap();
                // Squashed onto the plane at 3 m/s: contact, folds, shifted steps.
                let low = rest
                    .positions()
                    .iter()
                    .map(|p| p.z)
                    .fold(f64::INFINITY, f64::min);
                let x0: Vec<_> = rest
                    .positions()
                    .iter()
                    .map(|p| Vector3::new(p.x, p.y, low + 0.6 * (p.z - low) - 0.02))
                    .collect();
                let inertia = Inertia {
                    masses: b.masses.clone(),
                    x_hat: x0
                        .iter()
                        .map(|p| p + Vector3::new(0.0, 0.0, -3.0) * scene.dt)
                        .collect(),
                    dt: scene.dt,
                };
                let mut x = x0.clone();
                let st = newton
                    .minimize(&mut system, &mut x, Some(&inertia))
                    .unwrap();
                (x, st.iterations, st.factorizations)
            })
        };
        let (one, two) = (step(1, false), step(2, false));
        assert!(one == two, "{:?} vs {:?}", (one.1, one.2), (two.1, two.2));
        println!("default: {:?}", (one.1, one.2));
        let (p1, p2) = (step(1, true), step(2, true));
        println!(
            "faer's parallel factorization, 1 and 2 threads: {} {:?} {:?}",
            if p1 == p2 {
                "the same bits"
            } else {
                "different bits"
            },
            (p1.1, p1.2),
            (p2.1, p2.2)
        );
    }

    fn continued_and_plain_agree(membrane: &str) {
        let mut results = Vec::new();
        for on in [true, false] {
            let mut scene = strip(1e8, 1e-3);
            scene.material.membrane = membrane.into();
            scene.solver.membrane_continuation = on;
            let rest = scene.rest_mesh(None).unwrap();
            let s = equilibrium(&scene, &rest, None, None, None).unwrap();
            assert!(
                s.final_gradient_norm <= 1e-9,
                "{on}: {}",
                s.final_gradient_norm
            );
            results.push(s);
        }
        let (with, without) = (&results[0], &results[1]);
        assert!(with.far_end_drop > 0.2, "{}", with.far_end_drop);
        assert!(
            (with.far_end_drop / without.far_end_drop - 1.0).abs() < 1e-9,
            "{} vs {}",
            with.far_end_drop,
            without.far_end_drop
        );
        println!(
            "{membrane}: {} Newton iterations with the continuation, {} without",
            with.newton_iterations, without.newton_iterations
        );
        assert!(
            2 * with.newton_iterations < without.newton_iterations,
            "{membrane}: {} vs {}",
            with.newton_iterations,
            without.newton_iterations
        );
    }

    /// Set-up warnings go to [`super::Hooks::warn`] when one is given (the Python package's way), in the
    /// file's numbering with `names` and from 0 without, for dynamics and statics alike; none for a mild
    /// crease.
    #[test]
    fn set_up_warnings_reach_the_warn_hook_in_either_numbering() {
        let dir = std::env::temp_dir().join(format!("hinge-hooks-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // The hinge's edge is the file's vertices 2 and 5 (from 0: 1 and 4); the wing vertex 3 folded by
        // `fold` from flat about it. No gravity: the rest state is the equilibrium, and the runs succeed.
        let write = |fold: f64| {
            let (s, c) = fold.sin_cos();
            let obj = format!(
                "v 0.4 -0.9 0.5\nv 1 0 0.5\nv 0.5 {} {}\nv 2 0 0.5\nv 0 0 0.5\nf 1 5 2\nf 3 2 5\nf 4 2 3\n",
                0.8 * c,
                0.5 + 0.8 * s
            );
            std::fs::write(dir.join("pair.obj"), obj).unwrap();
            let path = dir.join("pair.toml");
            std::fs::write(
                &path,
                "name = \"pair\"\nframes = 1\ndt = 0.0166\ngravity = [0.0, 0.0, 0.0]\n[mesh]\n\
                 obj = \"pair.obj\"\n[material]\nyoung = 2e5\npoisson = 0.3\nthickness = 5e-4\n\
                 density = 0.1\n[bending]\nenergy = \"tan-bending\"\n",
            )
            .unwrap();
            load(path.to_str().unwrap()).unwrap()
        };
        for (fold, stiff) in [(std::f64::consts::PI - 1e-4, true), (2.5, false)] {
            let (scene, base) = write(fold);
            let (rest, numbering) = scene.rest_mesh_numbered(base.as_deref()).unwrap();
            for (names, edge) in [
                (None, "between vertices 1 and 4"),
                (numbering.as_ref(), "between vertices 2 and 5"),
            ] {
                for statics in [false, true] {
                    let mut seen: Vec<String> = Vec::new();
                    let hooks = super::Hooks {
                        names,
                        warn: Some(Box::new(|line: &str| seen.push(line.to_string()))),
                        ..super::Hooks::default()
                    };
                    let summary = if statics {
                        equilibrium_observed(&scene, &rest, None, hooks)
                    } else {
                        super::simulate_observed(&scene, &rest, None, hooks, |_, _, _, _| {})
                    };
                    assert!(summary.is_ok(), "{summary:?}");
                    assert_eq!(seen.len(), usize::from(stiff), "{seen:?}");
                    for line in &seen {
                        assert!(
                            line.starts_with(
                                "1 rest hinge is at least 1e6 times stiffer than flat"
                            ) && line.contains(edge)
                                && line.ends_with("Newton may need many iterations and substeps"),
                            "{line}"
                        );
                    }
                }
            }
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// A scene changed in code after validation (its fields are public) with an unknown bending energy is
    /// an error naming the key, not silently the tan energy.
    #[test]
    fn an_unknown_bending_energy_is_named_by_build() {
        let (mut scene, _) = load("drape").unwrap();
        let rest = scene.rest_mesh(None).unwrap();
        assert!(build(&scene, &rest, true).is_ok());
        scene.bending.energy = "tan".into();
        let err = build(&scene, &rest, true).err().unwrap();
        assert!(err.starts_with("bending.energy: unknown `tan`"), "{err}");
        scene.bending.energy = "tan-bending".into();
        scene.material.membrane = "linear".into();
        let err = build(&scene, &rest, true).err().unwrap();
        assert!(
            err.starts_with("material.membrane: unknown `linear`"),
            "{err}"
        );
    }
}

#[cfg(test)]
mod path_tests {
    use super::{ContactWatch, build};
    use crate::scene::load;
    use hinge_core::nalgebra::Vector3;

    /// A frame taken in substeps: the path test follows the substeps' ends. The centre vertex of a 3 × 3
    /// drape goes from 0.3 m above the sphere's centre (radius 0.25) to the centre at the first substep's
    /// end and on to 0.3 m above a point 0.6 m aside at the frame's end: the straight line between the
    /// frame's ends stays 0.3 m from the centre (no warning from it), the chain through the substep passes
    /// through it.
    #[test]
    fn the_path_test_follows_a_frame_through_its_substeps() {
        let (mut scene, _) = load("drape").unwrap();
        scene.set_resolution(2).unwrap();
        let rest = scene.rest_mesh(None).unwrap();
        let obstacles = build(&scene, &rest, true).unwrap().obstacles;
        let start: Vec<Vector3<f64>> = rest.positions().to_vec();
        assert_eq!(start.len(), 9);
        let centre = 4;
        assert!((start[centre] - Vector3::new(0.0, 0.0, 0.3)).norm() < 1e-12);
        let (mut mid, mut end) = (start.clone(), start.clone());
        mid[centre] = Vector3::zeros();
        end[centre] = Vector3::new(0.6, 0.0, 0.3);
        let dt = scene.dt;
        let lines = std::cell::RefCell::new(Vec::<String>::new());
        let mut warn = |l: &str| lines.borrow_mut().push(l.to_string());
        // Frame ends only (one substep): nothing.
        let mut watch =
            ContactWatch::start(&scene, &obstacles, &rest, (&start, 0.0, &[]), None, None);
        watch.check(
            &obstacles,
            dt,
            (&end, &[(end.clone(), dt)]),
            Some(1),
            Some(&mut warn),
        );
        assert!(lines.borrow().is_empty(), "{lines:?}");
        // Through the substep: one line naming the centre vertex, 0 m from the centre.
        let mut watch =
            ContactWatch::start(&scene, &obstacles, &rest, (&start, 0.0, &[]), None, None);
        let substeps = [(mid.clone(), 0.5 * dt), (end.clone(), dt)];
        watch.check(&obstacles, dt, (&end, &substeps), Some(1), Some(&mut warn));
        let lines = lines.borrow();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            lines[0].starts_with(
                "frame 1: 1 vertex went through obstacles[0] since frame 0 (its path through the frame's 2 \
                 substeps relative to the sphere passes within half its radius of its centre; the closest, \
                 vertex 4, 0.000e0 m from it)"
            ),
            "{lines:?}"
        );
    }
}
