//! `hinge eval`: evaluate a hinge energy on user meshes and export energy, gradient and Hessian.

use std::path::PathBuf;

use crate::scene::CustomPsi;
use clap::Args;
use hinge_core::bending::{BendingModel, HessianMode, Method, Parallelism, Request};
use hinge_core::energy::{Energy, HingeTerm, System};
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::HingePsi;
use hinge_core::psi::runtime::ParamValue;
use hinge_core::{TriMesh, export};
use hinge_energies::bending::{BuiltinBending, PsiConsumer, ViscousDamping};
use hinge_energies::contact::{Contact, Obstacle};
use hinge_energies::gravity::{Gravity, lumped_masses};
use hinge_energies::membrane::MembraneModel;
use hinge_energies::quadratic::QuadraticBending;
use hinge_energies::spring::MassSpring;

/// An energy `hinge eval` knows: name, parameters with defaults, description.
pub type EnergyEntry = (&'static str, &'static [(&'static str, f64)], &'static str);

/// Energies `hinge eval` knows.
pub const ENERGIES: [EnergyEntry; 14] = [
    (
        "discrete-shells",
        &[("k", 1.0)],
        "k*a*(theta - theta_bar)^2",
    ),
    (
        "tan-bending",
        &[("k", 1.0)],
        "k*a*(2tan(theta/2) - 2tan(theta_bar/2))^2",
    ),
    (
        "willmore",
        &[("k", 1.0)],
        "k*a*(2sin(theta/2) - 2sin(theta_bar/2))^2",
    ),
    (
        "bridson",
        &[("k", 1.0)],
        "psi' = k*a*(sin(theta/2) - sin(theta_bar/2)), psi(theta_bar) = 0",
    ),
    (
        "viscous-damping",
        &[("kd", 1.0), ("dt", 0.01)],
        "(kd/dt)*a*(2tan(theta/2) - 2tan(theta_prev/2))^2, theta_prev from the rest mesh",
    ),
    (
        "mass-spring",
        &[("k", 1.0), ("compressive", 1.0)],
        "sum over edges of k/2 (l - L)^2; compressive=0 drops the compressive Hessian term",
    ),
    (
        "bending-springs",
        &[("k", 1.0)],
        "springs k/2 (l - L)^2 across each hinge, between its opposite vertices (the lecture's poor bending model)",
    ),
    (
        "quadratic-bending",
        &[("k", 1.0)],
        "Bergou et al. 2006, constant Hessian",
    ),
    (
        "membrane",
        &[("young", 1000.0), ("poisson", 0.3), ("thickness", 0.001)],
        "St. Venant-Kirchhoff membrane",
    ),
    (
        "corotational-membrane",
        &[("young", 1000.0), ("poisson", 0.3), ("thickness", 0.001)],
        "co-rotational (shape matching) membrane k/2 A |F - R|^2, k = young*thickness/(1+poisson), exact Hessian",
    ),
    (
        "neo-hookean-membrane",
        &[("young", 1000.0), ("poisson", 0.3), ("thickness", 0.001)],
        "compressible neo-Hookean membrane mu/2 (I1 - 2) - mu ln J + lambda/2 ln^2 J, infinite at zero area, exact Hessian",
    ),
    (
        "gravity",
        &[("density", 1.0), ("g", 9.81)],
        "lumped masses (density per area) under gravity along -z",
    ),
    (
        "contact-sphere",
        &[
            ("cx", 0.0),
            ("cy", 0.0),
            ("cz", 0.0),
            ("radius", 0.5),
            ("stiffness", 1000.0),
            ("margin", 0.0),
            ("smoothing", 0.0),
            ("barrier", 0.0),
        ],
        "one-sided penalty outside a sphere (quadratic; C2 with smoothing > 0); barrier=1: log barrier of reach margin",
    ),
    (
        "contact-plane",
        &[
            ("px", 0.0),
            ("py", 0.0),
            ("pz", 0.0),
            ("nx", 0.0),
            ("ny", 0.0),
            ("nz", 1.0),
            ("stiffness", 1000.0),
            ("margin", 0.0),
            ("smoothing", 0.0),
            ("barrier", 0.0),
        ],
        "one-sided penalty above a plane (quadratic; C2 with smoothing > 0); barrier=1: log barrier of reach margin",
    ),
];

/// Arguments of `hinge eval`.
#[derive(Args)]
pub struct EvalArgs {
    /// Rest mesh (OBJ, OFF, PLY or STL, by extension).
    #[arg(long, required_unless_present = "list_energies")]
    rest: Option<PathBuf>,
    /// Deformed mesh (a mesh file with the rest mesh's vertices in its order, and its faces in any order and
    /// corner rotation); default: the rest mesh.
    #[arg(long)]
    deformed: Option<PathBuf>,
    /// Energy name (see --list-energies).
    #[arg(long, required_unless_present_any = ["list_energies", "psi"], conflicts_with = "psi")]
    energy: Option<String>,
    /// A custom hinge energy ψ(θ) in the derive's expression language, for example
    /// "k * a * (theta - theta_bar).powi(2)"; its parameters come from --param NAME=VALUE.
    #[arg(long)]
    psi: Option<String>,
    /// Energy parameter KEY=VALUE (repeatable).
    #[arg(long = "param")]
    params: Vec<String>,
    /// refactored, per_hinge or autodiff.
    #[arg(long, default_value = "refactored")]
    method: String,
    /// The hinge Hessian: exact, gauss-newton (max(ψ″, 0) ∇θ∇θᵀ) or projected (each hinge's 12×12
    /// Hessian with its negative eigenvalues clamped to zero); hinge energies and --psi only.
    #[arg(long, default_value = "exact")]
    hessian: String,
    /// Worker threads (default: all logical CPUs; a larger count is clamped to them with a warning on
    /// stderr).
    #[arg(long)]
    threads: Option<usize>,
    /// Output directory for gradient.txt and hessian.mtx.
    #[arg(long, required_unless_present = "list_energies")]
    out: Option<PathBuf>,
    /// Print the energy names, one per line, with their parameters.
    #[arg(long)]
    list_energies: bool,
}

/// Parameters of `energy` from its defaults and `KEY=VALUE` overrides.
fn parse_params(
    energy: &str,
    params: &[String],
) -> Result<std::collections::BTreeMap<&'static str, f64>, String> {
    let (_, defaults, _) = ENERGIES.iter().find(|e| e.0 == energy).ok_or_else(|| {
        format!(
            "unknown energy `{energy}` (known: {})",
            ENERGIES.map(|e| e.0).join(", ")
        )
    })?;
    let mut values: std::collections::BTreeMap<&'static str, f64> =
        defaults.iter().copied().collect();
    for p in params {
        let (key, value) = p
            .split_once('=')
            .ok_or_else(|| format!("parameter `{p}` is not KEY=VALUE"))?;
        let v: f64 = value
            .parse()
            .map_err(|_| format!("parameter `{key}`: `{value}` is not a number"))?;
        if !v.is_finite() {
            return Err(format!("parameter `{key}` must be finite, got {value}"));
        }
        let Some(slot) = values.iter_mut().find(|(k, _)| **k == key).map(|(_, v)| v) else {
            let names: Vec<&str> = defaults.iter().map(|d| d.0).collect();
            return Err(format!(
                "energy `{energy}` has no parameter `{key}` (it has: {})",
                names.join(", ")
            ));
        };
        *slot = v;
    }
    Ok(values)
}

/// A run-time ψ from `--psi EXPR` and its `--param NAME=VALUE` values.
pub fn custom_psi(expr: &str, params: &[String]) -> Result<CustomPsi, String> {
    let mut values: Vec<(String, ParamValue)> = Vec::new();
    for p in params {
        let (key, value) = p
            .split_once('=')
            .ok_or_else(|| format!("parameter `{p}` is not NAME=VALUE"))?;
        let v: f64 = value
            .parse()
            .map_err(|_| format!("parameter `{key}`: `{value}` is not a number"))?;
        if !v.is_finite() {
            return Err(format!("parameter `{key}` must be finite, got {value}"));
        }
        values.push((key.to_string(), ParamValue::Scalar(v)));
    }
    CustomPsi::new(expr, values)
}

/// Builds a hinge term of `hinge eval` from its parameters (`g(key)`, 0 when absent), its Hessian mode set.
/// The one hinge energy of `hinge eval` that is not a [`BuiltinBending`] (`--hessian` applies to these).
const VISCOUS_DAMPING: &str = ViscousDamping::NAME;

/// Builds [`hinge_term`] of the ψ [`BuiltinBending::with_psi`] hands it.
struct HingeTermOf<'a> {
    name: &'a str,
    rest: &'a TriMesh,
    method: Method,
    mode: HessianMode,
}

