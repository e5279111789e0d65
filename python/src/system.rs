//! `hinge.System`, `hinge.solve_static` and `hinge.ImplicitEuler`: energies composed on one mesh, and the
//! Newton solvers of hinge-solver on them.

use hinge_cli::run::{StiffRest, solver_message};
use hinge_cli::scene::CustomPsi;
use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, HessianMode, Method, Parallelism, Request};
use hinge_core::energy::SystemEvaluation;
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::export::CsrLayout;
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::HingePsi;
use hinge_core::psi::runtime::ParamValue;
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::drag::Drag;
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::MembraneModel;
use hinge_energies::pins::Pins;
use hinge_energies::spring::MassSpring;
use hinge_solver::adjoint::{
    Adjoint, FieldCheck, Fit, FitOptions, FitResult, FitVariable, Link, TargetLoss,
};
use hinge_solver::linear::FaerLlt;
use hinge_solver::newton::{
    DEFINITE_HOLD, DEFINITE_SHIFT_RATIO, Globalization, ImplicitEuler as Stepper,
    MAX_ITERATIONS_CEILING, MAX_ITERATIONS_CEILING_TEXT, Newton, NewtonParams, NewtonStats,
    SubstepPolicy,
};
use hinge_solver::statics::{
    continuation_scales, continued_start_all, mean_edge_length, minimize_continued_all,
};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::{
    detached, interruptible, mesh_from, parse_hessian, parse_method, psi_spec, value_error,
};

/// One term of a system, as specified (built into energies when the system is used).
#[derive(Clone)]
enum Term {
    Bending {
        name: String,
        text: String,
        values: Vec<(String, ParamValue)>,
        mode: HessianMode,
        method: Method,
    },
    Membrane {
        young: f64,
        poisson: f64,
        thickness: f64,
        kind: MembraneModel,
    },
    Springs {
        k: f64,
        compressive: bool,
    },
    Gravity {
        density: f64,
        g: [f64; 3],
    },
    Drag {
        density: f64,
        rate: f64,
    },
    Sphere {
        center: [f64; 3],
        radius: f64,
        stiffness: f64,
        margin: f64,
        smoothing: f64,
        barrier: bool,
    },
    Plane {
        point: [f64; 3],
        normal: [f64; 3],
        stiffness: f64,
        margin: f64,
        smoothing: f64,
        barrier: bool,
    },
}

/// A term, with the rest hinges a bending term makes at least a million times stiffer than flat
/// ([`StiffRest`]; `None` for the other terms).
type BuiltTerm = (Box<dyn Energy>, Option<StiffRest>);

/// A bending term named `name` of ψ `psi` on `rest`, its Hessian in `mode`, evaluated by `method`.
fn bending_term<P: HingePsi + Send + 'static>(
    rest: &TriMesh,
    name: &str,
    psi: P,
    mode: HessianMode,
    method: Method,
) -> Result<BuiltTerm, String> {
    let mut m = BendingModel::new(rest, psi).map_err(|e| e.to_string())?;
    m.set_hessian_mode(mode).map_err(|e| e.to_string())?;
    let stiff = StiffRest::of(&m);
    Ok((Box::new(HingeTerm::new(name, m, method)), stiff))
}

fn build_term(rest: &TriMesh, t: &Term) -> Result<BuiltTerm, String> {
    let e = |e: hinge_core::EvalError| e.to_string();
    let n = rest.n_vertices();
    let energy: Box<dyn Energy> = match t {
        Term::Bending {
            name,
            text,
            values,
            mode,
            method,
        } => {
            return match CustomPsi::new(text, values.clone())? {
                CustomPsi::Small(p) => bending_term(rest, name, p, *mode, *method),
                CustomPsi::Large(p) => bending_term(rest, name, p, *mode, *method),
            };
        }
        Term::Membrane {
            young,
            poisson,
            thickness,
            kind,
        } => kind.build(rest, *young, *poisson, *thickness).map_err(e)?,
        Term::Springs { k, compressive } => Box::new(
            MassSpring::new(rest, *k)
                .map_err(e)?
                .drop_compressive_term(!compressive),
        ),
        Term::Gravity { density, g } => {
            Box::new(Gravity::new(lumped_masses(rest, *density), Vector3::from(*g)).map_err(e)?)
        }
        Term::Drag { density, rate } => {
            Box::new(Drag::new(lumped_masses(rest, *density), *rate).map_err(e)?)
        }
        Term::Sphere {
            center,
            radius,
            stiffness,
            margin,
            smoothing,
            barrier,
        } => Box::new(
            Contact::new(
                n,
                Obstacle::Sphere {
                    center: Vector3::from(*center),
                    radius: *radius,
                },
                *stiffness,
                *margin,
            )
            .and_then(|c| c.with_smoothing(*smoothing))
            .and_then(|c| if *barrier { c.with_barrier() } else { Ok(c) })
            .map_err(e)?,
        ),
        Term::Plane {
            point,
            normal,
            stiffness,
            margin,
            smoothing,
            barrier,
        } => Box::new(
            Contact::new(
                n,
                Obstacle::Plane {
                    point: Vector3::from(*point),
                    normal: Vector3::from(*normal),
                },
                *stiffness,
                *margin,
            )
            .and_then(|c| c.with_smoothing(*smoothing))
            .and_then(|c| if *barrier { c.with_barrier() } else { Ok(c) })
            .map_err(e)?,
        ),
    };
    Ok((energy, None))
}

/// Energies composed on one rest mesh, with pinned vertices.
#[pyclass(module = "hinge._hinge", name = "System")]
pub struct PySystem {
    rest: TriMesh,
    terms: Vec<Term>,
    pins: Vec<usize>,
    /// The built system, its CSR layout and its evaluation buffers (rebuilt after a change).
    built: Option<(System, CsrLayout, SystemEvaluation)>,
    /// Parameters set with `set_parameter` (or by `fit`), applied again whenever the system is rebuilt.
    overrides: Vec<(String, Vec<f64>)>,
}

impl PySystem {
    fn build(&self) -> Result<System, String> {
        if self.terms.is_empty() {
            return Err(
                "the system has no energies: add some (add_bending, add_membrane, …)".into(),
            );
        }
        let terms = self
            .terms
            .iter()
            .map(|t| build_term(&self.rest, t).map(|(energy, _)| energy))
            .collect::<Result<Vec<_>, _>>()?;
        let mut system = System::new(self.rest.n_vertices(), terms).map_err(|e| e.to_string())?;
        for (name, values) in &self.overrides {
            system
                .set_parameter(name, values)
                .map_err(|e| e.to_string())?;
        }
        Ok(system)
    }

