//! `hinge run`: simulate a built-in scene with implicit Euler, writing OBJ frames and `summary.json`.
//!
//! Built-in scenes are defined in code for now (the TOML scene format of the scenes issue is not built
//! yet): `drape`, after the paper's §7.1 — a square cloth falls onto a sphere; StVK membrane + tan bending
//! (stiffness from material, Eq. 11) + gravity + sphere contact; no damping.

use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use hinge_core::bending::{BendingModel, Method};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::Vector3;
use hinge_core::obj::write_obj;
use hinge_energies::bending::{TanBending, stiffness_from_material};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::StvkMembrane;
use hinge_energies::pins::Pins;
use hinge_solver::linear::default_solver;
use hinge_solver::newton::{ImplicitEuler, NewtonParams};

/// Arguments of `hinge run`.
#[derive(Args, Default)]
pub struct RunArgs {
    /// Built-in scene name (`drape`).
    #[arg(default_value = "drape")]
    pub scene: String,
    /// Frames to simulate (default: the scene's).
    #[arg(long)]
    pub frames: Option<usize>,
    /// Cells per side of the cloth (default: the scene's).
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Output directory (default: out/SCENE).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Do not write OBJ frames (summary only).
    #[arg(long)]
    pub no_frames: bool,
}

/// The drape scene's parameters.
#[derive(Debug, Clone)]
pub struct Drape {
    /// Cells per side.
    pub cells: usize,
    /// Frames (one implicit-Euler step each).
    pub frames: usize,
    /// Time step (s).
    pub dt: f64,
    /// Sphere radius (m); the sphere is centred at the origin.
    pub radius: f64,
    /// Initial height of the flat cloth (m).
    pub height: f64,
    /// Contact stiffness (N/m) and margin (m).
    pub contact: (f64, f64),
}

impl Default for Drape {
    fn default() -> Self {
        Self {
            cells: 30,
            frames: 90,
            dt: 1.0 / 60.0,
            radius: 0.25,
            height: 0.3,
            contact: (2e3, 0.005),
        }
    }
}

/// What a run produced.
#[derive(Debug, Clone)]
pub struct RunSummary {
    /// Frames simulated.
    pub frames: usize,
    /// Newton iterations, summed.
    pub newton_iterations: usize,
    /// Line-search halvings, summed.
    pub line_search_steps: usize,
    /// Seconds in bending evaluation + assembly.
    pub bending_seconds: f64,
    /// Seconds in the other energies.
    pub other_energy_seconds: f64,
    /// Seconds in factorizations and solves.
    pub linear_solve_seconds: f64,
    /// Wall time of the whole run.
    pub total_seconds: f64,
    /// Smallest signed distance of a vertex to the sphere at the end (negative: inside).
    pub min_clearance: f64,
    /// Final positions.
    pub positions: Vec<Vector3<f64>>,
    /// Vertex count.
    pub n_vertices: usize,
}