impl PsiConsumer for HingeTermOf<'_> {
    type Output = Result<Box<dyn Energy>, String>;
    fn consume<P>(self, psi: P) -> Self::Output
    where
        P: HingePsi + Clone + Send + Sync + std::fmt::Debug + 'static,
    {
        hinge_term(
            self.name,
            BendingModel::new(self.rest, psi),
            self.method,
            self.mode,
        )
    }
}

/// A hinge term named `name` of a freshly built `model`, its Hessian mode set to `mode`.
fn hinge_term<P: HingePsi + Send + 'static>(
    name: &str,
    model: Result<BendingModel<P>, hinge_core::EvalError>,
    method: Method,
    mode: HessianMode,
) -> Result<Box<dyn Energy>, String> {
    let err = |e: hinge_core::EvalError| format!("{name}: {e}");
    let mut model = model.map_err(err)?;
    model.set_hessian_mode(mode).map_err(err)?;
    Ok(Box::new(HingeTerm::new(name, model, method)))
}

/// Builds the one-term system for `energy`.
fn build(
    energy: &str,
    p: &std::collections::BTreeMap<&'static str, f64>,
    rest: &TriMesh,
    method: Method,
    mode: HessianMode,
) -> Result<System, String> {
    let g = |k: &str| p.get(k).copied().unwrap_or(0.0);
    let model_err = |e: hinge_core::EvalError| format!("{energy}: {e}");
    let n = rest.n_vertices();
    if let Ok(builtin) = energy.parse::<BuiltinBending>() {
        let term = builtin.with_psi(
            g("k"),
            HingeTermOf {
                name: energy,
                rest,
                method,
                mode,
            },
        )?;
        return System::new(n, vec![term]).map_err(|e| e.to_string());
    }
    if energy == VISCOUS_DAMPING {
        let model = BendingModel::new(rest, ViscousDamping { kd: g("kd") })
            .and_then(|mut m| m.set_step(rest.positions(), g("dt")).map(|()| m));
        let term = hinge_term(energy, model, method, mode)?;
        return System::new(n, vec![term]).map_err(|e| e.to_string());
    }
    if mode != HessianMode::Exact {
        let names: Vec<&str> = BuiltinBending::NAMES
            .into_iter()
            .chain([VISCOUS_DAMPING])
            .collect();
        return Err(format!(
            "--hessian {} applies to hinge energies ({}, or --psi), not `{energy}`",
            mode.name(),
            names.join(", ")
        ));
    }
    if let Some(model) = MembraneModel::from_energy_name(energy) {
        let term = model
            .build(rest, g("young"), g("poisson"), g("thickness"))
            .map_err(model_err)?;
        return System::new(n, vec![term]).map_err(|e| e.to_string());
    }
    let term: Box<dyn Energy> = match energy {
        "mass-spring" => Box::new(
            MassSpring::new(rest, g("k"))
                .map_err(model_err)?
                .drop_compressive_term(g("compressive") == 0.0),
        ),
        "bending-springs" => {
            Box::new(MassSpring::bending_springs(rest, g("k")).map_err(model_err)?)
        }
        "quadratic-bending" => Box::new(QuadraticBending::new(rest, g("k")).map_err(model_err)?),
        "gravity" => Box::new(
            Gravity::new(
                lumped_masses(rest, g("density")),
                Vector3::new(0.0, 0.0, -g("g")),
            )
            .map_err(model_err)?,
        ),
        "contact-sphere" => contact(
            n,
            Obstacle::Sphere {
                center: Vector3::new(g("cx"), g("cy"), g("cz")),
                radius: g("radius"),
            },
            p,
        )
        .map_err(model_err)?,
        "contact-plane" => contact(
            n,
            Obstacle::Plane {
                point: Vector3::new(g("px"), g("py"), g("pz")),
                normal: Vector3::new(g("nx"), g("ny"), g("nz")),
            },
            p,
        )
        .map_err(model_err)?,
        other => return Err(format!("unknown energy `{other}`")),
    };
    System::new(n, vec![term]).map_err(|e| e.to_string())
}

