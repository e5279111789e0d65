//! `hinge report`: the paper's evaluation (§7) and more — Hessian accuracy against a double-double
//! reference along the drape, cost against vertex count with power-law fits, the share of step time in
//! bending, and error against run time. Writes `report.md`, `report.json` and PNG plots.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::{unit_grid, wave};
use hinge_core::nalgebra::Vector3;
use hinge_core::precise::{Dd, Jet};
use hinge_energies::bending::TanBending;
use serde_json::{Value, json};

use crate::plot::{PALETTE, Plot, Series, render_png};
use crate::run::simulate;

/// Arguments of `hinge report`.
#[derive(Args)]
pub struct ReportArgs {
    /// Fewer and smaller resolutions, shorter timings: about 17 s on 2 cores.
    #[arg(long)]
    pub quick: bool,
    /// Output directory.
    #[arg(long, default_value = "out/report")]
    pub out: PathBuf,
}

/// The reference Hessian of the tan energy `k a (2 tan(θ/2) − 2 tan(θ̄/2))²` of `model` at `x`, assembled in
/// double-double into the model's pattern (lower CSC order).
pub fn reference_hessian(model: &BendingModel<TanBending>, x: &[Vector3<f64>]) -> Vec<Dd> {
    let k = model.psi().k;
    let rest = model.rest_hinges();
    hinge_core::precise::reference_hessian(model, x, |h, t| {
        let r = &rest[h];
        let ka = Dd::from(k) * Dd::from(r.a);
        let phi_bar = Dd::from(r.theta_bar * 0.5).tan() * 2.0;
        let d = (t * Dd::from(0.5)).tan() * Dd::from(2.0) - Jet::constant(phi_bar);
        (d * d) * ka
    })
}

/// ‖H − H_ref‖_F / ‖H_ref‖_F over the full symmetric matrix, in units of 2⁻⁵³.
fn ulps(model: &BendingModel<TanBending>, h: &[f64], href: &[Dd]) -> f64 {
    hinge_core::precise::hessian_ulps(model.pattern(), h, href)
}

thread_local! {
    /// The least total time [`timed`] spends on one measurement (0.2 s; `--quick` 0.05 s).
    static MIN_TOTAL: std::cell::Cell<f64> = const { std::cell::Cell::new(0.2) };
}

/// Median seconds of `f` over repeated runs: at least 3 runs and 0.2 s (`--quick`: 0.05 s) unless the runs
/// take over 2 s, at most 15.
fn timed(mut f: impl FnMut() -> Result<(), String>) -> Result<f64, String> {
    let min_total = MIN_TOTAL.with(std::cell::Cell::get);
    let mut t = Vec::new();
    let mut total = 0.0;
    while t.len() < 15 {
        let s = Instant::now();
        f()?;
        let e = s.elapsed().as_secs_f64();
        t.push(e);
        total += e;
        if (t.len() >= 3 && total >= min_total) || total >= 2.0 {
            break;
        }
    }
    t.sort_by(f64::total_cmp);
    Ok(t[t.len() / 2])
}

/// Median seconds of forces + Hessian + assembly (no energy value) by `method` on one thread.
fn time_method(
    model: &BendingModel<TanBending>,
    x: &[Vector3<f64>],
    method: Method,
) -> Result<f64, String> {
    let (mut out, mut scratch) = (model.new_output(), model.new_scratch());
    let request = Request {
        value: false,
        gradient: true,
        hessian: true,
        definite: false,
    };
    timed(|| {
        model
            .evaluate_into(
                x,
                request,
                method,
                Parallelism::Sequential,
                &mut scratch,
                &mut out,
            )
            .map_err(err)
    })
}

fn quantiles(v: &[f64]) -> (f64, f64, f64) {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize];
    (q(0.5), q(0.99), q(1.0))
}

/// Power-law fit `t = a n^k` by least squares in log–log: `(k, ln a)`.
pub fn fit(points: &[(f64, f64)]) -> (f64, f64) {
    let n = points.len() as f64;
    let (mx, my) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + x.ln() / n, b + y.ln() / n)
    });
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (x, y) in points {
        sxy += (x.ln() - mx) * (y.ln() - my);
        sxx += (x.ln() - mx) * (x.ln() - mx);
    }
    let k = sxy / sxx;
    (k, my - k * mx)
}