    /// The built system (built now if needed).
    fn system(&mut self, py: Python<'_>) -> PyResult<&mut System> {
        self.ensure(py)?;
        match &mut self.built {
            Some((s, _, _)) => Ok(s),
            None => Err(value_error("system not built")),
        }
    }

    /// Records `name = values` (already accepted by the built system) for rebuilds.
    fn record(&mut self, name: &str, values: Vec<f64>) {
        self.overrides.retain(|(n, _)| n != name);
        self.overrides.push((name.to_string(), values));
    }

    fn ensure(&mut self, py: Python<'_>) -> PyResult<()> {
        if self.built.is_none() {
            let s = detached(py, || self.build()).map_err(value_error)?;
            let csr = CsrLayout::new(s.pattern());
            let out = s.new_output();
            self.built = Some((s, csr, out));
        }
        Ok(())
    }

    /// Adds a term; returns a bending term's stiff rest hinges ([`StiffRest`]), if any.
    fn add(&mut self, t: Term) -> PyResult<Option<StiffRest>> {
        // Built once to check the parameters now (the error names the term), then kept.
        let (_, stiff) = build_term(&self.rest, &t).map_err(value_error)?;
        self.terms.push(t);
        self.built = None;
        Ok(stiff)
    }

    /// The solvers' pins: the user's, and the vertices of no triangle (no mass, no stiffness: held).
    fn pins(&self) -> PyResult<Pins> {
        let mut pinned = self.pins.clone();
        pinned.extend(self.rest.unreferenced_vertices());
        Pins::new(self.rest.n_vertices(), pinned).map_err(value_error)
    }

    fn positions(&self, x: &PyReadonlyArray2<'_, f64>) -> PyResult<Vec<Vector3<f64>>> {
        let s = x.shape();
        if s.len() != 2 || s[1] != 3 || s[0] != self.rest.n_vertices() {
            return Err(value_error(format!(
                "positions must have shape ({}, 3), got {s:?}",
                self.rest.n_vertices()
            )));
        }
        let a = x.as_array();
        Ok((0..s[0])
            .map(|i| Vector3::new(a[[i, 0]], a[[i, 1]], a[[i, 2]]))
            .collect())
    }
}

fn vec3(name: &str, v: Vec<f64>) -> PyResult<[f64; 3]> {
    <[f64; 3]>::try_from(v)
        .map_err(|v| value_error(format!("{name} must have 3 components, got {}", v.len())))
}

fn to_array<'py>(py: Python<'py>, x: &[Vector3<f64>]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let rows: Vec<Vec<f64>> = x.iter().map(|p| vec![p.x, p.y, p.z]).collect();
    PyArray2::from_vec2(py, &rows).map_err(value_error)
}

fn stats_dict<'py>(py: Python<'py>, s: &NewtonStats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("newton_iterations", s.iterations)?;
    d.set_item("line_search_steps", s.line_search_steps)?;
    d.set_item("factorizations", s.factorizations)?;
    d.set_item("definite_iterations", s.definite_iterations)?;
    d.set_item("accelerated_iterations", s.accelerated_iterations)?;
    d.set_item(
        "final_gradient_norm",
        s.gradient_norms.last().copied().unwrap_or(f64::NAN),
    )?;
    d.set_item("gradient_norms", s.gradient_norms.clone())?;
    d.set_item("largest_residual", s.largest_residual)?;
    Ok(d)
}

#[pymethods]
impl PySystem {
    /// `System(V, F)`: an empty system on the rest mesh.
    #[new]
    fn new(v: PyReadonlyArray2<'_, f64>, f: PyReadonlyArray2<'_, i64>) -> PyResult<Self> {
        Ok(Self {
            rest: mesh_from(&v, &f)?,
            terms: Vec::new(),
            pins: Vec::new(),
            built: None,
            overrides: Vec::new(),
        })
    }

    /// A hinge bending term: a built-in energy or a ψ string, with its parameters, assembling the Hessian
    /// `hessian` names (`exact`, `gauss-newton`, `projected`) by the per-hinge `method` (`refactored`,
    /// `per_hinge`, `autodiff`). Returns the set-up warning of rest hinges at least
    /// [`hinge_cli::run::STIFF_REST`] times stiffer than flat, if any.
    #[pyo3(signature = (energy=None, psi=None, params=None, hessian="exact", method="refactored"))]
    fn add_bending(
        &mut self,
        energy: Option<&str>,
        psi: Option<&str>,
        params: Option<&Bound<'_, PyDict>>,
        hessian: &str,
        method: &str,
    ) -> PyResult<Option<String>> {
        let mode = parse_hessian(hessian)?;
        let method = parse_method(method)?;
        let (name, text, values) = psi_spec(energy, psi, params)?;
        let stiff = self.add(Term::Bending {
            name,
            text,
            values,
            mode,
            method,
        })?;
        Ok(stiff.map(|s| s.describe(None)))
    }

    /// A membrane (Young's modulus, Poisson ratio, thickness): `kind` `stvk` (St. Venant–Kirchhoff),
    /// `corotational` (½ k A ‖F − R‖², k = Y h / (1 + ν)) or `neo-hookean` (compressible neo-Hookean,
    /// infinite at zero area).
    #[pyo3(signature = (young, poisson, thickness, kind="stvk"))]
    fn add_membrane(
        &mut self,
        young: f64,
        poisson: f64,
        thickness: f64,
        kind: &str,
    ) -> PyResult<()> {
        let kind: MembraneModel = kind
            .parse()
            .map_err(|e| value_error(format!("membrane kind: {e}")))?;
        self.add(Term::Membrane {
            young,
            poisson,
            thickness,
            kind,
        })
        .map(|_| ())
    }

    /// Mass-spring edges of stiffness k (`compressive=False` drops the compressive Hessian term).
    #[pyo3(signature = (k, compressive=true))]
    fn add_springs(&mut self, k: f64, compressive: bool) -> PyResult<()> {
        self.add(Term::Springs { k, compressive }).map(|_| ())
    }

    /// Gravity on lumped masses of `density` (mass per area).
    #[pyo3(signature = (density, g=vec![0.0, 0.0, -9.81]))]
    fn add_gravity(&mut self, density: f64, g: Vec<f64>) -> PyResult<()> {
        self.add(Term::Gravity {
            density,
            g: vec3("g", g)?,
        })
        .map(|_| ())
    }

    /// Mass-proportional drag of `rate` (1/s) on lumped masses of `density`.
    fn add_drag(&mut self, density: f64, rate: f64) -> PyResult<()> {
        self.add(Term::Drag { density, rate }).map(|_| ())
    }

