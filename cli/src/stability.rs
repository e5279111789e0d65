//! `hinge stability`: stiff and extreme cases, each passing or failing with its figures.
//!
//! A case passes when nothing non-finite comes out unannounced: values are finite, or the library returns a
//! typed error; solvers converge, or fail with a clear error and the state untouched; relative errors do not
//! grow where the mathematics says they should not (scaling).

use clap::Args;
use hinge_core::TriMesh;
use hinge_core::bending::{BendingModel, Method, Parallelism, Request};
use hinge_core::grid::{Diagonal, grid, wave};
use hinge_core::hinge::{Stencil, hinge_angle_hessian};
use hinge_core::nalgebra::Vector3;
use hinge_core::precise::{Dd, reference_hinge_angle, ulps};
use hinge_core::psi::HingePsi;
use hinge_energies::bending::{
    Bridson, DiscreteShells, TanBending, ViscousDamping, Willmore, stiffness_from_material,
};
use hinge_solver::newton::ImplicitEuler;
use serde_json::{Value, json};
use std::f64::consts::PI;

/// Arguments of `hinge stability`.
#[derive(Args)]
pub struct StabilityArgs {
    /// Write `{"cases": [...]}` to this file.
    #[arg(long)]
    pub json: Option<std::path::PathBuf>,
    /// Small instances of every case (what the tests run).
    #[arg(long)]
    pub quick: bool,
}

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// Two triangles on the edge x1 = (0,0,0) – x2 = (1,0,0): x0 above, x3 rotated about the edge by `phi`
/// (φ = 0: flat; |φ| → π: folded onto x0). Triangles (x0, x1, x2) and (x3, x2, x1).
fn two_triangles(phi: f64) -> Result<TriMesh, String> {
    let p = vec![
        Vector3::new(0.4, 0.8, 0.0),
        Vector3::new(0.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.6, -0.8 * phi.cos(), 0.8 * phi.sin()),
    ];
    TriMesh::new(p, vec![[0, 1, 2], [3, 2, 1]]).map_err(err)
}

/// What one evaluation gave: `Ok((energy, max |gradient|, max |Hessian|))` or a typed error's text;
/// `finite` is false only for non-finite numbers returned as success.
struct Probe {
    text: Value,
    finite: bool,
    energy: Option<f64>,
}

fn probe<P: HingePsi + Send + 'static>(model: &BendingModel<P>, x: &[Vector3<f64>]) -> Probe
where
    P::Params: Send + Sync,
{
    match model.evaluate(x, Request::ALL, Method::Refactored, Parallelism::Sequential) {
        Ok(e) => {
            let g = e.gradient.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let h = e.hessian.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let finite = e.energy.is_finite() && g.is_finite() && h.is_finite();
            Probe {
                text: json!({"energy": e.energy, "max_abs_gradient": g, "max_abs_hessian": h}),
                finite,
                energy: Some(e.energy),
            }
        }
        Err(e) => Probe {
            text: json!({"typed_error": e.to_string()}),
            finite: true,
            energy: None,
        },
    }
}

/// Bend angles 0.9π … π − 1e-6 (both signs) for one hinge energy on a flat rest hinge.
fn near_pi<P: HingePsi + Send + 'static>(name: &str, psi: P) -> Result<Value, String>
where
    P::Params: Send + Sync,
{
    let mut model = BendingModel::new(&two_triangles(0.0)?, psi).map_err(err)?;
    // Damping needs a step: the previous state is the flat rest.
    model
        .set_step(two_triangles(0.0)?.positions(), 0.01)
        .map_err(err)?;
    let mut rows = Vec::new();
    let mut pass = true;
    let mut energies = Vec::new();
    for theta in [0.9 * PI, 0.99 * PI, 0.999 * PI, PI - 1e-6] {
        for sign in [1.0, -1.0] {
            let x = two_triangles(sign * theta)?;
            let p = probe(&model, x.positions());
            pass &= p.finite;
            if sign > 0.0 {
                energies.push(p.energy.unwrap_or(f64::INFINITY));
            }
            rows.push(json!({"theta": sign * theta, "result": p.text}));
        }
    }
    let mut case = json!({"name": format!("near ±π: {name}"), "pass": pass, "angles": rows});
    if name == "tan-bending" {
        // The barrier: the energy grows without bound as θ → π (like 1/(π − θ)²).
        let grows = energies.windows(2).all(|w| w[1] > 10.0 * w[0]);
        case["barrier_energies"] = json!(energies);
        case["barrier_grows"] = json!(grows);
        case["pass"] = json!(pass && grows);
    }
    Ok(case)
}