const METHODS: [Method; 3] = [Method::Refactored, Method::PerHinge, Method::Autodiff];

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Accuracy along the drape at `cells` resolution: per method, the error of each snapshot, and the median
/// evaluation time at the last snapshot.
fn accuracy(cells: usize, frames: usize, every: usize) -> Result<Value, String> {
    let (mut scene, _) = crate::scene::load("drape")?;
    scene.set_resolution(cells)?;
    scene.frames = frames;
    let rest = scene.rest_mesh(None)?;
    let mut snapshots: Vec<Vec<Vector3<f64>>> = Vec::new();
    simulate(&scene, &rest, None, |frame, _, _, x| {
        if (frame + 1) % every == 0 {
            snapshots.push(x.to_vec());
        }
    })?;
    let m = &scene.material;
    let k = hinge_energies::bending::stiffness_from_material(m.young, m.thickness, m.poisson);
    let model = BendingModel::new(&rest, TanBending { k }).map_err(err)?;
    let mut per_method: Vec<Vec<f64>> = vec![Vec::new(); 3];
    let mut max_theta: f64 = 0.0;
    for x in &snapshots {
        let href = reference_hessian(&model, x);
        for (i, &method) in METHODS.iter().enumerate() {
            let e = model
                .evaluate(x, Request::ALL, method, Parallelism::Sequential)
                .map_err(err)?;
            per_method[i].push(ulps(&model, &e.hessian, &href));
        }
        let topo = model.topology();
        for h in topo.hinges() {
            let s = h.vertices.map(|v| x[v]);
            if let Ok(t) = hinge_core::hinge::hinge_angle(&s) {
                max_theta = max_theta.max(t.abs());
            }
        }
    }
    let last = snapshots.last().ok_or("no snapshot")?;
    let mut methods = serde_json::Map::new();
    for (i, &method) in METHODS.iter().enumerate() {
        let sec = time_method(&model, last, method)?;
        let (med, p99, max) = quantiles(&per_method[i]);
        methods.insert(
            method.name().into(),
            json!({"ulps": per_method[i], "median_ulps": med, "p99_ulps": p99, "max_ulps": max,
                   "seconds": sec}),
        );
    }
    Ok(json!({
        "cells": cells,
        "n_vertices": rest.n_vertices(),
        "n_hinges": model.topology().hinges().len(),
        "snapshots": snapshots.len(),
        "max_abs_theta": max_theta,
        "methods": methods,
    }))
}

/// Cost of forces + Hessian + assembly per method (one thread) and of one implicit-Euler linear solve on an
/// n×n unit grid under the wave deformation.
fn cost(cells: usize, with_autodiff: bool) -> Result<Value, String> {
    use hinge_core::energy::{Energy, HingeTerm, System};
    use hinge_energies::membrane::StvkMembrane;
    use hinge_solver::linear::{FaerLlt, LinearSolver};
    let rest: TriMesh = unit_grid(cells).map_err(err)?;
    let x = wave(rest.positions());
    let model = BendingModel::new(&rest, TanBending { k: 1e-3 }).map_err(err)?;
    let mut methods = serde_json::Map::new();
    for method in METHODS {
        if method == Method::Autodiff && !with_autodiff {
            continue;
        }
        let sec = time_method(&model, &x, method)?;
        methods.insert(method.name().into(), json!(sec));
    }
    // The Newton system of implicit Euler: bending + membrane + M/Δt².
    let nv = rest.n_vertices();
    let terms: Vec<Box<dyn Energy>> = vec![
        Box::new(StvkMembrane::new(&rest, 1e4, 0.3, 1e-3).map_err(err)?),
        Box::new(HingeTerm::new("bending", model.clone(), Method::Refactored)),
    ];
    let mut sys = System::new(nv, terms).map_err(err)?;
    let (red, values, rhs) = crate::bench::newton_system(&mut sys, &rest, &x)?;
    let mut solver = FaerLlt::default();
    solver.analyze(&red.csc).map_err(err)?;
    let solve = timed(|| {
        solver.factor(&values).map_err(err)?;
        let mut b = rhs.clone();
        solver.solve(&mut b).map_err(err)
    })?;
    Ok(json!({
        "cells": cells,
        "n_vertices": nv,
        "n_hinges": model.topology().hinges().len(),
        "seconds": methods,
        "linear_solve_seconds": solve,
    }))
}