    /// Penalty contact with a sphere; `smoothing` > 0 makes the penalty C² over the first `smoothing` of
    /// the margin (0: quadratic); `barrier` a logarithmic barrier reaching `margin` instead.
    #[pyo3(signature = (center, radius, stiffness, margin=0.0, smoothing=0.0, barrier=false))]
    fn add_sphere(
        &mut self,
        center: Vec<f64>,
        radius: f64,
        stiffness: f64,
        margin: f64,
        smoothing: f64,
        barrier: bool,
    ) -> PyResult<()> {
        self.add(Term::Sphere {
            center: vec3("center", center)?,
            radius,
            stiffness,
            margin,
            smoothing,
            barrier,
        })
        .map(|_| ())
    }

    /// Penalty contact with a plane (vertices pushed to the side `normal` points to); `smoothing` and
    /// `barrier` as for `add_sphere`.
    #[pyo3(signature = (point, normal, stiffness, margin=0.0, smoothing=0.0, barrier=false))]
    fn add_plane(
        &mut self,
        point: Vec<f64>,
        normal: Vec<f64>,
        stiffness: f64,
        margin: f64,
        smoothing: f64,
        barrier: bool,
    ) -> PyResult<()> {
        self.add(Term::Plane {
            point: vec3("point", point)?,
            normal: vec3("normal", normal)?,
            stiffness,
            margin,
            smoothing,
            barrier,
        })
        .map(|_| ())
    }

    /// Pins vertices (held at their positions by the solvers).
    fn pin(&mut self, vertices: Vec<i64>) -> PyResult<()> {
        let mut all = self.pins.clone();
        for v in vertices {
            all.push(
                usize::try_from(v).map_err(|_| value_error(format!("pin: negative vertex {v}")))?,
            );
        }
        Pins::new(self.rest.n_vertices(), all.clone()).map_err(value_error)?;
        self.pins = all;
        Ok(())
    }

    /// The pinned vertices.
    #[getter]
    fn pinned(&self) -> Vec<usize> {
        self.pins.clone()
    }

    /// The vertices in no triangle, ascending (no mass, no stiffness: the solvers hold them).
    #[getter]
    fn unreferenced_vertices(&self) -> Vec<usize> {
        self.rest.unreferenced_vertices()
    }

    /// `(vertex, first)` pairs of triangle vertices at exactly the rest position of a lower-numbered one
    /// (a mesh split along seams: nothing couples the copies).
    #[getter]
    fn coincident_vertices(&self) -> Vec<(usize, usize)> {
        self.rest.coincident_vertices()
    }

    /// Number of vertices.
    #[getter]
    fn n_vertices(&self) -> usize {
        self.rest.n_vertices()
    }

    /// The terms' names, in order; the k-th term of a name an earlier term has is `NAME#k`, as in parameter
    /// names (`custom#2.k`).
    fn term_names(&self) -> Vec<String> {
        let names: Vec<String> = self
            .terms
            .iter()
            .map(|t| match t {
                Term::Bending { name, .. } => name.clone(),
                Term::Membrane { kind, .. } => kind.energy_name().into(),
                Term::Springs { .. } => "mass-spring".into(),
                Term::Gravity { .. } => "gravity".into(),
                Term::Drag { .. } => "drag".into(),
                Term::Sphere { .. } => "contact-sphere".into(),
                Term::Plane { .. } => "contact-plane".into(),
            })
            .collect();
        hinge_core::energy::term_labels(names.iter().map(String::as_str))
    }

    /// The differentiable parameters of the system's terms as `[(name, length)]`, named `TERM.NAME`
    /// (`bending.k`, `bending.theta_bar`, `membrane.young`, `gravity.g`, …).
    fn parameters(&mut self, py: Python<'_>) -> PyResult<Vec<(String, usize)>> {
        Ok(self
            .system(py)?
            .parameters()
            .into_iter()
            .map(|p| (p.name, p.len))
            .collect())
    }

    /// The values of parameter `name` (see `parameters()`).
    fn parameter(&mut self, py: Python<'_>, name: &str) -> PyResult<Vec<f64>> {
        self.system(py)?.parameter(name).map_err(value_error)
    }

    /// Sets parameter `name` (as many values as it has); kept when the system is rebuilt.
    fn set_parameter(&mut self, py: Python<'_>, name: &str, values: Vec<f64>) -> PyResult<()> {
        self.system(py)?
            .set_parameter(name, &values)
            .map_err(value_error)?;
        self.record(name, values);
        Ok(())
    }

    /// `(indptr, indices)` of the system Hessian's full CSR structure.
    fn pattern<'py>(&mut self, py: Python<'py>) -> PyResult<crate::CsrStructure<'py>> {
        self.ensure(py)?;
        let Some((_, csr, _)) = &self.built else {
            return Err(value_error("system not built"));
        };
        let p: Vec<i64> = csr.row_ptr().iter().map(|&x| x as i64).collect();
        let c: Vec<i64> = csr.col_idx().iter().map(|&x| x as i64).collect();
        Ok((p.into_pyarray(py), c.into_pyarray(py)))
    }

    /// `(E, g, data)` of the whole system at `x` (data in `pattern()` order, None without `hessian`); with
    /// `definite`, the positive semi-definite Hessian of every term ([`Request::definite`]) instead of the
    /// exact one.
    #[pyo3(signature = (x, hessian=true, definite=false))]
    #[allow(clippy::type_complexity)]
    fn evaluate_raw<'py>(
        &mut self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        hessian: bool,
        definite: bool,
    ) -> PyResult<(
        f64,
        Bound<'py, PyArray1<f64>>,
        Option<Bound<'py, PyArray1<f64>>>,
    )> {
        let pos = self.positions(&x)?;
        self.ensure(py)?;
        let Some((sys, csr, out)) = &mut self.built else {
            return Err(value_error("system not built"));
        };
        let request = Request {
            value: true,
            gradient: true,
            hessian,
            definite: hessian && definite,
        };
        let r = detached(py, || -> Result<_, String> {
            // Values that overflow f64 raise, naming the term and the vertex (not NaN in the arrays).
            sys.evaluate_into(&pos, request, Parallelism::Rayon, out)
                .map_err(|e| e.to_string())?;
            let mut data = Vec::new();
            if hessian {
                data = vec![0.0; csr.nnz()];
                csr.scatter(&out.hessian, &mut data)
                    .map_err(|e| e.to_string())?;
            }
            Ok((out.energy, out.gradient.clone(), data))
        });
        let (energy, g, data) = r.map_err(value_error)?;
        Ok((
            energy,
            g.into_pyarray(py),
            hessian.then(|| data.into_pyarray(py)),
        ))
    }
}