/// A contact term from `hinge eval`'s parameters: `stiffness`, `margin`, `smoothing` and `barrier` (0: the
/// penalty, 1: the barrier; anything else is an error).
fn contact(
    n: usize,
    obstacle: Obstacle,
    p: &std::collections::BTreeMap<&'static str, f64>,
) -> Result<Box<dyn Energy>, hinge_core::EvalError> {
    let g = |k: &str| p.get(k).copied().unwrap_or(0.0);
    let term =
        Contact::new(n, obstacle, g("stiffness"), g("margin"))?.with_smoothing(g("smoothing"))?;
    let barrier = g("barrier");
    Ok(Box::new(if barrier == 1.0 {
        term.with_barrier()?
    } else if barrier == 0.0 {
        term
    } else {
        return Err(hinge_core::EvalError::Element {
            element: "contact".into(),
            message: format!("barrier must be 0 (penalty) or 1 (barrier), got {barrier}"),
        });
    }))
}

/// Runs `hinge eval`.
pub fn run(args: EvalArgs) -> Result<(), String> {
    if args.list_energies {
        for (name, params, what) in ENERGIES {
            let p: Vec<String> = params.iter().map(|(k, v)| format!("{k}={v}")).collect();
            println!("{name}\t{}\t{what}", p.join(" "));
        }
        return Ok(());
    }
    let (Some(rest_path), Some(out)) = (&args.rest, &args.out) else {
        return Err("eval needs --rest, --energy (or --psi) and --out".into());
    };
    let energy = match (&args.energy, &args.psi) {
        (Some(e), None) => e.as_str(),
        (None, Some(_)) => "custom",
        _ => return Err("eval needs one of --energy and --psi".into()),
    };
    let names = |all: &[&str]| all.join(", ");
    let method = Method::from_name(&args.method).ok_or_else(|| {
        format!(
            "unknown method `{}` ({})",
            args.method,
            names(&Method::ALL.map(Method::name))
        )
    })?;
    let mode = HessianMode::from_name(&args.hessian).ok_or_else(|| {
        format!(
            "unknown --hessian `{}` ({})",
            args.hessian,
            names(&HessianMode::ALL.map(HessianMode::name))
        )
    })?;
    let custom = match &args.psi {
        Some(expr) => Some(custom_psi(expr, &args.params)?),
        None => None,
    };
    let params = if custom.is_some() {
        Default::default()
    } else {
        parse_params(energy, &args.params)?
    };
    let (rest, rest_names) = hinge_cli::files::read_numbered(rest_path)?;
    // An evaluation error names vertices and faces as the file of the evaluated positions counts them.
    let (deformed, names, label) = match &args.deformed {
        Some(p) => {
            let (d, names) = crate::read_deformed(&rest, p)?;
            (d, names, p.display().to_string())
        }
        None => (rest.clone(), rest_names, rest_path.display().to_string()),
    };
    let (threads, warning) = hinge_cli::limits::threads(args.threads)?;
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| format!("thread pool: {e}"))?;
    let mut system = match custom {
        Some(psi) => {
            let term = match psi {
                CustomPsi::Small(p) => {
                    hinge_term("custom", BendingModel::new(&rest, p), method, mode)?
                }
                CustomPsi::Large(p) => {
                    hinge_term("custom", BendingModel::new(&rest, p), method, mode)?
                }
            };
            System::new(rest.n_vertices(), vec![term]).map_err(|e| e.to_string())?
        }
        None => build(energy, &params, &rest, method, mode)?,
    };
    let e = pool
        .install(|| system.evaluate(deformed.positions(), Request::ALL, Parallelism::Rayon))
        .map_err(|e| format!("{label}: {} {}", e.describe(&names), names.note()))?;
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    let write =
        |name: &str, f: &dyn Fn(std::io::BufWriter<std::fs::File>) -> std::io::Result<()>| {
            let path = out.join(name);
            let file =
                std::fs::File::create(&path).map_err(|e| format!("{}: {e}", path.display()))?;
            f(std::io::BufWriter::new(file)).map_err(|e| format!("{}: {e}", path.display()))
        };
    write("gradient.txt", &|w| export::write_vector(w, &e.gradient))?;
    write("hessian.mtx", &|w| {
        export::write_matrix_market(w, system.pattern(), &e.hessian)
    })?;
    let n_hinges = hinge_core::Topology::new(rest.n_vertices(), rest.triangles())
        .map_err(|e| e.to_string())?
        .hinges()
        .len();
    println!(
        "{{\"energy\": {:?}, \"method\": \"{}\", \"hessian\": \"{}\", \"threads\": {threads}, \"n_vertices\": {}, \"n_hinges\": {n_hinges}}}",
        e.energy,
        method.name(),
        mode.name(),
        rest.n_vertices(),
    );
    Ok(())
}
