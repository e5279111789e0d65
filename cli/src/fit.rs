//! `hinge fit`: the scene keys that make a scene's static equilibrium match a measured shape.
//!
//! The scene is built as `hinge run --static` builds it; each key becomes a variable of
//! [`hinge_solver::adjoint::Fit`] linked to the system parameters it sets:
//!
//! | key | sets | fitted as |
//! |---|---|---|
//! | `material.young` | bending `k` (∝ Y, when k comes from the material), membrane (∝ Y) | positive |
//! | `material.thickness` | bending `k` (∝ h³), membrane (∝ h) | positive |
//! | `material.poisson` | bending `k` (∝ 1/(1 − ν²)), membrane (its ν; the co-rotational one's stiffness ∝ 1/(1 + ν)) | in (−1, 0.5) |
//! | `material.density` | gravity (∝ ρ: the weight per area) | positive |
//! | `bending.params.NAME` | the custom ψ's parameter (scalar or per hinge) | positive if its start is |
//! | `bending.rest_angles` | the rest angles θ̄, one per hinge | any sign |
//!
//! The loss is the sum of squared distances of every vertex to the target's. Stdout carries only the
//! JSON result; progress goes to stderr; the fitted scene (`fitted.toml`, per-hinge values beside it) and the
//! fitted equilibrium (`fitted.obj`) go to `--out`.

use std::path::{Path, PathBuf};

use hinge_core::meshio::FileNumbering;
use hinge_core::nalgebra::Vector3;
use hinge_core::{ElementNames, TriMesh};
use hinge_energies::membrane::{MembraneModel, POISSON_BOUNDS};
use hinge_solver::adjoint::{
    AdjointError, FieldCheck, Fit, FitOptions, FitVariable, Link, TargetLoss,
};
use hinge_solver::newton::{Newton, NewtonParams};
use hinge_solver::statics::continued_start;

use crate::run::{Built, STATIC_ITERATIONS, build};
use crate::scene::Scene;

/// The keys `hinge fit` accepts (`bending.params.NAME` for any custom-ψ parameter).
pub const KEYS: &str = "material.young, material.thickness, material.poisson, material.density, bending.params.NAME, bending.rest_angles";