/// Newton's settings from Python (the keyword arguments `solve_static` and `ImplicitEuler` share).
#[derive(Debug, Clone, Copy)]
struct PyNewtonOptions<'a> {
    max_iterations: usize,
    gradient_tolerance: f64,
    globalization: &'a str,
    extrapolate: bool,
    relative_gradient_tolerance: f64,
    relative_step_tolerance: f64,
    remember_shift: bool,
    geodesic_acceleration: bool,
    definite_shift_ratio: f64,
    definite_hold: usize,
}

/// Newton's settings from Python: the limits, the [`Globalization`] by its scene-file name,
/// [`NewtonParams::extrapolate`], the unit-free stopping tests (the step test against the rest mesh's mean
/// edge length, as the CLI does), [`NewtonParams::remember_shift`],
/// [`NewtonParams::geodesic_acceleration`] and [`NewtonParams::definite_shift_ratio`].
fn newton_params(o: PyNewtonOptions<'_>, rest: &TriMesh) -> PyResult<NewtonParams> {
    if !(1..=MAX_ITERATIONS_CEILING).contains(&o.max_iterations) {
        return Err(value_error(format!(
            "max_iterations must be from 1 to {MAX_ITERATIONS_CEILING_TEXT}, got {}",
            o.max_iterations
        )));
    }
    // As in scene files: 0 leaves convergence to the other stopping tests (the relative ones, the step
    // tests, the stall rule).
    if !(o.gradient_tolerance >= 0.0 && o.gradient_tolerance.is_finite()) {
        return Err(value_error(format!(
            "gradient_tolerance must be finite and ≥ 0 (0: the other stopping tests only), got {}",
            o.gradient_tolerance
        )));
    }
    for (name, v) in [
        ("relative_gradient_tolerance", o.relative_gradient_tolerance),
        ("relative_step_tolerance", o.relative_step_tolerance),
    ] {
        if !(v >= 0.0 && v.is_finite()) {
            return Err(value_error(format!(
                "{name} must be finite and ≥ 0 (0: off), got {v}"
            )));
        }
    }
    if o.definite_shift_ratio.is_nan() || o.definite_shift_ratio < 0.0 {
        return Err(value_error(format!(
            "definite_shift_ratio must be ≥ 0 (inf: never), got {}",
            o.definite_shift_ratio
        )));
    }
    let globalization = Globalization::from_name(o.globalization).ok_or_else(|| {
        value_error(format!(
            "globalization must be \"shifted-exact\" or \"project-on-demand\", got {:?}",
            o.globalization
        ))
    })?;
    let params = NewtonParams {
        max_iterations: o.max_iterations,
        gradient_tolerance: o.gradient_tolerance,
        globalization,
        extrapolate: o.extrapolate,
        relative_gradient_tolerance: o.relative_gradient_tolerance,
        relative_step_tolerance: o.relative_step_tolerance,
        length_scale: mean_edge_length(rest),
        remember_shift: o.remember_shift,
        geodesic_acceleration: o.geodesic_acceleration,
        definite_shift_ratio: o.definite_shift_ratio,
        definite_hold: o.definite_hold,
        ..NewtonParams::default()
    };
    // The library's check of every parameter: the ones above with their keyword's name first, the rest
    // (`definite_hold`) named as `NewtonParams` fields.
    params.validate().map_err(value_error)?;
    Ok(params)
}

/// `solve_static(system, X0, max_iterations=500, gradient_tolerance=1e-8, globalization="shifted-exact",
/// extrapolate=True, membrane_continuation=True, relative_gradient_tolerance=0.0,
/// relative_step_tolerance=0.0, remember_shift=True, geodesic_acceleration=True,
/// definite_hold=DEFINITE_HOLD)`: the equilibrium ∇E = 0 from `X0` (pinned vertices
/// held at their `X0` positions) by Newton, through softer StVK membranes first when
/// [`hinge_solver::statics::membrane_scales`] asks for it and `membrane_continuation` is set. Returns
/// `(X, stats)`; a failed solve raises `ValueError` with the solver's message.
#[pyfunction]
#[pyo3(signature = (system, x0, max_iterations=500, gradient_tolerance=1e-8, globalization="shifted-exact", extrapolate=true, membrane_continuation=true, relative_gradient_tolerance=0.0, relative_step_tolerance=0.0, remember_shift=true, geodesic_acceleration=true, definite_hold=DEFINITE_HOLD))]
#[allow(clippy::too_many_arguments)]
pub fn solve_static<'py>(
    py: Python<'py>,
    system: &mut PySystem,
    x0: PyReadonlyArray2<'py, f64>,
    max_iterations: usize,
    gradient_tolerance: f64,
    globalization: &str,
    extrapolate: bool,
    membrane_continuation: bool,
    relative_gradient_tolerance: f64,
    relative_step_tolerance: f64,
    remember_shift: bool,
    geodesic_acceleration: bool,
    definite_hold: usize,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let mut x = system.positions(&x0)?;
    let params = newton_params(
        PyNewtonOptions {
            max_iterations,
            gradient_tolerance,
            globalization,
            extrapolate,
            relative_gradient_tolerance,
            relative_step_tolerance,
            remember_shift,
            geodesic_acceleration,
            // Statics have no inertia: the ratio does not apply.
            definite_shift_ratio: DEFINITE_SHIFT_RATIO,
            definite_hold,
        },
        &system.rest,
    )?;
    let pins = system.pins()?;
    system.ensure(py)?;
    let (rest, terms) = (&system.rest, &system.terms);
    let Some((sys, _, _)) = &mut system.built else {
        return Err(value_error("system not built"));
    };
    let (r, signal) = interruptible(py, |stop| -> Result<NewtonStats, String> {
        let (parameters, stages) = if membrane_continuation {
            continuation(terms, sys, rest)?
        } else {
            (Vec::new(), Vec::new())
        };
        let parameters: Vec<&str> = parameters.iter().map(String::as_str).collect();
        let mut newton = Newton::new(sys, &pins, Box::new(FaerLlt::default()), params)
            .map_err(|e| e.to_string())?;
        newton.set_stop(Some(stop.clone()));
        minimize_continued_all(&mut newton, sys, &mut x, &parameters, &stages)
            .map_err(|e| format!("static solve: {}", solver_message(&e, None)))
    });
    // Ctrl-C: the solve ended with the system's parameters set back; nothing is returned.
    if let Some(e) = signal {
        return Err(e);
    }
    let stats = r.map_err(value_error)?;
    Ok((to_array(py, &x)?, stats_dict(py, &stats)?))
}

