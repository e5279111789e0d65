//! `hinge`: the command line of the hinge bending-energy framework.
//!
//! The main job (`hinge` with no arguments) is `hinge run drape`: a cloth falling onto a sphere, simulated with
//! implicit Euler, frames and a summary written to `out/drape/`. `hinge eval` evaluates an energy on your
//! meshes and exports it; `hinge bench` measures the methods; `hinge stats` prints mesh statistics.

#![deny(missing_docs)]

mod bench;
mod eval;
mod plot;
mod report;
mod stability;

use hinge_cli::{run, scene};

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use hinge_core::hinge::HingeFrames;
use hinge_core::{Topology, TriMesh, grid};

#[derive(Parser)]
#[command(
    name = "hinge",
    version,
    about = "Hinge bending energies on triangle meshes"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Topology and hinge-angle statistics of a mesh.
    Stats {
        /// Rest mesh (OBJ, OFF, PLY or STL, by extension). Default: an N×N unit grid.
        #[arg(long)]
        rest: Option<std::path::PathBuf>,
        /// Deformed positions (a mesh file with the rest mesh's vertices in its order, its faces in any order and
        /// corner rotation). Default: the rest grid under the wave
        /// z = 0.1·sin(3x)·cos(2y), or the rest mesh itself when --rest is given.
        #[arg(long)]
        deformed: Option<std::path::PathBuf>,
        /// Cells per side of the default grid.
        #[arg(long, default_value_t = 80)]
        n: usize,
    },
    /// Evaluate a hinge energy: energy (JSON on stdout), gradient.txt and hessian.mtx in --out.
    Eval(eval::EvalArgs),
    /// Benchmark energy + gradient + Hessian + assembly per method (medians, ns per hinge).
    Bench(bench::BenchArgs),
    /// Simulate a scene (built-in name or TOML file), writing OBJ frames and summary.json (the default job).
    Run(run::RunArgs),
    /// The paper's evaluation and more: Hessian accuracy, cost fits, time shares, error against run time.
    Report(report::ReportArgs),
    /// Fit scene keys (material, ψ parameters, rest angles) so that the static equilibrium matches a measured
    /// shape; prints the JSON result, writes the fitted scene.
    Fit(hinge_cli::fit::FitArgs),
    /// Stability on stiff and extreme cases: a table of cases, each passing or failing with its figures.
    Stability(stability::StabilityArgs),
    /// List the built-in scenes with one line each, or print one's TOML (`hinge scenes show NAME`).
    Scenes {
        /// `show`
        action: Option<String>,
        /// Scene name for `show`.
        name: Option<String>,
    },
}

/// Standard output closed or failing (`hinge … | head`, a full disk) makes `println!` panic; this hook turns
/// that panic into what a Unix tool does instead of a backtrace: a closed pipe ends the process silently with
/// exit code 141 (128 + SIGPIPE, as a shell reports a tool killed by it), any other write error prints one
/// line and exits with 1. Every other panic goes to the default hook.
fn quiet_stdout_failures() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if let Some(reason) = message.strip_prefix("failed printing to stdout: ") {
            if reason.contains("Broken pipe") || reason.contains("os error 32") {
                std::process::exit(141);
            }
            eprintln!("hinge: cannot write to standard output: {reason}");
            std::process::exit(1);
        }
        default(info);
    }));
}

/// Clap's usage error `text` as one line: its first line without the "error: " prefix and, when that line
/// announces a list ("the following required arguments were not provided:"), the list's indented lines
/// joined onto it (the first line alone named no argument).
fn usage_line(text: &str) -> String {
    let mut lines = text.lines();
    let mut line = lines
        .next()
        .unwrap_or("invalid arguments")
        .trim_start_matches("error: ")
        .to_string();
    if line.ends_with(':') {
        let items: Vec<&str> = lines
            .take_while(|l| l.starts_with(char::is_whitespace) && !l.trim().is_empty())
            .map(str::trim)
            .collect();
        if !items.is_empty() {
            line.push(' ');
            line.push_str(&items.join(", "));
        }
    }
    line
}

fn main() -> ExitCode {
    quiet_stdout_failures();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            use clap::error::ErrorKind;
            if matches!(
                e.kind(),
                ErrorKind::DisplayHelp
                    | ErrorKind::DisplayVersion
                    | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
            ) {
                let _ = e.print();
                return ExitCode::SUCCESS;
            }
            // Usage errors: one line, non-zero exit.
            eprintln!("hinge: {} (see `hinge --help`)", usage_line(&e.to_string()));
            return ExitCode::from(2);
        }
    };
    let result = match cli.command {
        None => run_job(run::RunArgs {
            scene: "drape".into(),
            ..run::RunArgs::default()
        }),
        Some(Command::Stats { rest, deformed, n }) => stats(rest, deformed, n),
        Some(Command::Eval(args)) => eval::run(args),
        Some(Command::Bench(args)) => bench::run(args),
        Some(Command::Run(args)) => run_job(args),
        Some(Command::Report(args)) => report::run(args),
        Some(Command::Stability(args)) => stability::run(args),
        Some(Command::Fit(args)) => hinge_cli::fit::run(args),
        Some(Command::Scenes { action, name }) => scenes(action.as_deref(), name.as_deref()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) if message == INTERRUPTED => {
            eprintln!(
                "hinge: interrupted (Ctrl-C); frames completed before it are written, a static solve writes nothing; summary.json is marked interrupted"
            );
            ExitCode::from(130)
        }
        Err(message) => {
            eprintln!("hinge: {message}");
            ExitCode::FAILURE
        }
    }
}