/// Rest angle θ̄ = ±(π − ε): at rest, moving toward π, and across π (the angle wraps to ∓(π − ε/2)).
fn wrap<P: HingePsi + Clone + Send + 'static>(name: &str, psi: P, eps: f64) -> Result<Value, String>
where
    P::Params: Send + Sync,
{
    let mut rows = Vec::new();
    let mut pass = true;
    for sign in [1.0, -1.0] {
        let bar = sign * (PI - eps);
        let rest = two_triangles(bar)?;
        let mut model = BendingModel::new(&rest, psi.clone()).map_err(err)?;
        model.set_step(rest.positions(), 0.01).map_err(err)?;
        let at_rest = probe(&model, rest.positions());
        let toward = probe(&model, two_triangles(sign * (PI - 0.5 * eps))?.positions());
        let across = probe(&model, two_triangles(sign * (PI + 0.5 * eps))?.positions());
        let rest_energy = at_rest.energy.unwrap_or(0.0);
        pass &= at_rest.finite && toward.finite && across.finite && rest_energy.abs() < 1e-12;
        rows.push(json!({
            "theta_bar": bar,
            "at_rest": at_rest.text,
            "toward_pi": toward.text,
            "across_pi": across.text,
        }));
    }
    Ok(
        json!({"name": format!("rest angle near ±π (ε = {eps:e}): {name}"), "pass": pass, "rest_states": rows}),
    )
}

/// Near-degenerate upper triangle: x0's altitude over the hinge edge is `rel` times the edge length.
fn degenerate(quick: bool) -> Value {
    let rels: &[f64] = if quick {
        &[1e-4, 1e-8, 1e-12, 0.0]
    } else {
        &[1e-4, 1e-6, 1e-8, 1e-10, 1e-12, 0.0]
    };
    let mut rows = Vec::new();
    let mut pass = true;
    for &rel in rels {
        let s: Stencil = [
            Vector3::new(0.3, rel, 0.0),
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1.0, 0.0, 0.0),
            Vector3::new(0.6, -0.5 * 0.7f64.cos(), 0.5 * 0.7f64.sin()),
        ];
        match hinge_angle_hessian(&s) {
            Ok(d) => {
                let flat: [f64; 12] = std::array::from_fn(|k| s[k / 3][k % 3]);
                let r = reference_hinge_angle(&flat);
                let href: Vec<Dd> = (0..144).map(|k| r.hessian(k / 12, k % 12)).collect();
                let e = ulps(d.hessian.as_slice(), &href);
                let finite = d.hessian.iter().all(|v| v.is_finite());
                pass &= finite && rel > 0.0;
                rows.push(json!({"altitude": rel, "hessian_ulps": e, "max_abs_hessian": d.hessian.amax()}));
            }
            Err(e) => {
                // A typed error is the required outcome at true collapse; earlier it is allowed too.
                rows.push(json!({"altitude": rel, "typed_error": e.to_string()}));
            }
        }
    }
    let collapsed_is_error = rows.last().is_some_and(|r| r.get("typed_error").is_some());
    json!({"name": "near-degenerate triangles", "pass": pass && collapsed_is_error, "altitudes": rows})
}

/// The refactored Hessian's error against the reference, and the energy, at scales 1e-6, 1, 1e6.
fn scales(quick: bool) -> Result<Value, String> {
    let cells = if quick { 8 } else { 20 };
    let base = grid(cells, cells, 1.0, 1.0, Diagonal::Alternating).map_err(err)?;
    let bent = wave(base.positions());
    let mut rows = Vec::new();
    let mut reference = None;
    let mut pass = true;
    for s in [1.0, 1e-6, 1e6] {
        let rest = base
            .with_positions(base.positions().iter().map(|p| p * s).collect())
            .map_err(err)?;
        let x: Vec<Vector3<f64>> = bent.iter().map(|p| p * s).collect();
        let model = BendingModel::new(&rest, TanBending { k: 1.0 }).map_err(err)?;
        let e = model
            .evaluate(
                &x,
                Request::ALL,
                Method::Refactored,
                Parallelism::Sequential,
            )
            .map_err(err)?;
        let href = crate::report::reference_hessian(&model, &x);
        let h: Vec<f64> = e.hessian.clone();
        let u = ulps(&h, &href);
        let (e0, u0) = *reference.get_or_insert((e.energy, u));
        let energy_change = (e.energy - e0).abs() / e0.abs();
        pass &= energy_change < 1e-12 && u <= 2.0 * u0 + 2.0 && e.energy.is_finite();
        rows.push(
            json!({"scale": s, "energy": e.energy, "energy_relative_change": energy_change,
                         "hessian_ulps": u}),
        );
    }
    Ok(json!({"name": "extreme scales (1e-6, 1e6)", "pass": pass, "scales": rows}))
}