/// The membrane continuation of a static solve on `sys` (built from `terms`): the StVK membranes'
/// `young` (every StVK membrane term, `membrane`, `membrane#2`, …) with [`continuation_scales`] of their
/// summed stiffness `Σ Yᵢ hᵢ` (what [`hinge_solver::statics::membrane_scales`] gives for one), or else the
/// co-rotational membranes' `stiffness` with [`continuation_scales`] of the first one's thickness and the
/// Young's modulus its stiffness stands for (`k (1 + ν) / h`, so a stiffness set with
/// `set_parameter` counts); no stages when neither needs them.
fn continuation(
    terms: &[Term],
    sys: &mut System,
    rest: &TriMesh,
) -> Result<(Vec<String>, Vec<f64>), String> {
    // The membrane terms of one kind with their labels in the system.
    let labels = sys.term_labels();
    // `young`-carrying (StVK and neo-Hookean) or co-rotational.
    let membranes = |corotational: bool| -> Vec<(&Term, &String)> {
        terms
            .iter()
            .zip(&labels)
            .filter(|(t, _)| {
                matches!(t, Term::Membrane { kind, .. }
                    if (*kind == MembraneModel::Corotational) == corotational)
            })
            .collect()
    };
    let named = |list: &[(&Term, &String)], parameter: &str| -> Vec<String> {
        list.iter()
            .map(|(_, l)| format!("{l}.{parameter}"))
            .collect()
    };
    let scalar =
        |sys: &System, name: &str| sys.parameter(name).ok().and_then(|v| v.first().copied());
    // The StVK (and neo-Hookean) membranes act as one of stiffness Σ Yᵢ hᵢ at the first one's thickness.
    let stvk = membranes(false);
    let (mut yh, mut first_h) = (0.0, None);
    for (_, label) in &stvk {
        if let (Some(y), Some(h)) = (
            scalar(sys, &format!("{label}.young")),
            scalar(sys, &format!("{label}.thickness")),
        ) {
            yh += y * h;
            first_h.get_or_insert(h);
        }
    }
    if let Some(h) = first_h.filter(|h| *h > 0.0) {
        let scales = continuation_scales(sys, rest, yh / h, h).map_err(|e| e.to_string())?;
        if !scales.is_empty() {
            return Ok((named(&stvk, "young"), scales));
        }
    }
    // Else the co-rotational ones, by their stiffness, from the first one's material.
    let corotational = membranes(true);
    if let Some((
        Term::Membrane {
            poisson, thickness, ..
        },
        label,
    )) = corotational.first()
        && *thickness > 0.0
        && let Some(k) = scalar(sys, &format!("{label}.stiffness"))
    {
        let (poisson, thickness) = (*poisson, *thickness);
        return continuation_scales(sys, rest, k * (1.0 + poisson) / thickness, thickness)
            .map(|s| (named(&corotational, "stiffness"), s))
            .map_err(|e| e.to_string());
    }
    Ok((Vec::new(), Vec::new()))
}

/// Implicit Euler time stepping on a system: `ImplicitEuler(system, X0, dt, density, V0=None, …)`.
#[pyclass(module = "hinge._hinge", name = "ImplicitEuler")]
pub struct PyStepper {
    /// Behind a mutex: the linear solver is `Send` but not `Sync`.
    state: std::sync::Mutex<StepState>,
}

struct StepState {
    system: System,
    stepper: Stepper,
    x: Vec<Vector3<f64>>,
    v: Vec<Vector3<f64>>,
    time: f64,
}

impl PyStepper {
    fn lock(&self) -> PyResult<std::sync::MutexGuard<'_, StepState>> {
        self.state
            .lock()
            .map_err(|_| value_error("the stepper failed in another thread"))
    }
}

#[pymethods]
impl PyStepper {
    /// A stepper from `x0` (and velocities `v0`, default zero) with step `dt` and lumped masses of
    /// `density`; the system's current terms and pins are copied. `globalization`, `extrapolate`, the
    /// relative tolerances, `remember_shift` and `geodesic_acceleration` as in `solve_static`;
    /// `definite_shift_ratio` ([`NewtonParams::definite_shift_ratio`], ≥ 0, `inf`: never); `definite_hold` as
    /// in `solve_static`.
    #[new]
    #[pyo3(signature = (system, x0, dt, density, v0=None, max_iterations=50, gradient_tolerance=1e-8, globalization="shifted-exact", extrapolate=true, relative_gradient_tolerance=0.0, relative_step_tolerance=0.0, remember_shift=true, geodesic_acceleration=true, definite_shift_ratio=DEFINITE_SHIFT_RATIO, definite_hold=DEFINITE_HOLD))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        system: &PySystem,
        x0: PyReadonlyArray2<'_, f64>,
        dt: f64,
        density: f64,
        v0: Option<PyReadonlyArray2<'_, f64>>,
        max_iterations: usize,
        gradient_tolerance: f64,
        globalization: &str,
        extrapolate: bool,
        relative_gradient_tolerance: f64,
        relative_step_tolerance: f64,
        remember_shift: bool,
        geodesic_acceleration: bool,
        definite_shift_ratio: f64,
        definite_hold: usize,
    ) -> PyResult<Self> {
        let x = system.positions(&x0)?;
        let v = match v0 {
            Some(a) => system.positions(&a)?,
            None => vec![Vector3::zeros(); x.len()],
        };
        Stepper::check_state(&x, &v).map_err(value_error)?;
        if !(density > 0.0 && density.is_finite()) {
            return Err(value_error(format!(
                "density must be positive and finite, got {density}"
            )));
        }
        let params = newton_params(
            PyNewtonOptions {
                max_iterations,
                gradient_tolerance,
                globalization,
                extrapolate,
                relative_gradient_tolerance,
                relative_step_tolerance,
                remember_shift,
                geodesic_acceleration,
                definite_shift_ratio,
                definite_hold,
            },
            &system.rest,
        )?;
        let pins = system.pins()?;
        let sys = detached(py, || system.build()).map_err(value_error)?;
        let masses = lumped_masses(&system.rest, density);
        let stepper = Stepper::new(&sys, dt, masses, pins, Box::new(FaerLlt::default()), params)
            .map_err(value_error)?;
        Ok(Self {
            state: std::sync::Mutex::new(StepState {
                system: sys,
                stepper,
                x,
                v,
                time: 0.0,
            }),
        })
    }

    /// One frame of `dt` (split into substeps if a step fails): returns `(X, stats)`. On failure raises
    /// `ValueError`, and positions, velocities and time stay those before the call.
    fn step<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
        let mut guard = self.lock()?;
        let st: &mut StepState = &mut guard;
        let (r, signal) = interruptible(py, |stop| {
            st.stepper.newton_mut().set_stop(Some(stop.clone()));
            st.stepper
                .advance(
                    &mut st.system,
                    &mut st.x,
                    &mut st.v,
                    SubstepPolicy::default(),
                )
                .map_err(|e| solver_message(&e, None))
        });
        // Ctrl-C: a frame that saw it is undone (state and time as before the call); one that finished
        // first is kept, and the interrupt is raised after it.
        if r.is_ok() {
            st.time += st.stepper.dt;
        }
        if let Some(e) = signal {
            return Err(e);
        }
        let fs = r.map_err(value_error)?;
        let d = stats_dict(py, &fs.newton)?;
        d.set_item("substeps", fs.substeps)?;
        d.set_item("max_final_gradient_norm", fs.max_final_gradient_norm)?;
        Ok((to_array(py, &st.x)?, d))
    }

    /// Current positions.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        to_array(py, &self.lock()?.x)
    }

    /// Current velocities.
    #[getter]
    fn v<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        to_array(py, &self.lock()?.v)
    }

    /// Simulated time.
    #[getter]
    fn time(&self) -> PyResult<f64> {
        Ok(self.lock()?.time)
    }
}

