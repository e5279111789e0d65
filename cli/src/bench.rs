//! `hinge bench`: energy + gradient + Hessian + assembly of discrete shells per method, on the unit grids of
//! 81×81 and 401×401 vertices (flat rest, deformed by z = 0.1·sin(3x)·cos(2y)). Medians after a warm-up.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::{unit_grid, wave};
use hinge_core::psi::{DiscreteShells, Stiffness};

/// Arguments of `hinge bench`.
#[derive(Args)]
pub struct BenchArgs {
    /// Also write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Timed runs per row (at least 5).
    #[arg(long, default_value_t = 7)]
    runs: usize,
    /// Cells per side of the grids (default 80 and 400, i.e. 81×81 and 401×401 vertices).
    #[arg(long, value_delimiter = ',', default_values_t = [80usize, 400])]
    sizes: Vec<usize>,
}

struct Row {
    method: String,
    threads: usize,
    n_vertices: usize,
    n_hinges: usize,
    median_ms: f64,
}

fn median_ms(runs: usize, mut f: impl FnMut() -> Result<(), String>) -> Result<f64, String> {
    f()?; // warm-up
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs {
        let start = Instant::now();
        f()?;
        t.push(start.elapsed().as_secs_f64() * 1e3);
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// Runs `hinge bench`.
pub fn run(args: BenchArgs) -> Result<(), String> {
    let runs = args.runs.max(5);
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let pool = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .map_err(|e| format!("thread pool: {e}"))
    };
    let (one, many) = (pool(1)?, pool(all)?);
    let mut rows = Vec::new();
    for &n in &args.sizes {
        let rest = unit_grid(n).map_err(|e| e.to_string())?;
        let x = wave(rest.positions());
        let model = BendingModel::new(
            &rest,
            DiscreteShells {
                k: Stiffness::Uniform(1.0),
            },
        )
        .map_err(|e| e.to_string())?;
        let (nv, nh) = (model.n_vertices(), model.topology().hinges().len());
        let mut out = model.new_output();
        let mut scratch = model.new_scratch();
        let mut push = |method: &str, threads: usize, ms: f64| {
            rows.push(Row {
                method: method.to_string(),
                threads,
                n_vertices: nv,
                n_hinges: nh,
                median_ms: ms,
            })
        };
        let mut reference: Option<Vec<f64>> = None;
        for (method, threads) in [
            (Method::Refactored, 1),
            (Method::PerHinge, 1),
            (Method::Autodiff, 1),
            (Method::Refactored, all),
        ] {
            let p = if threads == 1 { &one } else { &many };
            let r = if method == Method::Autodiff { 5 } else { runs };
            let ms = median_ms(r, || {
                p.install(|| {
                    model.evaluate_into(
                        &x,
                        Request::ALL,
                        method,
                        Parallelism::Rayon,
                        &mut scratch,
                        &mut out,
                    )
                })
                .map_err(|e| e.to_string())
            })?;
            push(method.name(), threads, ms);
            if method == Method::Refactored {
                // Bitwise identity across thread counts, checked on the benchmark itself.
                match &reference {
                    None => reference = Some(out.hessian.clone()),
                    Some(h) => {
                        if h.iter()
                            .zip(&out.hessian)
                            .any(|(a, b)| a.to_bits() != b.to_bits())
                        {
                            return Err(format!(
                                "{threads}-thread Hessian differs from the 1-thread one"
                            ));
                        }
                    }
                }
            }
        }
        for (name, method) in [
            ("refactored_local", Method::Refactored),
            ("per_hinge_local", Method::PerHinge),
        ] {
            let mut sink = 0.0;
            let ms = median_ms(runs, || {
                sink += model
                    .local_blocks_checksum(&x, method, &mut scratch, &mut out)
                    .map_err(|e| e.to_string())?;
                Ok(())
            })?;
            std::hint::black_box(sink);
            push(name, 1, ms);
        }
        let ms = median_ms(runs, || {
            for v in out.hessian.iter_mut() {
                *v = std::hint::black_box(1.0);
            }
            std::hint::black_box(&out.hessian);
            Ok(())
        })?;
        push("write_floor", 1, ms);
    }
    println!(
        "{:<18} {:>7} {:>10} {:>9} {:>12} {:>12}",
        "method", "threads", "vertices", "hinges", "median_ms", "ns_per_hinge"
    );
    for r in &rows {
        println!(
            "{:<18} {:>7} {:>10} {:>9} {:>12.3} {:>12.1}",
            r.method,
            r.threads,
            r.n_vertices,
            r.n_hinges,
            r.median_ms,
            r.median_ms * 1e6 / r.n_hinges as f64
        );
    }
    for &n in &args.sizes {
        let nv = (n + 1) * (n + 1);
        let get = |m: &str, t: usize| {
            rows.iter()
                .find(|r| r.n_vertices == nv && r.method == m && (t == 0 || r.threads == t))
                .map(|r| r.median_ms)
        };
        if let (Some(rf), Some(ph), Some(ad), Some(rl), Some(pl), Some(rp)) = (
            get("refactored", 1),
            get("per_hinge", 1),
            get("autodiff", 1),
            get("refactored_local", 1),
            get("per_hinge_local", 1),
            get("refactored", all),
        ) {
            println!(
                "{nv} vertices: per_hinge/refactored {:.2}x, per_hinge_local/refactored_local {:.2}x, refactored/refactored_local {:.2}, autodiff/refactored {:.1}x, 1 thread/{all} threads {:.2}x",
                ph / rf,
                pl / rl,
                rf / rl,
                ad / rf,
                rf / rp
            );
        }
    }
    if let Some(path) = args.json {
        let results: Vec<_> = rows
            .iter()
            .map(|r| {
                serde_json::json!({
                    "method": r.method,
                    "threads": r.threads,
                    "n_vertices": r.n_vertices,
                    "n_hinges": r.n_hinges,
                    "median_ms": r.median_ms,
                    "ns_per_hinge": r.median_ms * 1e6 / r.n_hinges as f64,
                })
            })
            .collect();
        let text = serde_json::to_string_pretty(&serde_json::json!({ "results": results }))
            .map_err(|e| e.to_string())?;
        std::fs::write(&path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    Ok(())
}