/// Share of step time in bending evaluation + assembly, other energies and the linear solve.
fn fraction(name: &str, resolution: Option<usize>, frames: usize) -> Result<Value, String> {
    let (mut scene, _) = crate::scene::load(name)?;
    if let Some(r) = resolution {
        scene.set_resolution(r)?;
    }
    scene.frames = frames;
    let rest = scene.rest_mesh(None)?;
    let s = simulate(&scene, &rest, None, |_, _, _, _| {})?;
    let t = s.total_seconds;
    Ok(json!({
        "scene": name,
        "n_vertices": s.n_vertices,
        "frames": frames,
        "newton_iterations": s.newton_iterations,
        "step_seconds": t,
        "bending_fraction": s.bending_seconds / t,
        "other_energies_fraction": s.other_energy_seconds / t,
        "linear_solve_fraction": s.linear_solve_seconds / t,
    }))
}

/// A section's row, or — when it failed — `what` with the error recorded, so that one failing resolution
/// (say a Newton step that does not converge) is reported without losing the rest of the report.
fn recorded(row: Result<Value, String>, mut what: Value) -> Value {
    match row {
        Ok(v) => v,
        Err(e) => {
            eprintln!("hinge report: {what}: {e}");
            what["error"] = json!(e);
            what
        }
    }
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// Runs `hinge report`.
pub fn run(args: ReportArgs) -> Result<(), String> {
    let start = Instant::now();
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    MIN_TOTAL.with(|m| m.set(if args.quick { 0.05 } else { 0.2 }));
    let (acc_cells, frames, every): (&[usize], usize, usize) = if args.quick {
        (&[10, 20], 60, 30)
    } else {
        // 12 of the paper's 36 resolutions (10 to 80 cells in steps of 2: 11×11 to 81×81 vertices).
        (&[10, 12, 14, 16, 18, 22, 26, 30, 36, 44, 56, 80], 90, 15)
    };
    let cost_cells: &[usize] = if args.quick {
        &[10, 16, 25, 40, 63, 100, 160]
    } else {
        &[10, 16, 25, 40, 63, 100, 160, 250, 320, 400]
    };
    let autodiff_max = if args.quick { 100 } else { 400 };

    let mut accuracy_rows = Vec::new();
    for &c in acc_cells {
        println!("accuracy: drape at {c}×{c} cells, {frames} frames…");
        accuracy_rows.push(recorded(accuracy(c, frames, every), json!({"cells": c})));
    }
    let mut cost_rows = Vec::new();
    for &c in cost_cells {
        println!("cost: {}×{} vertices…", c + 1, c + 1);
        cost_rows.push(recorded(cost(c, c <= autodiff_max), json!({"cells": c})));
    }
    let mut fractions = vec![recorded(
        fraction("drape", None, if args.quick { 20 } else { 90 }),
        json!({"scene": "drape"}),
    )];
    for b in 1..=5 {
        let name = format!("beam{b}");
        fractions.push(recorded(
            fraction(&name, None, if args.quick { 30 } else { 200 }),
            json!({ "scene": name }),
        ));
    }
    let failures: Vec<String> = accuracy_rows
        .iter()
        .chain(&cost_rows)
        .chain(&fractions)
        .filter_map(|r| r["error"].as_str().map(str::to_string))
        .collect();

    // Fits.
    let mut fits = serde_json::Map::new();
    let series_of = |pick: &dyn Fn(&Value) -> Option<f64>| -> Vec<(f64, f64)> {
        cost_rows
            .iter()
            .filter_map(|r| pick(r).map(|t| (f(&r["n_vertices"]), t)))
            .collect()
    };
    let mut cost_series = Vec::new();
    for m in METHODS {
        let pts = series_of(&|r| r["seconds"][m.name()].as_f64());
        cost_series.push((m.name().to_string(), pts));
    }
    cost_series.push((
        "linear_solve".into(),
        series_of(&|r| r["linear_solve_seconds"].as_f64()),
    ));
    let ln_a_ref = fit(&cost_series[0].1).1;
    let reference = cost_series[0].1.clone();
    for (name, pts) in &cost_series {
        if pts.len() < 2 {
            continue;
        }
        let (k, ln_a) = fit(pts);
        // With different exponents a_other/a_refactored depends on the units of n; the geometric mean of the
        // time ratios over the common sizes is the speed-up at a common exponent.
        let logs: Vec<f64> = pts
            .iter()
            .filter_map(|(n, t)| {
                reference
                    .iter()
                    .find(|(m, _)| m == n)
                    .map(|(_, r)| (t / r).ln())
            })
            .collect();
        let common = (logs.iter().sum::<f64>() / logs.len().max(1) as f64).exp();
        fits.insert(
            name.clone(),
            json!({"k": k, "ln_a": ln_a, "a_over_a_refactored": (ln_a - ln_a_ref).exp(),
                   "ratio_to_refactored_common_k": common, "points": pts.len()}),
        );
    }

    let report = json!({
        "quick": args.quick,
        "threads_for_methods": 1,
        "accuracy": accuracy_rows,
        "cost": cost_rows,
        "fits": fits,
        "fractions": fractions,
        "seconds": start.elapsed().as_secs_f64(),
        "failures": failures,
    });
    let path = args.out.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report).map_err(err)?)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    write_plots(&report, &cost_series, &args.out)?;
    let md = markdown(&report);
    let path = args.out.join("report.md");
    std::fs::write(&path, &md).map_err(|e| format!("{}: {e}", path.display()))?;
    println!("{md}");
    println!(
        "report written to {} in {:.0} s",
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    if failures.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "{} report row(s) failed (recorded in report.json): {}",
            failures.len(),
            failures.join("; ")
        ))
    }
}