/// Frames of a scene: (frames, n, 3) positions.
type Frames = Vec<Vec<Vector3<f64>>>;

/// `run_scene(scene, frames=None, trace=False, checkpoint=None, resume=None, checkpoint_every=None)`:
/// simulates a built-in scene (`drape`, `shell-drop`, `beam1`, …) or a TOML scene file, as `hinge run` does, and returns
/// `(V, F, X, summary)`: the rest mesh, the positions of every frame as a (frames, n, 3) array, and the
/// run's counts, per frame too (`frame_newton_iterations`, `frame_factorizations`, `frame_substeps`).
/// `checkpoint`: a file the run writes its state to when it ends, is interrupted or fails (then the last
/// good frame's), as `hinge run` writes `checkpoint.txt`; `resume`: such a file to continue from (`X` then
/// holds the frames after its frame, `summary["resumed_after_frame"]` says which; with the scene unchanged
/// they are bitwise those of the run that did not stop). `checkpoint_every`: also write the checkpoint
/// after every N-th frame. With `trace`, `summary["trace"]`
/// is a (k, 11) array with a row per accepted Newton iteration, as `hinge run --trace` prints them: frame
/// (from 0), iteration (from 1 in each solve), F, ‖∇F‖, ‖Δx‖, α, shift, definite (1 for a step with the
/// definite Hessian of `globalization = "project-on-demand"`, else 0), accelerated (1 for a step
/// corrected by geodesic acceleration, else 0), and where the residual is: the vertex (a row of `V`) whose
/// free dofs carry the largest force ‖∂F/∂x_v‖ at the new iterate and that force (−1 and 0 when no dof is
/// free); the two flags' column sums are the summary's `definite_iterations` and
/// `accelerated_iterations`.
#[pyfunction]
#[pyo3(signature = (scene, frames=None, trace=false, checkpoint=None, resume=None, checkpoint_every=None))]
#[allow(clippy::type_complexity)]
pub fn run_scene<'py>(
    py: Python<'py>,
    scene: &str,
    frames: Option<usize>,
    trace: bool,
    checkpoint: Option<std::path::PathBuf>,
    resume: Option<std::path::PathBuf>,
    checkpoint_every: Option<usize>,
) -> PyResult<(
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray2<i64>>,
    Bound<'py, numpy::PyArray3<f64>>,
    Bound<'py, PyDict>,
)> {
    let (mut sc, base) = hinge_cli::scene::load(scene).map_err(value_error)?;
    if let Some(f) = frames {
        if f == 0 || f > 100_000 {
            return Err(value_error(format!("frames must be 1 to 100000, got {f}")));
        }
        sc.frames = f;
    }
    // A checkpoint that cannot be written is said before the run, not after it.
    if let Some(p) = &checkpoint {
        let dir = p.parent().filter(|d| !d.as_os_str().is_empty());
        if dir.is_some_and(|d| !d.is_dir()) || p.is_dir() {
            return Err(value_error(format!(
                "checkpoint: {} cannot be written (no such directory, or it is a directory)",
                p.display()
            )));
        }
    }
    let resume = resume
        .map(|p| hinge_cli::checkpoint::Checkpoint::read(&p))
        .transpose()
        .map_err(|e| value_error(format!("resume: {e}")))?;
    let rest = sc.rest_mesh(base.as_deref()).map_err(value_error)?;
    let n = rest.n_vertices();
    if sc.frames.saturating_mul(n) > 50_000_000 {
        return Err(value_error(format!(
            "{} frames of {n} vertices is more than this call returns at once (5e7 positions)",
            sc.frames
        )));
    }
    let mut xs: Frames = Vec::with_capacity(sc.frames);
    // The trace's rows, and the frame the observer's iterations belong to (the frames done so far).
    let rows = std::sync::Arc::new(std::sync::Mutex::new(Vec::<[f64; 11]>::new()));
    let frame = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(
        resume.as_ref().map_or(0, |c| c.frame),
    ));
    let observer: Option<hinge_solver::newton::Observer> = trace.then(|| {
        let (rows, frame) = (std::sync::Arc::clone(&rows), std::sync::Arc::clone(&frame));
        Box::new(move |r: &hinge_solver::newton::IterationReport| {
            let k = frame.load(std::sync::atomic::Ordering::Relaxed);
            if let Ok(mut rows) = rows.lock() {
                rows.push([
                    k as f64,
                    r.iteration as f64,
                    r.energy,
                    r.gradient_norm,
                    r.step_norm,
                    r.step_length,
                    r.shift,
                    f64::from(u8::from(r.definite)),
                    f64::from(u8::from(r.accelerated)),
                    r.largest_residual.map_or(-1.0, |(v, _)| v as f64),
                    r.largest_residual.map_or(0.0, |(_, f)| f),
                ]);
            }
        }) as hinge_solver::newton::Observer
    });
    // Set-up warnings and the run's (a penalty obstacle that let vertices through), raised as
    // `hinge.MeshWarning` once the run is over (whether or not it failed).
    let mut warnings: Vec<String> = Vec::new();
    let (summary, signal) = interruptible(py, |stop| {
        hinge_cli::run::simulate_observed(
            &sc,
            &rest,
            None,
            hinge_cli::run::Hooks {
                stop: Some(stop),
                names: None,
                observer,
                warn: Some(Box::new(|line: &str| {
                    warnings.push(format!("{line} (vertices from 0)"));
                })),
                checkpoint: checkpoint.as_deref(),
                checkpoint_every: checkpoint_every.unwrap_or(0),
                resume: resume.as_ref(),
            },
            |k, _, _, x| {
                xs.push(x.to_vec());
                frame.store(k + 1, std::sync::atomic::Ordering::Relaxed);
            },
        )
    });
    if !warnings.is_empty() {
        let category = py.import("hinge")?.getattr("MeshWarning")?;
        for w in warnings {
            let text = std::ffi::CString::new(w.replace('\0', " ")).map_err(value_error)?;
            PyErr::warn(py, &category, &text, 2)?;
        }
    }
    // Ctrl-C ends the run after the frame it is in (or at its next Newton iteration) and raises here.
    if let Some(e) = signal {
        return Err(e);
    }
    let summary = summary.map_err(value_error)?;
    let flat: Vec<f64> = xs
        .iter()
        .flat_map(|f| f.iter().flat_map(|p| [p.x, p.y, p.z]))
        .collect();
    let arr = flat
        .into_pyarray(py)
        .reshape([xs.len(), n, 3])
        .map_err(value_error)?;
    let tris: Vec<Vec<i64>> = rest
        .triangles()
        .iter()
        .map(|t| t.iter().map(|&v| v as i64).collect())
        .collect();
    let d = PyDict::new(py);
    d.set_item("frames", summary.frames)?;
    d.set_item("resumed_after_frame", resume.as_ref().map(|c| c.frame))?;
    d.set_item("newton_iterations", summary.newton_iterations)?;
    d.set_item("factorizations", summary.factorizations)?;
    d.set_item("line_search_steps", summary.line_search_steps)?;
    d.set_item("substeps", summary.substeps)?;
    d.set_item("definite_iterations", summary.definite_iterations)?;
    d.set_item("accelerated_iterations", summary.accelerated_iterations)?;
    d.set_item("max_final_gradient_norm", summary.max_final_gradient_norm)?;
    d.set_item("total_seconds", summary.total_seconds)?;
    d.set_item("min_clearance", summary.min_clearance)?;
    d.set_item("frame_newton_iterations", &summary.frame_newton_iterations)?;
    d.set_item("frame_factorizations", &summary.frame_factorizations)?;
    d.set_item("frame_substeps", &summary.frame_substeps)?;
    if trace {
        let rows = rows
            .lock()
            .map(|mut r| std::mem::take(&mut *r))
            .unwrap_or_default();
        let count = rows.len();
        let flat: Vec<f64> = rows.into_iter().flatten().collect();
        d.set_item(
            "trace",
            flat.into_pyarray(py)
                .reshape([count, 11])
                .map_err(value_error)?,
        )?;
    }
    Ok((
        to_array(py, rest.positions())?,
        PyArray2::from_vec2(py, &tris).map_err(value_error)?,
        arr,
        d,
    ))
}