/// Statics of a clamped strip for a range of materials: Newton converges, and the tip deflection matches
/// linear plate theory where that holds (δ/L ≤ 5% by the formula), or else stays below the strip's length.
fn stiff_beams(quick: bool) -> Result<Vec<Value>, String> {
    let youngs: &[f64] = if quick {
        &[1e6, 2e11]
    } else {
        &[1e6, 1e8, 1e10, 2e11]
    };
    let thicknesses: &[f64] = if quick {
        &[1e-4, 1e-2]
    } else {
        &[1e-4, 1e-3, 1e-2]
    };
    let mut out = Vec::new();
    for &y in youngs {
        for &h in thicknesses {
            let (mut scene, _) = crate::scene::load("beam5")?;
            scene.material.young = y;
            scene.material.thickness = h;
            scene.material.density = 1000.0 * h;
            let rest = scene.rest_mesh(None)?;
            let name = format!("stiff beam: Y = {y:e} Pa, h = {h:e} m");
            let (length, plate) = plate_tip_deflection(&scene)?;
            match crate::run::equilibrium(&scene, &rest, None, None, None) {
                Ok(s) => {
                    // Newton stopped on its own tests (gradient or step tolerance): converged.
                    let converged = s.final_gradient_norm.is_finite();
                    let tip = s.far_end_drop;
                    // Linear theory holds for small deflections: there the tip must match the plate
                    // formula within the beam tests' 10%; beyond, it must stay below the strip's length
                    // (the whole strip: a soft one hangs by its free length plus its stretch).
                    let linear = plate <= PLATE_LINEAR_RANGE * length;
                    let shape_ok = if linear {
                        (tip / plate - 1.0).abs() < PLATE_TOLERANCE
                    } else {
                        tip > 0.0 && tip < scene.mesh.size[0]
                    };
                    out.push(json!({"name": name, "pass": converged && shape_ok,
                        "newton_iterations": s.newton_iterations, "final_residual": s.final_gradient_norm,
                        "tip_deflection": tip, "plate_tip_deflection": plate, "free_length": length,
                        "checked_against": if linear { "plate formula" } else { "strip length" }}));
                }
                Err(e) => out.push(json!({"name": name, "pass": false, "error": e})),
            }
        }
    }
    Ok(out)
}

/// Largest plate-formula deflection, as a fraction of the free length, at which a stiff beam is checked
/// against the formula (linear theory holds: δ/L ≤ 5%).
const PLATE_LINEAR_RANGE: f64 = 0.05;

/// Relative tolerance of a tip deflection against the plate formula (the beam tests' 10%).
const PLATE_TOLERANCE: f64 = 0.10;

/// The free length of a clamped strip scene and its tip deflection by linear plate theory under its own
/// weight: `δ = q L⁴ / (8 D)` with `q` the weight per area, `D = Y h³ / (12 (1 − ν²))`, and `L` the strip
/// length minus the clamped columns' width.
fn plate_tip_deflection(scene: &crate::scene::Scene) -> Result<(f64, f64), String> {
    let cells = scene
        .mesh
        .cells
        .ok_or("stiff beams: the beam scene must be a grid")?;
    let clamped = scene.pins.clamp_columns.unwrap_or(1).max(1) - 1;
    let length = scene.mesh.size[0] * (1.0 - clamped as f64 / cells[0] as f64);
    let m = &scene.material;
    let d = m.young * m.thickness.powi(3) / (12.0 * (1.0 - m.poisson * m.poisson));
    let g = Vector3::from(scene.gravity).norm();
    Ok((length, m.density * g * length.powi(4) / (8.0 * d)))
}