/// Simulates the drape scene; writes frames to `out` when given.
///
/// # Errors
/// A one-line message (a failed step names the frame and the solver's diagnostics).
pub fn simulate_drape(
    scene: &Drape,
    out: Option<&std::path::Path>,
    mut progress: impl FnMut(usize, usize, f64),
) -> Result<RunSummary, String> {
    let start = Instant::now();
    let flat = grid(scene.cells, scene.cells, 1.0, 1.0, Diagonal::Alternating)
        .map_err(|e| e.to_string())?;
    let x0: Vec<Vector3<f64>> = flat
        .positions()
        .iter()
        .map(|p| Vector3::new(p.x - 0.5, p.y - 0.5, scene.height))
        .collect();
    let rest = flat.with_positions(x0.clone()).map_err(|e| e.to_string())?;
    let n = rest.n_vertices();
    let (young, poisson, thickness, density) = (2e5, 0.3, 5e-4, 0.1);
    let k_bend = stiffness_from_material(young, thickness, poisson);
    let bending = BendingModel::new(&rest, TanBending { k: k_bend }).map_err(|e| e.to_string())?;
    let masses = lumped_masses(&rest, density);
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(HingeTerm::new("bending", bending, Method::Refactored)),
        Box::new(StvkMembrane::new(&rest, young, poisson, thickness).map_err(|e| e.to_string())?),
        Box::new(
            Gravity::new(masses.clone(), Vector3::new(0.0, 0.0, -9.81))
                .map_err(|e| e.to_string())?,
        ),
        Box::new(
            Contact::new(
                n,
                Obstacle::Sphere {
                    center: Vector3::zeros(),
                    radius: scene.radius,
                },
                scene.contact.0,
                scene.contact.1,
            )
            .map_err(|e| e.to_string())?,
        ),
    ];
    let mut system = System::new(n, terms).map_err(|e| e.to_string())?;
    let params = NewtonParams {
        gradient_tolerance: 1e-6,
        step_tolerance: 1e-9,
        max_iterations: 100,
        ..NewtonParams::default()
    };
    let mut stepper = ImplicitEuler::new(
        &system,
        scene.dt,
        masses,
        Pins::default(),
        default_solver(),
        params,
    )
    .map_err(|e| e.to_string())?;
    let (mut x, mut v) = (x0, vec![Vector3::zeros(); n]);
    let mut summary = RunSummary {
        frames: scene.frames,
        newton_iterations: 0,
        line_search_steps: 0,
        bending_seconds: 0.0,
        other_energy_seconds: 0.0,
        linear_solve_seconds: 0.0,
        total_seconds: 0.0,
        min_clearance: f64::INFINITY,
        positions: Vec::new(),
        n_vertices: n,
    };
    for frame in 0..scene.frames {
        let t = Instant::now();
        let stats = stepper
            .step(&mut system, &mut x, &mut v)
            .map_err(|e| format!("frame {frame}: {e}"))?;
        summary.newton_iterations += stats.iterations;
        summary.line_search_steps += stats.line_search_steps;
        summary.linear_solve_seconds += stats.factor_seconds + stats.solve_seconds;
        for (name, sec) in system.take_timings() {
            if name == "bending" {
                summary.bending_seconds += sec;
            } else {
                summary.other_energy_seconds += sec;
            }
        }
        if let Some(dir) = out {
            write_obj(
                dir.join(format!("frame_{frame:04}.obj")),
                &x,
                rest.triangles(),
            )
            .map_err(|e| e.to_string())?;
        }
        progress(frame, stats.iterations, t.elapsed().as_secs_f64());
    }
    summary.min_clearance = x
        .iter()
        .map(|p| p.norm() - scene.radius)
        .fold(f64::INFINITY, f64::min);
    summary.positions = x;
    summary.total_seconds = start.elapsed().as_secs_f64();
    Ok(summary)
}

/// Runs `hinge run`.
pub fn run(args: RunArgs) -> Result<(), String> {
    if args.scene != "drape" {
        return Err(format!("unknown scene `{}` (built-in: drape)", args.scene));
    }
    let mut scene = Drape::default();
    if let Some(f) = args.frames {
        scene.frames = f;
    }
    if let Some(r) = args.resolution {
        if r < 2 {
            return Err("--resolution must be at least 2".into());
        }
        scene.cells = r;
    }
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 {
        return Err("--threads must be at least 1".into());
    }
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(&args.scene));
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| e.to_string())?;
    println!(
        "hinge run drape: {0}×{0} cells ({1} vertices), {2} frames of {3:.4} s, {threads} threads → {4}",
        scene.cells,
        (scene.cells + 1) * (scene.cells + 1),
        scene.frames,
        scene.dt,
        out.display()
    );
    let frames_dir = (!args.no_frames).then_some(out.as_path());
    let summary = pool.install(|| {
        simulate_drape(&scene, frames_dir, |frame, iterations, seconds| {
            println!(
                "frame {:>4}/{}: {iterations} Newton iterations, {:.1} ms",
                frame + 1,
                scene.frames,
                seconds * 1e3
            );
            let _ = std::io::stdout().flush();
        })
    })?;
    let json = serde_json::json!({
        "scene": "drape",
        "frames": summary.frames,
        "n_vertices": summary.n_vertices,
        "newton_iterations": summary.newton_iterations,
        "line_search_steps": summary.line_search_steps,
        "seconds": {
            "bending_evaluation_and_assembly": summary.bending_seconds,
            "other_energies": summary.other_energy_seconds,
            "linear_solve": summary.linear_solve_seconds,
            "total": summary.total_seconds,
        },
        "min_clearance_to_sphere": summary.min_clearance,
    });
    let path = out.join("summary.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&json).map_err(|e| e.to_string())?,
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    println!(
        "done: {} frames, {} Newton iterations ({} line-search halvings); time: bending {:.3} s, other energies {:.3} s, linear solve {:.3} s, total {:.3} s; min clearance to the sphere {:.2e} m",
        summary.frames,
        summary.newton_iterations,
        summary.line_search_steps,
        summary.bending_seconds,
        summary.other_energy_seconds,
        summary.linear_solve_seconds,
        summary.total_seconds,
        summary.min_clearance
    );
    Ok(())
}