/// Arguments of `hinge fit`.
#[derive(clap::Args, Debug, Clone)]
pub struct FitArgs {
    /// Scene: a built-in name (`hinge scenes`) or a TOML file.
    pub scene: String,
    /// The measured shape: a mesh file (OBJ, OFF, PLY or STL) with the scene mesh's vertices and faces.
    #[arg(long)]
    pub target: PathBuf,
    /// Scene keys to fit, comma-separated: material.young, material.thickness, material.poisson,
    /// material.density, bending.params.NAME, bending.rest_angles.
    #[arg(long, value_delimiter = ',', required = true)]
    pub fit: Vec<String>,
    /// Mesh resolution, as for `hinge run`.
    #[arg(long)]
    pub resolution: Option<usize>,
    /// Output directory for fitted.toml and fitted.obj (default: out/fit-SCENE).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// L-BFGS iteration limit, 0 to 1 000 000 (0 evaluates the start only).
    #[arg(long, default_value_t = 50)]
    pub max_iterations: usize,
    /// Weight of the smoothness regularizer on per-hinge keys (squared differences of the log values, or
    /// of the values for rest angles, over adjacent hinges; 0: none).
    #[arg(long, default_value_t = 0.0)]
    pub smoothness: f64,
    /// Worker threads (default: all logical CPUs).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// What `hinge fit` found.
#[derive(Debug, Clone)]
pub struct Fitted {
    /// Every key with its fitted value(s).
    pub values: Vec<(String, Vec<f64>)>,
    /// The loss at the fitted values.
    pub loss: f64,
    /// L-BFGS iterations.
    pub iterations: usize,
    /// Equilibrium solves, line-search trials included.
    pub equilibria: usize,
    /// Newton iterations in all: the first equilibrium (through the membrane continuation when the scene
    /// asks for it) and every solve of the fit.
    pub newton_iterations: usize,
    /// The fitted equilibrium.
    pub x: Vec<Vector3<f64>>,
    /// Why the fit stopped.
    pub stop: &'static str,
    /// How many values of each per-hinge key the target determines ([`FieldCheck`]).
    pub fields: Vec<FieldCheck>,
}

impl Fitted {
    /// The JSON `hinge fit` prints: `{"fitted": {KEY: value or [values]}, "loss", "iterations",
    /// "equilibria", "newton_iterations", "fields"}`, `fields` with `{KEY: {"entries", "without_effect",
    /// "determined"}}` for every checked per-hinge key.
    pub fn json(&self) -> serde_json::Value {
        let fitted: serde_json::Map<String, serde_json::Value> = self
            .values
            .iter()
            .map(|(k, v)| {
                let value = if v.len() == 1 {
                    serde_json::json!(v[0])
                } else {
                    serde_json::json!(v)
                };
                (k.clone(), value)
            })
            .collect();
        let fields: serde_json::Map<String, serde_json::Value> = self
            .fields
            .iter()
            .filter_map(|f| {
                let r = f.rank?;
                Some((
                    f.variable.clone(),
                    serde_json::json!({
                        "entries": f.entries,
                        "without_effect": r.without_effect,
                        "determined": r.determined,
                    }),
                ))
            })
            .collect();
        serde_json::json!({
            "fitted": fitted,
            "loss": self.loss,
            "iterations": self.iterations,
            "equilibria": self.equilibria,
            "newton_iterations": self.newton_iterations,
            "fields": fields,
        })
    }
}

/// The variable of `key` in the system `b` built from `scene`.
///
/// # Errors
/// A one-line message naming the key.
fn variable(scene: &Scene, b: &Built, key: &str) -> Result<FitVariable, String> {
    let has = |name: &str| b.system.parameters().iter().any(|p| p.name == name);
    let value = |name: &str| b.system.parameter(name).map_err(|e| format!("{key}: {e}"));
    let m = &scene.material;
    // The bending stiffness follows the material unless the custom ψ's `k` is set explicitly.
    let k_from_material = has("bending.k")
        && !(scene.bending.energy == "custom" && scene.bending.params.contains_key("k"));
    let power = |parameter: &str, exponent: f64| Link::Power {
        parameter: parameter.into(),
        exponent,
    };
    let model = b.membrane;
    // The membrane parameter `young` or `thickness`: the co-rotational membrane has one stiffness,
    // proportional to both.
    let membrane = |parameter: &str| -> Link {
        match model {
            MembraneModel::Corotational => power(model.stiffness_parameter(), 1.0),
            _ => power(&format!("{}.{parameter}", model.energy_name()), 1.0),
        }
    };
    let positive_start = |v: f64| -> Result<Vec<f64>, String> {
        if v > 0.0 && v.is_finite() {
            Ok(vec![v])
        } else {
            Err(format!(
                "{key}: the start value {v} must be positive (it is fitted on a log scale)"
            ))
        }
    };
    let mut links = Vec::new();
    let mut range = None;
    let (start, positive) = match key {
        "material.young" => {
            if k_from_material {
                links.push(power("bending.k", 1.0));
            }
            links.push(membrane("young"));
            (positive_start(m.young)?, true)
        }
        "material.thickness" => {
            if k_from_material {
                links.push(power("bending.k", 3.0));
            }
            links.push(membrane("thickness"));
            (positive_start(m.thickness)?, true)
        }
        "material.density" => {
            links.push(power("gravity.g", 1.0));
            (positive_start(m.density)?, true)
        }
        "material.poisson" => {
            // k ∝ 1/(1 − ν²); the co-rotational membrane's stiffness ∝ 1/(1 + ν); the StVK and neo-Hookean
            // membranes take ν itself.
            let inverse = |parameter: &str, coefficients: [f64; 3]| Link::Quadratic {
                parameter: parameter.into(),
                coefficients,
                exponent: -1.0,
            };
            if k_from_material {
                links.push(inverse("bending.k", [1.0, 0.0, -1.0]));
            }
            links.push(match model {
                MembraneModel::Corotational => {
                    inverse(model.stiffness_parameter(), [1.0, 1.0, 0.0])
                }
                _ => Link::Value {
                    parameter: format!("{}.poisson", model.energy_name()),
                },
            });
            range = Some(POISSON_BOUNDS);
            (vec![m.poisson], false)
        }
        "bending.rest_angles" => {
            links.push(Link::Value {
                parameter: "bending.theta_bar".into(),
            });
            (value("bending.theta_bar")?, false)
        }
        _ => match key.strip_prefix("bending.params.") {
            Some(name) if scene.bending.energy == "custom" => {
                if !scene.bending.params.contains_key(name) {
                    return Err(if name == "k" && k_from_material {
                        format!(
                            "{key}: k comes from the material here; fit material.young (or set bending.params.k)"
                        )
                    } else {
                        format!(
                            "{key}: the scene's [bending.params] has no `{name}` (it has: {})",
                            scene
                                .bending
                                .params
                                .keys()
                                .cloned()
                                .collect::<Vec<_>>()
                                .join(", ")
                        )
                    });
                }
                let parameter = format!("bending.{name}");
                let start = value(&parameter)?;
                let positive = start.iter().all(|v| *v > 0.0);
                links.push(if positive {
                    power(&parameter, 1.0)
                } else {
                    Link::Value { parameter }
                });
                (start, positive)
            }
            Some(_) => {
                return Err(format!(
                    "{key}: only a custom ψ (bending.energy = \"custom\") has parameters"
                ));
            }
            None => return Err(format!("unknown key `{key}` (fittable: {KEYS})")),
        },
    };
    Ok(FitVariable {
        name: key.to_string(),
        start,
        positive,
        range,
        links,
    })
}

/// Pairs of hinges that share a triangle (the smoothness regularizer's neighbours), for variable `k`.
fn adjacent_hinges(rest: &TriMesh, k: usize) -> Result<Vec<(usize, usize, usize)>, String> {
    let topo = hinge_core::Topology::new(rest.n_vertices(), rest.triangles())
        .map_err(|e| e.to_string())?;
    let mut of_edge = std::collections::HashMap::new();
    for (i, h) in topo.hinges().iter().enumerate() {
        let (a, b) = (h.vertices[1], h.vertices[2]);
        of_edge.insert((a.min(b), a.max(b)), i);
    }
    let mut pairs = Vec::new();
    for t in rest.triangles() {
        let inner: Vec<usize> = (0..3)
            .filter_map(|c| {
                let (a, b) = (t[c], t[(c + 1) % 3]);
                of_edge.get(&(a.min(b), a.max(b))).copied()
            })
            .collect();
        for i in 0..inner.len() {
            for j in i + 1..inner.len() {
                pairs.push((k, inner[i], inner[j]));
            }
        }
    }
    Ok(pairs)
}

/// Fits `keys` of `scene` (mesh `rest`) so that its static equilibrium matches `target`. With `names` (the
/// scene's mesh file's numbering), an evaluation or equilibrium error at a vertex, triangle or hinge is
/// told as the file counts them.
///
/// # Errors
/// A one-line message: an unknown or repeated key, a non-positive start of a positive key, a target that
/// does not match the mesh, an equilibrium that does not converge, keys not separately identifiable.
pub fn fit_scene(
    scene: &Scene,
    rest: &TriMesh,
    target: &TriMesh,
    target_name: &str,
    keys: &[String],
    options: FitOptions,
    names: Option<&FileNumbering>,
) -> Result<Fitted, String> {
    fit_scene_until(scene, rest, target, target_name, keys, options, names, None)
}

/// [`fit_scene`] that ends when `stop` is raised (another thread, a Ctrl-C handler): the equilibrium
/// solves read it before each Newton iteration ([`Newton::set_stop`]) and the fit then fails with an
/// `interrupted` message.
///
/// # Errors
/// As [`fit_scene`].
#[allow(clippy::too_many_arguments)]
pub fn fit_scene_until(
    scene: &Scene,
    rest: &TriMesh,
    target: &TriMesh,
    target_name: &str,
    keys: &[String],
    options: FitOptions,
    names: Option<&FileNumbering>,
    stop: Option<&std::sync::Arc<std::sync::atomic::AtomicBool>>,
) -> Result<Fitted, String> {
    crate::files::check_same_mesh(rest, target, None, target_name)?;
    let b = build(scene, rest, false)?;
    let mut variables = Vec::new();
    for (i, key) in keys.iter().enumerate() {
        if keys[..i].contains(key) {
            return Err(format!("{key}: given twice"));
        }
        variables.push(variable(scene, &b, key)?);
    }
    let mut options = options;
    if options.smoothness > 0.0 {
        for (k, v) in variables.iter().enumerate() {
            if v.start.len() > 1 {
                options.smooth_pairs.extend(adjacent_hinges(rest, k)?);
            }
        }
    }
    let Built {
        mut system,
        pins,
        solver,
        params,
        membrane,
        ..
    } = b;
    let params = NewtonParams {
        max_iterations: params.max_iterations.max(STATIC_ITERATIONS),
        ..params
    };
    let mut newton = Newton::new(&system, &pins, solver, params).map_err(|e| e.to_string())?;
    newton.set_stop(stop.cloned());
    let loss = TargetLoss::all(target.positions().to_vec());
    let mut x = rest.positions().to_vec();
    // The first equilibrium through the membrane continuation (as `hinge run --static`): the fit's solves
    // then start from it, a few iterations each, where a thin stiff strip solved from flat takes hundreds.
    let (parameter, stages) = crate::run::membrane_stages(scene, membrane, rest, &mut system)
        .map_err(|e| crate::run::solver_message(&e, names))?;
    let start_iterations = continued_start(&mut newton, &mut system, &mut x, parameter, &stages);
    let smoothness = options.smoothness;
    let mut fit = Fit::new(&system, &pins, &mut newton, variables, options)
        .map_err(|e| fit_message(&e, names))?;
    fit.observe(|p| {
        eprintln!(
            "fit: iteration {:3}: loss {:.6e} ({} equilibria)",
            p.iteration, p.loss, p.equilibria
        );
    });
    let r = fit
        .run(&mut system, &mut x, &mut |x, g| loss.evaluate(x, g))
        .map_err(|e| fit_message(&e, names))?;
    eprintln!(
        "fit: stopped ({}): loss {:.3e} → {:.3e} in {} iterations, {} equilibria",
        r.stop, r.initial_loss, r.loss, r.iterations, r.equilibria
    );
    for f in &r.fields {
        if let Some(line) = field_note(f, smoothness) {
            eprintln!("{line}");
        }
    }
    Ok(Fitted {
        values: keys.iter().cloned().zip(r.values).collect(),
        loss: r.loss,
        iterations: r.iterations,
        equilibria: r.equilibria,
        newton_iterations: start_iterations + r.newton_iterations,
        x: r.x,
        stop: r.stop,
        fields: r.fields,
    })
}

/// The warning for a per-hinge key the target does not determine (`None` when it does, or when the key was
/// not checked).
fn field_note(f: &FieldCheck, smoothness: f64) -> Option<String> {
    let r = f.rank?;
    let free = f.entries - r.without_effect - r.determined;
    if free == 0 && r.without_effect == 0 {
        return None;
    }
    let mut parts = Vec::new();
    if r.without_effect > 0 {
        parts.push(format!(
            "{} move nothing (hinges inside a clamp, say)",
            r.without_effect
        ));
    }
    if free > 0 {
        parts.push(format!(
            "{free} combinations of the others leave the equilibrium unchanged"
        ));
    }
    Some(format!(
        "fit: warning: the target determines {} of the {} values of {}: {}; {}",
        r.determined,
        f.entries,
        f.variable,
        parts.join(", "),
        if smoothness > 0.0 {
            "the smoothness term chooses among the fields that fit"
        } else {
            "the fitted field is one of many that fit (--smoothness W chooses the smoothest)"
        }
    ))
}

/// A fit's error; with `names` (a mesh file's numbering), an evaluation or equilibrium error names its
/// vertices and faces as the file counts them.
fn fit_message(e: &AdjointError, names: Option<&FileNumbering>) -> String {
    match (e, names) {
        (AdjointError::Eval(e), Some(n)) => format!("{} {}", e.describe(n), n.note()),
        (AdjointError::Equilibrium(e), Some(n)) => {
            format!("equilibrium: {}", crate::run::solver_message(e, Some(n)))
        }
        (AdjointError::NotMinimum { vertex, .. }, Some(n)) => format!(
            "the exact Hessian at the equilibrium is not positive definite (at {}): the state is not a \
             strict minimum, its sensitivities are undefined {}",
            n.vertex(*vertex),
            n.note()
        ),
        _ => e.to_string(),
    }
}

/// The scene's TOML text (a built-in's, or the file's).
fn scene_text(name_or_path: &str) -> Result<String, String> {
    match crate::scene::BUILT_IN
        .iter()
        .find(|(n, _)| *n == name_or_path)
    {
        Some((_, text)) => Ok((*text).to_string()),
        None => std::fs::read_to_string(name_or_path).map_err(|e| format!("{name_or_path}: {e}")),
    }
}

/// Writes numbers one per line.
fn write_numbers(path: &Path, v: &[f64]) -> Result<(), String> {
    let text: String = v.iter().map(|x| format!("{x:e}\n")).collect();
    std::fs::write(path, text).map_err(|e| format!("{}: {e}", path.display()))
}

/// The fitted scene: the original TOML with the fitted keys set (per-hinge values in files beside it) and
/// relative file paths made absolute (the fitted scene lives elsewhere).
fn fitted_toml(
    args: &FitArgs,
    scene: &Scene,
    fitted: &Fitted,
    dir: &Path,
) -> Result<String, String> {
    let text = scene_text(&args.scene)?;
    let mut doc: toml::Table = toml::from_str(&text).map_err(|e| format!("{}: {e}", args.scene))?;
    let base = scene.base.clone();
    let absolute = |p: &str| -> String {
        match &base {
            Some(b) if Path::new(p).is_relative() => {
                let joined = b.join(p);
                std::fs::canonicalize(&joined)
                    .unwrap_or(joined)
                    .display()
                    .to_string()
            }
            _ => p.to_string(),
        }
    };
    let table = |doc: &mut toml::Table, name: &str| -> Result<toml::Table, String> {
        match doc.remove(name) {
            Some(toml::Value::Table(t)) => Ok(t),
            None => Ok(toml::Table::new()),
            Some(_) => Err(format!("{}: `{name}` is not a table", args.scene)),
        }
    };
    let mut mesh = table(&mut doc, "mesh")?;
    if let Some(toml::Value::String(p)) = mesh.get("obj").cloned() {
        mesh.insert("obj".into(), toml::Value::String(absolute(&p)));
    }
    if let Some(cells) = scene.mesh.cells {
        mesh.insert(
            "cells".into(),
            toml::Value::Array(
                cells
                    .iter()
                    .map(|&c| toml::Value::Integer(c as i64))
                    .collect(),
            ),
        );
        mesh.remove("resolutions");
    }
    if let Some(s) = scene.mesh.subdivisions {
        mesh.insert("subdivisions".into(), toml::Value::Integer(s as i64));
    }
    doc.insert("mesh".into(), toml::Value::Table(mesh));
    let mut material = table(&mut doc, "material")?;
    let mut bending = table(&mut doc, "bending")?;
    let mut params = match bending.remove("params") {
        Some(toml::Value::Table(t)) => t,
        _ => toml::Table::new(),
    };
    for (_, v) in params.iter_mut() {
        if let toml::Value::String(p) = v {
            *p = absolute(p);
        }
    }
    if let Some(toml::Value::String(p)) = bending.get("rest_angles").cloned() {
        bending.insert("rest_angles".into(), toml::Value::String(absolute(&p)));
    }
    for (key, values) in &fitted.values {
        let scalar = values.len() == 1;
        match key.as_str() {
            "material.young" | "material.thickness" | "material.poisson" | "material.density" => {
                let name = &key["material.".len()..];
                material.insert(name.into(), toml::Value::Float(values[0]));
            }
            "bending.rest_angles" => {
                let file = dir.join("fitted_rest_angles.txt");
                write_numbers(&file, values)?;
                bending.insert(
                    "rest_angles".into(),
                    toml::Value::String("fitted_rest_angles.txt".into()),
                );
            }
            _ => {
                let name = key.trim_start_matches("bending.params.");
                if scalar {
                    params.insert(name.into(), toml::Value::Float(values[0]));
                } else {
                    let file = format!("fitted_{name}.txt");
                    write_numbers(&dir.join(&file), values)?;
                    params.insert(name.into(), toml::Value::String(file));
                }
            }
        }
    }
    if !params.is_empty() {
        bending.insert("params".into(), toml::Value::Table(params));
    }
    doc.insert("material".into(), toml::Value::Table(material));
    doc.insert("bending".into(), toml::Value::Table(bending));
    let body = toml::to_string(&doc).map_err(|e| format!("fitted scene: {e}"))?;
    Ok(format!(
        "# Fitted by `hinge fit {}` to {} (keys: {}).\n{body}",
        args.scene,
        args.target.display(),
        args.fit.join(", ")
    ))
}

/// `hinge fit`: prints the JSON result on stdout, writes `fitted.toml` and `fitted.obj` to the output
/// directory.
///
/// # Errors
/// A one-line message (see [`fit_scene`]).
pub fn run(args: FitArgs) -> Result<(), String> {
    let (mut scene, base) = crate::scene::load(&args.scene)?;
    if let Some(r) = args.resolution {
        scene.set_resolution(r)?;
    }
    let (threads, warning) = crate::limits::threads(args.threads)?;
    if let Some(w) = warning {
        eprintln!("{w}");
    }
    let (rest, names) = scene.rest_mesh_numbered(base.as_deref())?;
    let (target, target_names) = crate::files::read_numbered(&args.target)?;
    let name = args.target.display().to_string();
    // Checked here too, to name a face that does not fit as the target file counts it.
    crate::files::check_same_mesh(&rest, &target, Some(&target_names), &name)?;
    let options = FitOptions {
        max_iterations: args.max_iterations,
        smoothness: args.smoothness,
        ..FitOptions::default()
    };
    if !(args.smoothness >= 0.0 && args.smoothness.is_finite()) {
        return Err(format!(
            "--smoothness {}: must be non-negative and finite",
            args.smoothness
        ));
    }
    if args.max_iterations > hinge_solver::newton::MAX_ITERATIONS_CEILING {
        return Err(format!(
            "--max-iterations {}: must be from 0 to {}",
            args.max_iterations,
            hinge_solver::newton::MAX_ITERATIONS_CEILING_TEXT
        ));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| format!("thread pool: {e}"))?;
    let fitted = pool.install(|| {
        fit_scene(
            &scene,
            &rest,
            &target,
            &name,
            &args.fit,
            options,
            names.as_ref(),
        )
    })?;
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("out").join(format!("fit-{}", scene.name)));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let toml = fitted_toml(&args, &scene, &fitted, &dir)?;
    std::fs::write(dir.join("fitted.toml"), toml)
        .map_err(|e| format!("{}: {e}", dir.join("fitted.toml").display()))?;
    hinge_core::meshio::write_mesh(dir.join("fitted.obj"), &fitted.x, rest.triangles())
        .map_err(|e| e.to_string())?;
    eprintln!("fit: wrote {}", dir.join("fitted.toml").display());
    println!("{}", fitted.json());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::fit_scene;
    use crate::run::{Built, STATIC_ITERATIONS, build, membrane_stages};
    use crate::scene::load;
    use hinge_energies::membrane::MembraneModel;
    use hinge_solver::adjoint::FitOptions;
    use hinge_solver::newton::{Newton, NewtonParams};
    use hinge_solver::statics::minimize_continued;

