//! `hinge eval`: evaluate a hinge energy on user meshes and export energy, gradient and Hessian.

use std::path::PathBuf;

use clap::Args;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::psi::{DiscreteShells, HingePsi, TanBending};
use hinge_core::{TriMesh, export, obj};

/// Energies `hinge eval` knows, with their parameters and defaults.
pub const ENERGIES: [(&str, &str); 2] = [
    ("discrete-shells", "k=1 (psi = k*a*(theta - theta_bar)^2)"),
    (
        "tan-bending",
        "k=1 (psi = k*a*(2tan(theta/2) - 2tan(theta_bar/2))^2)",
    ),
];

/// Arguments of `hinge eval`.
#[derive(Args)]
pub struct EvalArgs {
    /// Rest mesh (OBJ).
    #[arg(long, required_unless_present = "list_energies")]
    rest: Option<PathBuf>,
    /// Deformed mesh (OBJ with the same vertices and triangles); default: the rest mesh.
    #[arg(long)]
    deformed: Option<PathBuf>,
    /// Energy name (see --list-energies).
    #[arg(long, required_unless_present = "list_energies")]
    energy: Option<String>,
    /// Energy parameter KEY=VALUE (repeatable).
    #[arg(long = "param")]
    params: Vec<String>,
    /// refactored, per_hinge or autodiff.
    #[arg(long, default_value = "refactored")]
    method: String,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Output directory for gradient.txt and hessian.mtx.
    #[arg(long, required_unless_present = "list_energies")]
    out: Option<PathBuf>,
    /// Print the energy names, one per line, with their parameters.
    #[arg(long)]
    list_energies: bool,
}

fn parse_params(energy: &str, params: &[String]) -> Result<f64, String> {
    let mut k = 1.0;
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
        match key {
            "k" => k = v,
            _ => {
                return Err(format!(
                    "energy `{energy}` has no parameter `{key}` (it has: k)"
                ));
            }
        }
    }
    Ok(k)
}

/// Runs `hinge eval`.
pub fn run(args: EvalArgs) -> Result<(), String> {
    if args.list_energies {
        for (name, params) in ENERGIES {
            println!("{name}\t{params}");
        }
        return Ok(());
    }
    let (Some(rest_path), Some(energy), Some(out)) = (&args.rest, &args.energy, &args.out) else {
        return Err("eval needs --rest, --energy and --out".into());
    };
    let method = Method::from_name(&args.method).ok_or_else(|| {
        format!(
            "unknown method `{}` (refactored, per_hinge, autodiff)",
            args.method
        )
    })?;
    let k = parse_params(energy, &args.params)?;
    let rest = obj::read_obj(rest_path).map_err(|e| e.to_string())?;
    let deformed = match &args.deformed {
        Some(p) => crate::read_deformed(&rest, p)?,
        None => rest.clone(),
    };
    let threads = args
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    if threads == 0 {
        return Err("--threads must be at least 1".into());
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| format!("thread pool: {e}"))?;
    let ctx = EvalCtx {
        rest: &rest,
        deformed: &deformed,
        method,
        pool: &pool,
        threads,
        out,
    };
    match energy.as_str() {
        "discrete-shells" => ctx.eval(DiscreteShells { k }),
        "tan-bending" => ctx.eval(TanBending { k }),
        other => Err(format!(
            "unknown energy `{other}` (known: {})",
            ENERGIES.map(|e| e.0).join(", ")
        )),
    }
}

struct EvalCtx<'a> {
    rest: &'a TriMesh,
    deformed: &'a TriMesh,
    method: Method,
    pool: &'a rayon::ThreadPool,
    threads: usize,
    out: &'a std::path::Path,
}

impl EvalCtx<'_> {
    fn eval<P: HingePsi>(&self, psi: P) -> Result<(), String> {
        let (rest, deformed, method, pool, threads, out) = (
            self.rest,
            self.deformed,
            self.method,
            self.pool,
            self.threads,
            self.out,
        );
        let model = BendingModel::new(rest, psi).map_err(|e| format!("rest mesh: {e}"))?;
        let e = pool
            .install(|| {
                model.evaluate(
                    deformed.positions(),
                    Request::ALL,
                    method,
                    Parallelism::Rayon,
                )
            })
            .map_err(|e| format!("deformed mesh: {e}"))?;
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
            export::write_matrix_market(w, model.pattern(), &e.hessian)
        })?;
        println!(
            "{{\"energy\": {:?}, \"method\": \"{}\", \"threads\": {threads}, \"n_vertices\": {}, \"n_hinges\": {}}}",
            e.energy,
            method.name(),
            model.n_vertices(),
            model.topology().hinges().len()
        );
        Ok(())
    }
}