/// Large time steps with the default Newton strategy on the clamped strips (the soft ones swing down by
/// most of their length within one step of 1 s): every step converges, or fails with a clear error and the
/// state untouched.
fn large_steps(quick: bool) -> Result<Vec<Value>, String> {
    let mut out = Vec::new();
    let beams: &[&str] = if quick {
        &["beam1"]
    } else {
        &["beam1", "beam3"]
    };
    for &beam in beams {
        for dt in [0.01, 0.1, 0.5, 1.0] {
            let (mut scene, _) = crate::scene::load(beam)?;
            scene.dt = dt;
            let rest = scene.rest_mesh(None)?;
            let b = crate::run::build(&scene, &rest, true)?;
            let mut system = b.system;
            let mut stepper = ImplicitEuler::new(&system, dt, b.masses, b.pins, b.solver, b.params)
                .map_err(err)?;
            let (mut x, mut v) = (
                rest.positions().to_vec(),
                vec![Vector3::zeros(); rest.n_vertices()],
            );
            let mut iterations = Vec::new();
            let mut failure = Value::Null;
            let mut pass = true;
            for _ in 0..5 {
                let (x0, v0) = (x.clone(), v.clone());
                match stepper.step(&mut system, &mut x, &mut v) {
                    Ok(s) => iterations.push(s.iterations),
                    Err(e) => {
                        let intact = x == x0 && v == v0;
                        pass = intact;
                        failure = json!({"error": e.to_string(), "state_intact": intact});
                        break;
                    }
                }
            }
            let finite = x.iter().all(|p| p.iter().all(|c| c.is_finite()));
            let r = rest.positions();
            let drop = (0..r.len()).map(|i| r[i].z - x[i].z).fold(0.0f64, f64::max);
            out.push(
                json!({"name": format!("large time step: {beam}, dt = {dt} s"),
                "pass": pass && finite, "newton_iterations": iterations, "largest_drop": drop,
                "failure": failure}),
            );
        }
    }
    Ok(out)
}