fn write_plots(
    report: &Value,
    cost: &[(String, Vec<(f64, f64)>)],
    out: &Path,
) -> Result<(), String> {
    // Error against run time: a point per method and resolution, joined per method.
    let mut series = Vec::new();
    for (i, m) in METHODS.iter().enumerate() {
        let rows = report["accuracy"].as_array().cloned().unwrap_or_default();
        let pts: Vec<(f64, f64)> = rows
            .iter()
            .map(|r| {
                let e = &r["methods"][m.name()];
                (f(&e["seconds"]) * 1e3, f(&e["median_ulps"]))
            })
            .collect();
        // Each point labelled with its vertex count.
        let labels = rows
            .iter()
            .map(|r| format!("{} v", r["n_vertices"]))
            .collect();
        series.push(Series {
            name: m.name().into(),
            color: PALETTE[i],
            points: pts,
            lines: true,
            labels,
            fit: None,
        });
    }
    render_png(
        &Plot {
            title: "Hessian error vs run time (drape, per resolution)".into(),
            x_label: "forces + Hessian + assembly, ms (1 thread)".into(),
            y_label: "median error, ulps".into(),
            series,
        },
        &out.join("error_vs_time.png"),
    )?;
    let series = cost
        .iter()
        .enumerate()
        .map(|(i, (name, pts))| {
            // The measured points, and the power-law fit drawn through them (its exponent in the legend).
            let fit = (pts.len() >= 2).then(|| fit(pts));
            Series {
                name: fit.map_or(name.clone(), |(k, _)| format!("{name} n^{k:.2}")),
                color: PALETTE[i],
                points: pts.clone(),
                lines: false,
                labels: Vec::new(),
                fit,
            }
        })
        .collect();
    render_png(
        &Plot {
            title: "Cost against vertex count".into(),
            x_label: "vertices".into(),
            y_label: "seconds".into(),
            series,
        },
        &out.join("cost.png"),
    )
}