/// `adjoint_gradient(system, X, dloss_dx, parameters)`: `dL/dp = −λᵀ ∂g/∂p` at an equilibrium `X` of the
/// system (pins eliminated) for a loss whose gradient with respect to the positions is `dloss_dx` (shape
/// (n, 3)), for every named parameter; `H λ = ∂L/∂x` with the exact Hessian at `X`. Returns a dict name →
/// array. An `X` that is not a strict minimum (indefinite Hessian) raises `ValueError`.
#[pyfunction]
pub fn adjoint_gradient<'py>(
    py: Python<'py>,
    system: &mut PySystem,
    x: PyReadonlyArray2<'py, f64>,
    dloss_dx: PyReadonlyArray2<'py, f64>,
    parameters: Vec<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let pos = system.positions(&x)?;
    let dl: Vec<f64> = system
        .positions(&dloss_dx)?
        .iter()
        .flat_map(|p| [p.x, p.y, p.z])
        .collect();
    let pins = system.pins()?;
    let sys = system.system(py)?;
    let r = detached(py, || -> Result<Vec<(String, Vec<f64>)>, String> {
        let mut adjoint = Adjoint::new(sys, &pins).map_err(|e| e.to_string())?;
        adjoint.factor(sys, &pos).map_err(|e| e.to_string())?;
        adjoint.solve(&dl).map_err(|e| e.to_string())?;
        parameters
            .iter()
            .map(|name| {
                adjoint
                    .parameter_gradient(sys, &pos, name)
                    .map(|g| (name.clone(), g))
                    .map_err(|e| e.to_string())
            })
            .collect()
    });
    let d = PyDict::new(py);
    for (name, g) in r.map_err(value_error)? {
        d.set_item(name, g.into_pyarray(py))?;
    }
    Ok(d)
}

/// The dict `{"fitted": …, "loss", "iterations", "equilibria", "newton_iterations", "stop", "fields"}` of a
/// fit; `fields` maps every checked field variable to `{"entries", "without_effect", "determined"}`
/// ([`FieldCheck`]).
fn fit_info<'py>(
    py: Python<'py>,
    names: &[String],
    values: &[Vec<f64>],
    r: (f64, usize, usize, usize, &str),
    checks: &[FieldCheck],
) -> PyResult<Bound<'py, PyDict>> {
    let fitted = PyDict::new(py);
    for (n, v) in names.iter().zip(values) {
        if v.len() == 1 {
            fitted.set_item(n, v[0])?;
        } else {
            fitted.set_item(n, v.clone().into_pyarray(py))?;
        }
    }
    let d = PyDict::new(py);
    d.set_item("fitted", fitted)?;
    d.set_item("loss", r.0)?;
    d.set_item("iterations", r.1)?;
    d.set_item("equilibria", r.2)?;
    d.set_item("newton_iterations", r.3)?;
    d.set_item("stop", r.4)?;
    let fields = PyDict::new(py);
    for f in checks {
        if let Some(rank) = f.rank {
            let c = PyDict::new(py);
            c.set_item("entries", f.entries)?;
            c.set_item("without_effect", rank.without_effect)?;
            c.set_item("determined", rank.determined)?;
            fields.set_item(&f.variable, c)?;
        }
    }
    d.set_item("fields", fields)?;
    Ok(d)
}