/// Whether symplectic Euler with step `h` runs `duration` seconds of `scene` (without damping: explicit
/// damping has a stability limit of its own) from rest without blowing up.
fn explicit_stable(
    scene: &crate::scene::Scene,
    rest: &TriMesh,
    h: f64,
    duration: f64,
) -> Result<bool, String> {
    let b = crate::run::build(scene, rest, false)?;
    let mut system = b.system;
    let mut stepper =
        hinge_solver::explicit::SymplecticEuler::new(&system, h, 1, b.masses, &b.pins)
            .map_err(err)?;
    let (mut x, mut v) = (
        rest.positions().to_vec(),
        vec![Vector3::zeros(); rest.n_vertices()],
    );
    for _ in 0..(duration / h).ceil() as usize {
        match stepper.advance(&mut system, &mut x, &mut v) {
            Ok(_) => {}
            Err(hinge_solver::newton::SolverError::Unstable { .. }) => return Ok(false),
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(x.iter().all(|p| p.iter().all(|c| c.is_finite())))
}

/// The largest stable explicit step against the implicit step that works (lecture P12–P14): the limit
/// `2/ω_max` predicted from the rest Hessian, the largest step symplectic Euler survives for `duration`
/// (bisection in log scale between an eighth of and four times the prediction: penalty contact, absent from
/// the rest Hessian, lowers the limit once the cloth lands), and three implicit-Euler steps of the scene's
/// own dt. It passes when the explicit run survives the small end and blows up (detected, never NaN) at
/// the large one, and the implicit step works and is more than ten times the explicit limit.
fn explicit_limits(quick: bool) -> Result<Vec<Value>, String> {
    let mut out = Vec::new();
    let cases: &[(&str, Option<usize>, f64)] = if quick {
        &[("beam1", None, 0.02), ("drape", Some(12), 0.3)]
    } else {
        &[("beam1", None, 0.05), ("drape", None, 0.4)]
    };
    for &(name, resolution, duration) in cases {
        let (mut scene, _) = crate::scene::load(name)?;
        if let Some(r) = resolution {
            scene.set_resolution(r)?;
        }
        let rest = scene.rest_mesh(None)?;
        let b = crate::run::build(&scene, &rest, false)?;
        let mut system = b.system;
        let predicted = hinge_solver::explicit::critical_step(
            &mut system,
            rest.positions(),
            &b.masses,
            &b.pins,
            300,
        )
        .map_err(err)?;
        let (mut lo, mut hi) = (0.125 * predicted, 4.0 * predicted);
        let stable_at_eighth = explicit_stable(&scene, &rest, lo, duration)?;
        let unstable_at_4 = !explicit_stable(&scene, &rest, hi, duration)?;
        for _ in 0..if quick { 6 } else { 10 } {
            let mid = (lo * hi).sqrt();
            if explicit_stable(&scene, &rest, mid, duration)? {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        // The implicit step of the scene's own dt (undamped too).
        let b = crate::run::build(&scene, &rest, false)?;
        let mut system = b.system;
        let mut implicit =
            ImplicitEuler::new(&system, scene.dt, b.masses, b.pins, b.solver, b.params)
                .map_err(err)?;
        let (mut x, mut v) = (
            rest.positions().to_vec(),
            vec![Vector3::zeros(); rest.n_vertices()],
        );
        let implicit_ok = (0..3).all(|_| implicit.step(&mut system, &mut x, &mut v).is_ok());
        out.push(json!({
            "name": format!("explicit limit: {name} ({} vertices, no damping)", rest.n_vertices()),
            "pass": stable_at_eighth && unstable_at_4 && implicit_ok && scene.dt > 10.0 * lo,
            "predicted_explicit_step": predicted,
            "largest_stable_explicit_step": lo,
            "duration": duration,
            "implicit_step": scene.dt,
            "implicit_step_works": implicit_ok,
            "implicit_over_explicit": scene.dt / lo,
        }));
    }
    Ok(out)
}

/// All cases.
pub fn cases(quick: bool) -> Result<Vec<Value>, String> {
    let k = stiffness_from_material(2e5, 5e-4, 0.3);
    let mut cases = stiff_beams(quick)?;
    cases.push(near_pi("discrete-shells", DiscreteShells { k })?);
    cases.push(near_pi("tan-bending", TanBending { k })?);
    cases.push(near_pi("willmore", Willmore { k })?);
    cases.push(near_pi("bridson", Bridson { k })?);
    cases.push(near_pi("viscous-damping", ViscousDamping { kd: k })?);
    for eps in if quick { vec![1e-2] } else { vec![1e-2, 1e-4] } {
        cases.push(wrap("discrete-shells", DiscreteShells { k }, eps)?);
        cases.push(wrap("tan-bending", TanBending { k }, eps)?);
        cases.push(wrap("willmore", Willmore { k }, eps)?);
        cases.push(wrap("bridson", Bridson { k }, eps)?);
    }
    cases.push(degenerate(quick));
    cases.push(scales(quick)?);
    cases.extend(large_steps(quick)?);
    cases.extend(explicit_limits(quick)?);
    Ok(cases)
}

/// `v` with three significant digits (fixed notation between 1e-3 and 1e4, else scientific).
fn sig(v: f64) -> String {
    let a = v.abs();
    if v == 0.0 {
        "0".into()
    } else if !v.is_finite() {
        format!("{v}")
    } else if (1e-3..1e4).contains(&a) {
        let decimals = (2 - a.log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    } else {
        format!("{v:.2e}")
    }
}

/// The largest of `field` over the `result`-like objects of a case's list `key` (`path` picks the object).
fn largest(case: &Value, key: &str, path: &[&str], field: &str) -> f64 {
    let mut m = 0.0_f64;
    for item in case[key].as_array().into_iter().flatten() {
        let mut objs = Vec::new();
        if path.is_empty() {
            objs.push(item);
        }
        for p in path {
            objs.push(&item[*p]);
        }
        for o in objs {
            if let Some(v) = o[field].as_f64() {
                m = m.max(v.abs());
            }
        }
    }
    m
}

/// How many entries of a case's list `key` ended in a typed error.
fn typed_errors(case: &Value, key: &str) -> usize {
    let mut n = 0;
    for item in case[key].as_array().into_iter().flatten() {
        let text = item.to_string();
        n += text.matches("typed_error").count();
    }
    n
}

/// The readable figures of a case: rounded, with units (the JSON keeps every figure at full precision).
fn figures(case: &Value) -> String {
    let f = |k: &str| case[k].as_f64().unwrap_or(f64::NAN);
    if case.get("tip_deflection").is_some() {
        return format!(
            "tip {} m (plate theory {} m; checked against the {}), {} Newton iterations, ‖∇E‖ {} N",
            sig(f("tip_deflection")),
            sig(f("plate_tip_deflection")),
            case["checked_against"].as_str().unwrap_or("?"),
            case["newton_iterations"],
            sig(f("final_residual"))
        );
    }
    if case.get("angles").is_some() {
        return format!(
            "{} angles: largest energy {} J, |gradient| {} N, |Hessian| {} N/m; {} typed errors{}",
            case["angles"].as_array().map_or(0, Vec::len),
            sig(largest(case, "angles", &["result"], "energy")),
            sig(largest(case, "angles", &["result"], "max_abs_gradient")),
            sig(largest(case, "angles", &["result"], "max_abs_hessian")),
            typed_errors(case, "angles"),
            match case["barrier_grows"].as_bool() {
                Some(true) => "; the barrier grows towards ±π",
                Some(false) => "; the barrier does NOT grow towards ±π",
                None => "",
            }
        );
    }
    if case.get("rest_states").is_some() {
        let parts = ["at_rest", "toward_pi", "across_pi"];
        return format!(
            "{} rest states: largest energy {} J, |gradient| {} N, |Hessian| {} N/m; {} typed errors",
            case["rest_states"].as_array().map_or(0, Vec::len),
            sig(largest(case, "rest_states", &parts, "energy")),
            sig(largest(case, "rest_states", &parts, "max_abs_gradient")),
            sig(largest(case, "rest_states", &parts, "max_abs_hessian")),
            typed_errors(case, "rest_states")
        );
    }
    if case.get("altitudes").is_some() {
        return format!(
            "{} altitudes down to 0: Hessian error at most {} ulps, |Hessian| up to {} N/m; {} typed errors",
            case["altitudes"].as_array().map_or(0, Vec::len),
            sig(largest(case, "altitudes", &[], "hessian_ulps")),
            sig(largest(case, "altitudes", &[], "max_abs_hessian")),
            typed_errors(case, "altitudes")
        );
    }
    if case.get("scales").is_some() {
        return format!(
            "{} scales: energy changes by at most {} (relative), Hessian error at most {} ulps",
            case["scales"].as_array().map_or(0, Vec::len),
            sig(largest(case, "scales", &[], "energy_relative_change")),
            sig(largest(case, "scales", &[], "hessian_ulps"))
        );
    }
    if case.get("largest_drop").is_some() {
        let its: Vec<String> = case["newton_iterations"]
            .as_array()
            .into_iter()
            .flatten()
            .map(Value::to_string)
            .collect();
        return format!(
            "largest drop {} m, Newton iterations per step [{}]{}",
            sig(f("largest_drop")),
            its.join(", "),
            case["failure"]
                .as_str()
                .map_or(String::new(), |e| format!("; failed: {e}"))
        );
    }
    if case.get("largest_stable_explicit_step").is_some() {
        return format!(
            "explicit step stable up to {} s over {} s (predicted 2/ω_max = {} s); the implicit step {} s {} ({}× larger)",
            sig(f("largest_stable_explicit_step")),
            sig(f("duration")),
            sig(f("predicted_explicit_step")),
            sig(f("implicit_step")),
            if case["implicit_step_works"].as_bool() == Some(true) {
                "works"
            } else {
                "FAILS"
            },
            sig(f("implicit_over_explicit"))
        );
    }
    // Any other case: its fields, compact.
    let mut s = String::new();
    for (k, v) in case.as_object().into_iter().flatten() {
        if k != "name" && k != "pass" {
            let t = v.to_string();
            s.push_str(&format!("{k}={} ", t.chars().take(60).collect::<String>()));
        }
    }
    s
}

/// Runs `hinge stability`.
pub fn run(args: StabilityArgs) -> Result<(), String> {
    let cases = cases(args.quick)?;
    let mut failed = 0;
    for c in &cases {
        let pass = c["pass"].as_bool() == Some(true);
        failed += usize::from(!pass);
        println!(
            "{} {:<48} {}",
            if pass { "PASS" } else { "FAIL" },
            c["name"].as_str().unwrap_or("?"),
            figures(c)
        );
    }
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&json!({"cases": cases})).map_err(err)?;
        std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    println!("{} cases, {failed} failed", cases.len());
    if failed > 0 {
        return Err(format!("{failed} stability case(s) failed"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::sig;

    #[test]
    fn figures_are_rounded_to_three_significant_digits() {
        assert_eq!(sig(0.2954195563079083), "0.295");
        assert_eq!(sig(10141.208754665624), "1.01e4");
        assert_eq!(sig(101.41208754665624), "101");
        assert_eq!(sig(5.434509654241668e-6), "5.43e-6");
        assert_eq!(sig(0.013718314293482095), "0.0137");
        assert_eq!(sig(-2.5), "-2.50");
        assert_eq!(sig(0.0), "0");
    }
}