fn markdown(r: &Value) -> String {
    let mut s = String::new();
    s.push_str("# hinge report\n\n");
    s.push_str(&format!(
        "{} run, {:.0} s. Commands: `hinge report{}`.\n\n",
        if r["quick"].as_bool() == Some(true) {
            "Quick"
        } else {
            "Full"
        },
        f(&r["seconds"]),
        if r["quick"].as_bool() == Some(true) {
            " --quick"
        } else {
            ""
        }
    ));
    s.push_str("## Accuracy (paper Fig. 6)\n\nBending Hessian of the tan energy along the drape, each method against a double-double reference (jets over double-double differentiating θ's definition); normwise relative Frobenius error in ulps (2⁻⁵³) over the snapshots; time of forces + Hessian + assembly at the last snapshot, one thread.\n\n");
    s.push_str("| vertices | hinges | snapshots | max abs θ | method | median | p99 | max | time (ms) |\n|---:|---:|---:|---:|---|---:|---:|---:|---:|\n");
    for row in r["accuracy"].as_array().into_iter().flatten() {
        if let Some(e) = row["error"].as_str() {
            s.push_str(&format!("| {} | failed: {e} |\n", row["cells"]));
            continue;
        }
        for m in METHODS {
            let e = &row["methods"][m.name()];
            s.push_str(&format!(
                "| {} | {} | {} | {:.3} | {} | {:.2} | {:.2} | {:.2} | {:.3} |\n",
                row["n_vertices"],
                row["n_hinges"],
                row["snapshots"],
                f(&row["max_abs_theta"]),
                m.name(),
                f(&e["median_ulps"]),
                f(&e["p99_ulps"]),
                f(&e["max_ulps"]),
                f(&e["seconds"]) * 1e3
            ));
        }
    }
    s.push_str("\n![error vs time](error_vs_time.png)\n\n## Cost (paper Fig. 7, Table 2)\n\nForces + Hessian + assembly per method (one thread, median of repeated runs) on an n×n unit grid under a wave; linear solve = faer LLᵀ factor + solve of the implicit-Euler Newton system (bending + membrane + M/Δt², all cores).\n\n");
    s.push_str("| vertices | hinges | refactored (ms) | per_hinge (ms) | autodiff (ms) | per_hinge / refactored | autodiff / refactored | linear solve (ms) |\n|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for row in r["cost"].as_array().into_iter().flatten() {
        if let Some(e) = row["error"].as_str() {
            s.push_str(&format!("| {} | failed: {e} |\n", row["cells"]));
            continue;
        }
        let t = |m: &str| row["seconds"][m].as_f64();
        let ms = |v: Option<f64>| v.map_or("–".into(), |v| format!("{:.3}", v * 1e3));
        let ratio = |v: Option<f64>| {
            v.zip(t("refactored"))
                .map_or("–".into(), |(a, b)| format!("{:.2}", a / b))
        };
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} |\n",
            row["n_vertices"],
            row["n_hinges"],
            ms(t("refactored")),
            ms(t("per_hinge")),
            ms(t("autodiff")),
            ratio(t("per_hinge")),
            ratio(t("autodiff")),
            f(&row["linear_solve_seconds"]) * 1e3
        ));
    }
    s.push_str("\nFits t = a·n^k (n vertices, t seconds); the last column is the geometric mean of the time ratios to refactored (the speed-up at a common exponent):\n\n| series | k | ln a | a / a_refactored | time / refactored | points |\n|---|---:|---:|---:|---:|---:|\n");
    if let Some(fits) = r["fits"].as_object() {
        for (name, v) in fits {
            s.push_str(&format!(
                "| {name} | {:.3} | {:.3} | {:.2} | {:.2} | {} |\n",
                f(&v["k"]),
                f(&v["ln_a"]),
                f(&v["a_over_a_refactored"]),
                f(&v["ratio_to_refactored_common_k"]),
                v["points"]
            ));
        }
    }
    s.push_str("\n![cost](cost.png)\n\n## Share of step time (paper Table 1)\n\n| scene | vertices | frames | Newton iterations | step time (s) | bending eval + assembly | other energies | linear solve |\n|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for row in r["fractions"].as_array().into_iter().flatten() {
        if let Some(e) = row["error"].as_str() {
            s.push_str(&format!("| {} | failed: {e} |\n", row["scene"]));
            continue;
        }
        s.push_str(&format!(
            "| {} | {} | {} | {} | {:.3} | {:.1}% | {:.1}% | {:.1}% |\n",
            row["scene"].as_str().unwrap_or("?"),
            row["n_vertices"],
            row["frames"],
            row["newton_iterations"],
            f(&row["step_seconds"]),
            100.0 * f(&row["bending_fraction"]),
            100.0 * f(&row["other_energies_fraction"]),
            100.0 * f(&row["linear_solve_fraction"])
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_failed_row_is_recorded_and_rendered_not_fatal() {
        let ok = recorded(
            Ok(json!({"cells": 10, "n_vertices": 121})),
            json!({"cells": 10}),
        );
        assert!(ok["error"].is_null());
        let bad = recorded(Err("frame 19: no convergence".into()), json!({"cells": 80}));
        assert_eq!(bad["error"], "frame 19: no convergence");
        let md = markdown(&json!({"quick": true, "seconds": 1.0, "accuracy": [bad],
                                  "cost": [], "fits": {}, "fractions": []}));
        assert!(
            md.contains("| 80 | failed: frame 19: no convergence |"),
            "{md}"
        );
    }

    #[test]
    fn power_law_fit_recovers_exponent_and_prefactor() {
        let pts: Vec<(f64, f64)> = [100.0, 1e3, 1e4, 1e5]
            .iter()
            .map(|&n: &f64| (n, 3e-7 * n.powf(1.25)))
            .collect();
        let (k, ln_a) = fit(&pts);
        assert!((k - 1.25).abs() < 1e-12 && (ln_a - 3e-7f64.ln()).abs() < 1e-10);
    }
}