    #[test]
    fn a_fit_starts_from_the_equilibrium_the_membrane_continuation_reaches() {
        // The 0.1 mm strip of Y = 1e10 Pa of `hinge stability`'s stiff beams: its equilibrium from flat takes
        // hundreds of Newton iterations without the continuation. Fitted back from Y = 2e10.
        let (mut truth, _) = load("beam5").unwrap();
        truth.material.young = 1e10;
        truth.material.thickness = 1e-4;
        truth.material.density = 0.1;
        let rest = truth.rest_mesh(None).unwrap();
        let Built {
            mut system,
            pins,
            solver,
            params,
            ..
        } = build(&truth, &rest, false).unwrap();
        let params = NewtonParams {
            max_iterations: STATIC_ITERATIONS,
            ..params
        };
        let mut newton = Newton::new(&system, &pins, solver, params).unwrap();
        let (parameter, stages) =
            membrane_stages(&truth, MembraneModel::Stvk, &rest, &mut system).unwrap();
        assert_eq!(parameter, "membrane.young");
        assert!(!stages.is_empty());
        let mut x = rest.positions().to_vec();
        minimize_continued(&mut newton, &mut system, &mut x, parameter, &stages).unwrap();
        let target = rest.with_positions(x).unwrap();
        let mut counts = Vec::new();
        for on in [true, false] {
            let mut scene = truth.clone();
            scene.material.young = 2e10;
            scene.solver.membrane_continuation = on;
            let f = fit_scene(
                &scene,
                &rest,
                &target,
                "target",
                &["material.young".to_string()],
                FitOptions::default(),
                None,
            )
            .unwrap();
            let y = f.values[0].1[0];
            assert!((y / 1e10 - 1.0).abs() < 1e-5, "continuation {on}: Y = {y}");
            counts.push(f.newton_iterations);
        }
        println!("Newton iterations of the fit with / without the continuation: {counts:?}");
        assert!(2 * counts[0] < counts[1], "{counts:?}");
        // A raised stop flag: the fit ends with the interruption, no values (the same scene fits without
        // it, above).
        let flag = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
        let mut scene = truth.clone();
        scene.material.young = 2e10;
        let err = super::fit_scene_until(
            &scene,
            &rest,
            &target,
            "target",
            &["material.young".to_string()],
            FitOptions::default(),
            None,
            Some(&flag),
        )
        .unwrap_err();
        assert!(
            err.starts_with("equilibrium: interrupted after 0 iterations"),
            "{err}"
        );
    }
}