/// `fit(system, X0, target, parameters, max_iterations=50, gradient_tolerance=1e-9,
/// membrane_continuation=True)`: the named system parameters (`TERM.NAME`) that make the equilibrium match
/// `target` (shape (n, 3); loss: the sum of squared vertex distances), by L-BFGS with adjoint gradients; a
/// parameter whose values are all positive is fitted on a log scale, one an energy bounds (a membrane's
/// `poisson`) inside its interval. The first equilibrium goes through the
/// membrane continuation of `solve_static` when `membrane_continuation` is set; the fit's solves start from
/// it. Returns `(X, info)` with `info["fitted"]` the values; the system keeps them.
#[pyfunction]
#[pyo3(signature = (system, x0, target, parameters, max_iterations=50, gradient_tolerance=1e-9, membrane_continuation=true))]
#[allow(clippy::too_many_arguments)]
pub fn fit<'py>(
    py: Python<'py>,
    system: &mut PySystem,
    x0: PyReadonlyArray2<'py, f64>,
    target: PyReadonlyArray2<'py, f64>,
    parameters: Vec<String>,
    max_iterations: usize,
    gradient_tolerance: f64,
    membrane_continuation: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let options = FitOptions {
        max_iterations,
        ..FitOptions::default()
    };
    options.validate().map_err(|e| value_error(e.to_string()))?;
    let mut x = system.positions(&x0)?;
    let target = system.positions(&target)?;
    let (rest, terms) = (system.rest.clone(), system.terms.clone());
    let params = newton_params(
        PyNewtonOptions {
            max_iterations: 500,
            gradient_tolerance,
            globalization: "shifted-exact",
            extrapolate: true,
            relative_gradient_tolerance: 0.0,
            relative_step_tolerance: 0.0,
            remember_shift: true,
            geodesic_acceleration: true,
            definite_shift_ratio: DEFINITE_SHIFT_RATIO,
            definite_hold: DEFINITE_HOLD,
        },
        &rest,
    )?;
    let pins = system.pins()?;
    let sys = system.system(py)?;
    let mut variables = Vec::new();
    for (i, name) in parameters.iter().enumerate() {
        if parameters[..i].contains(name) {
            return Err(value_error(format!("parameter `{name}` given twice")));
        }
        let start = sys.parameter(name).map_err(value_error)?;
        // A bounded parameter (a Poisson ratio) is fitted inside its interval, a positive one on a log scale.
        let range = sys.parameter_bounds(name).map_err(value_error)?;
        let positive = range.is_none() && start.iter().all(|v| *v > 0.0);
        variables.push(FitVariable {
            name: name.clone(),
            links: vec![if positive {
                Link::Power {
                    parameter: name.clone(),
                    exponent: 1.0,
                }
            } else {
                Link::Value {
                    parameter: name.clone(),
                }
            }],
            start,
            positive,
            range,
        });
    }
    let (r, signal) = interruptible(py, |stop| -> Result<(FitResult, usize), String> {
        let (parameters, stages) = if membrane_continuation {
            continuation(&terms, sys, &rest)?
        } else {
            (Vec::new(), Vec::new())
        };
        let parameters: Vec<&str> = parameters.iter().map(String::as_str).collect();
        let mut newton = Newton::new(sys, &pins, Box::new(FaerLlt::default()), params)
            .map_err(|e| e.to_string())?;
        newton.set_stop(Some(stop.clone()));
        // The first equilibrium through the continuation; the fit's solves start from it.
        let start = continued_start_all(&mut newton, sys, &mut x, &parameters, &stages);
        let loss = TargetLoss::all(target);
        let mut fit =
            Fit::new(sys, &pins, &mut newton, variables, options).map_err(|e| e.to_string())?;
        let r = fit
            .run(sys, &mut x, &mut |x, g| loss.evaluate(x, g))
            .map_err(|e| e.to_string())?;
        Ok((r, start))
    });
    // Ctrl-C: the fit ended with the start values set back; nothing is recorded.
    if let Some(e) = signal {
        return Err(e);
    }
    let (r, start) = r.map_err(value_error)?;
    for (name, v) in parameters.iter().zip(&r.values) {
        system.record(name, v.clone());
    }
    let info = fit_info(
        py,
        &parameters,
        &r.values,
        (
            r.loss,
            r.iterations,
            r.equilibria,
            start + r.newton_iterations,
            r.stop,
        ),
        &r.fields,
    )?;
    Ok((to_array(py, &r.x)?, info))
}

/// `fit_scene(scene, target, keys, max_iterations=50, smoothness=0.0)`: `hinge fit` from Python — the scene
/// keys (`material.young`, `material.thickness`, `material.poisson`, `material.density`,
/// `bending.params.NAME`, `bending.rest_angles`) that make the scene's static equilibrium match `target` (a
/// mesh file path, or the positions as an (n, 3) array). Returns `(X, info)` like `fit`.
#[pyfunction]
#[pyo3(signature = (scene, target, keys, max_iterations=50, smoothness=0.0))]
pub fn fit_scene<'py>(
    py: Python<'py>,
    scene: &str,
    target: &Bound<'py, PyAny>,
    keys: Vec<String>,
    max_iterations: usize,
    smoothness: f64,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let options = FitOptions {
        max_iterations,
        smoothness,
        ..FitOptions::default()
    };
    options.validate().map_err(|e| value_error(e.to_string()))?;
    let (sc, base) = hinge_cli::scene::load(scene).map_err(value_error)?;
    let rest = sc.rest_mesh(base.as_deref()).map_err(value_error)?;
    let (target_mesh, name) = if let Ok(path) = target.extract::<String>() {
        (
            hinge_cli::files::read(std::path::Path::new(&path)).map_err(value_error)?,
            path,
        )
    } else {
        let arr: PyReadonlyArray2<'py, f64> = target.extract().map_err(|_| {
            value_error("target must be a mesh file path or an (n, 3) array of positions")
        })?;
        let s = arr.shape();
        if s.len() != 2 || s[1] != 3 || s[0] != rest.n_vertices() {
            return Err(value_error(format!(
                "target must have shape ({}, 3), got {s:?}",
                rest.n_vertices()
            )));
        }
        let a = arr.as_array();
        let x: Vec<Vector3<f64>> = (0..s[0])
            .map(|i| Vector3::new(a[[i, 0]], a[[i, 1]], a[[i, 2]]))
            .collect();
        (
            rest.with_positions(x).map_err(value_error)?,
            "target".to_string(),
        )
    };
    let (r, signal) = interruptible(py, |stop| {
        hinge_cli::fit::fit_scene_until(
            &sc,
            &rest,
            &target_mesh,
            &name,
            &keys,
            options,
            None,
            Some(stop),
        )
    });
    if let Some(e) = signal {
        return Err(e);
    }
    let r = r.map_err(value_error)?;
    let names: Vec<String> = r.values.iter().map(|(k, _)| k.clone()).collect();
    let values: Vec<Vec<f64>> = r.values.iter().map(|(_, v)| v.clone()).collect();
    let info = fit_info(
        py,
        &names,
        &values,
        (
            r.loss,
            r.iterations,
            r.equilibria,
            r.newton_iterations,
            r.stop,
        ),
        &r.fields,
    )?;
    Ok((to_array(py, &r.x)?, info))
}