/// The message [`run_job`] returns for an interrupted run (exit code 130).
const INTERRUPTED: &str = "\0interrupted";

/// `hinge run`, with an interrupted run as the error [`INTERRUPTED`].
fn run_job(args: run::RunArgs) -> Result<(), String> {
    match run::run(args)? {
        run::Completion::Finished => Ok(()),
        run::Completion::Interrupted => Err(INTERRUPTED.into()),
    }
}

fn scenes(action: Option<&str>, name: Option<&str>) -> Result<(), String> {
    match (action, name) {
        (None, _) => {
            let width = scene::BUILT_IN
                .iter()
                .map(|(n, _)| n.len())
                .max()
                .unwrap_or(0);
            for (n, text) in scene::BUILT_IN {
                println!("{n:width$}  {}", scene::description(text));
            }
            Ok(())
        }
        (Some("show"), Some(n)) => match scene::BUILT_IN.iter().find(|(b, _)| *b == n) {
            Some((_, text)) => {
                print!("{text}");
                Ok(())
            }
            None => Err(format!(
                "unknown scene `{n}` (built-in: {})",
                scene::BUILT_IN.map(|b| b.0).join(", ")
            )),
        },
        (Some("show"), None) => Err("usage: hinge scenes show NAME".into()),
        (Some(other), _) => Err(format!(
            "unknown action `{other}` (use `hinge scenes` or `hinge scenes show NAME`)"
        )),
    }
}

/// Reads a deformed state of `rest` from a mesh file (OBJ, OFF, PLY or STL), with how that file counts its
/// vertices and faces. Only its positions are used: its vertices must be the rest mesh's, in the same
/// order, and its faces the rest mesh's, in any order and with their corners in any rotation (as another
/// tool may write them back), else the first face that is not the rest mesh's is named.
pub(crate) fn read_deformed(
    rest: &TriMesh,
    path: &std::path::Path,
) -> Result<(TriMesh, hinge_core::meshio::FileNumbering), String> {
    let (d, names) = hinge_cli::files::read_numbered(path)?;
    hinge_cli::files::check_same_mesh(rest, &d, Some(&names), &path.display().to_string())?;
    rest.with_positions(d.into_parts().0)
        .map(|m| (m, names))
        .map_err(|e| format!("{}: {e}", path.display()))
}

fn stats(
    rest: Option<std::path::PathBuf>,
    deformed: Option<std::path::PathBuf>,
    n: usize,
) -> Result<(), String> {
    let (mesh, label) = match &rest {
        Some(p) => (hinge_cli::files::read(p)?, p.display().to_string()),
        None => (
            {
                hinge_cli::limits::memory(
                    grid::counts(n, n).0,
                    hinge_cli::limits::STATS_BYTES_PER_VERTEX,
                    &format!("--n {n}"),
                )?;
                grid::unit_grid(n).map_err(|e| format!("default grid: {e}"))?
            },
            format!("default {n}×{n} unit grid"),
        ),
    };
    let current: TriMesh = match (&deformed, &rest) {
        (Some(p), _) => read_deformed(&mesh, p)?.0,
        (None, Some(_)) => mesh.clone(),
        (None, None) => mesh
            .with_positions(grid::wave(mesh.positions()))
            .map_err(|e| e.to_string())?,
    };
    let topo =
        Topology::new(mesh.n_vertices(), mesh.triangles()).map_err(|e| format!("{label}: {e}"))?;
    println!("mesh: {label}");
    println!(
        "  vertices {}  triangles {}  edges {}  boundary edges {}  hinges {}",
        mesh.n_vertices(),
        mesh.n_triangles(),
        topo.edges().len(),
        topo.n_boundary_edges(),
        topo.hinges().len()
    );
    let mut thetas = Vec::with_capacity(topo.hinges().len());
    for (i, h) in topo.hinges().iter().enumerate() {
        let x = h.vertices.map(|v| current.positions()[v]);
        let f = HingeFrames::new(&x)
            .map_err(|e| format!("hinge {i} (vertices {:?}): {e}", h.vertices))?;
        thetas.push(f.theta());
    }
    if thetas.is_empty() {
        println!("  no hinges: nothing bends");
        return Ok(());
    }
    thetas.sort_by(f64::total_cmp);
    let mean = thetas.iter().sum::<f64>() / thetas.len() as f64;
    let rms = (thetas.iter().map(|t| t * t).sum::<f64>() / thetas.len() as f64).sqrt();
    let q = |p: f64| thetas[((thetas.len() - 1) as f64 * p).round() as usize];
    println!("hinge angle θ (radians) of the deformed state:");
    println!(
        "  min {:.6}  median {:.6}  max {:.6}  mean {:.6}  rms {:.6}",
        q(0.0),
        q(0.5),
        q(1.0),
        mean,
        rms
    );
    Ok(())
}
