//! Scene files (TOML): mesh, material, energies, obstacles, pins, gravity, time step, frames, solver.
//! Unknown keys and invalid values are errors naming the key path. Built-in scenes are embedded in the
//! binary (`hinge scenes`, `hinge scenes show NAME`).

use std::path::{Path, PathBuf};

use hinge_core::TriMesh;
use hinge_core::anisotropy::TriangleUv;
use hinge_core::bending::HessianMode;
use hinge_core::error::Num;
use hinge_core::grid::{Diagonal, grid};
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::runtime::{ParamValue, RuntimePsi, RuntimePsiError};
use hinge_energies::bending::BuiltinBending;
use hinge_energies::membrane::{MembraneModel, POISSON_BOUNDS};
use serde::Deserialize;

/// Built-in scenes: name and TOML text.
pub const BUILT_IN: [(&str, &str); 10] = [
    ("drape", include_str!("../scenes/drape.toml")),
    ("shell-drop", include_str!("../scenes/shell-drop.toml")),
    ("beam1", include_str!("../scenes/beam1.toml")),
    ("beam2", include_str!("../scenes/beam2.toml")),
    ("beam3", include_str!("../scenes/beam3.toml")),
    ("beam4", include_str!("../scenes/beam4.toml")),
    ("beam5", include_str!("../scenes/beam5.toml")),
    (
        "anisotropic-drape",
        include_str!("../scenes/anisotropic-drape.toml"),
    ),
    ("twist", include_str!("../scenes/twist.toml")),
    ("crease", include_str!("../scenes/crease.toml")),
];

/// The one-line description of a scene's TOML text: the first sentence of its leading comment, without the
/// `NAME (…):` it starts with (empty when the text has no leading comment).
pub fn description(text: &str) -> String {
    let comment: Vec<&str> = text
        .lines()
        .map_while(|l| l.strip_prefix('#'))
        .map(str::trim)
        .collect();
    let joined = comment.join(" ");
    let body = joined.split_once(": ").map_or(joined.as_str(), |(_, b)| b);
    match body.find(". ") {
        Some(end) => body[..=end].to_string(),
        None => body.to_string(),
    }
}

/// A scene.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Scene {
    /// Name (used for the default output directory).
    pub name: String,
    /// Frames to simulate (one implicit-Euler step each).
    pub frames: usize,
    /// Time step in seconds.
    pub dt: f64,
    /// The mesh.
    pub mesh: MeshSpec,
    /// Material.
    pub material: Material,
    /// Bending energy.
    #[serde(default)]
    pub bending: BendingSpec,
    /// Gravity (m/s²).
    #[serde(default = "default_gravity")]
    pub gravity: [f64; 3],
    /// Mass-proportional damping ("air drag") rate c in 1/s: force −c m v (0: none).
    #[serde(default)]
    pub drag: f64,
    /// Analytic obstacles.
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    /// Pinned vertices.
    #[serde(default)]
    pub pins: PinSpec,
    /// Solver settings.
    #[serde(default)]
    pub solver: SolverSpec,
    /// The directory of the scene file (what a relative mesh path is resolved against; none for a
    /// built-in scene). Set by [`load`].
    #[serde(skip)]
    pub base: Option<PathBuf>,
}

/// The error for a `bending.energy` that is neither a built-in energy ([`BuiltinBending::NAMES`]) nor
/// `custom`.
pub(crate) fn unknown_bending_energy(energy: &str) -> String {
    format!(
        "bending.energy: unknown `{energy}` ({}, custom)",
        BuiltinBending::NAMES.join(", ")
    )
}

fn default_gravity() -> [f64; 3] {
    [0.0, 0.0, -9.81]
}

/// The mesh: a generated grid (`cells`, `size`, `origin`, `diagonal`) or an OBJ file (`obj`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshSpec {
    /// Grid cells along x and y.
    pub cells: Option<[usize; 2]>,
    /// Named grid resolutions (cells along x and y) that `--resolution 1, 2, …` selects; without them
    /// `--resolution N` sets N cells along x.
    pub resolutions: Option<Vec<[usize; 2]>>,
    /// Grid size (m), positive along both axes.
    #[serde(default = "unit_size")]
    pub size: [f64; 2],
    /// Position of the grid's first vertex.
    #[serde(default)]
    pub origin: [f64; 3],
    /// `forward`, `backward` or `alternating`.
    #[serde(default = "default_diagonal")]
    pub diagonal: String,
    /// A mesh file instead of a grid (OBJ, OFF, PLY or STL by extension; relative to the scene file).
    pub obj: Option<PathBuf>,
    /// A closed surface generated in code instead of a grid: `icosphere` (a subdivided icosahedron centred
    /// at `origin`, `10·4^subdivisions + 2` vertices; `--resolution N` sets the subdivisions).
    pub shape: Option<String>,
    /// Subdivisions of the icosphere (0 to 7).
    pub subdivisions: Option<usize>,
    /// Radius of the icosphere (m).
    pub radius: Option<f64>,
}

fn unit_size() -> [f64; 2] {
    [1.0, 1.0]
}

fn default_diagonal() -> String {
    "alternating".into()
}

/// Material constants.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Material {
    /// Young's modulus (Pa).
    pub young: f64,
    /// Poisson ratio.
    pub poisson: f64,
    /// Thickness (m).
    pub thickness: f64,
    /// Mass per area (kg/m²).
    pub density: f64,
    /// The membrane: `stvk` (St. Venant–Kirchhoff, the default), `corotational` (the co-rotational
    /// membrane, k = Y h / (1 + ν)) or `neo-hookean` (compressible neo-Hookean: infinite energy at zero
    /// area, for soft shells that fold).
    #[serde(default = "default_membrane")]
    pub membrane: String,
}

fn default_membrane() -> String {
    MembraneModel::Stvk.name().into()
}

impl Material {
    /// The membrane model `membrane` names.
    ///
    /// # Errors
    /// A one-line message naming `material.membrane` for a name that is not a model's.
    pub fn model(&self) -> Result<MembraneModel, String> {
        self.membrane
            .parse()
            .map_err(|e| format!("material.membrane: {e}"))
    }
}

/// Bending energy and damping.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BendingSpec {
    /// `discrete-shells`, `tan-bending`, `willmore`, `bridson`, or `custom` (ψ from [`BendingSpec::psi`]).
    pub energy: String,
    /// The custom ψ(θ) in the derive's expression language (with `energy = "custom"`).
    #[serde(default)]
    pub psi: Option<String>,
    /// Parameters of the custom ψ: a number, one number per hinge (an array, hinge order), or the path of a
    /// text file of per-hinge numbers (whitespace-separated, relative to the scene file). A `k` the
    /// expression reads and this table does not set is the material's stiffness (as for the built-ins).
    #[serde(default)]
    pub params: std::collections::BTreeMap<String, ParamSpec>,
    /// Viscous damping coefficient k_d (0: none).
    #[serde(default)]
    pub damping: f64,
    /// How the stiffness k follows from the material: `eq11` (the paper's Eq. 11, `Y h³/(24(1 − ν²))`) or
    /// `plate` (Eq. 11 / 3, which reproduces the plate's energy in cylindrical bending; see
    /// `hinge_energies::bending::plate_consistent_stiffness`).
    #[serde(default = "default_calibration")]
    pub calibration: String,
    /// The Hessian the bending term assembles (`hinge_core::bending::HessianMode`): `exact` (default),
    /// `gauss-newton` (max(ψ″, 0) ∇θ∇θᵀ) or `projected` (each hinge's 12×12 block projected onto the
    /// positive semi-definite cone). Energy and forces are exact in every mode; Newton on a Hessian that
    /// is not exact converges linearly.
    #[serde(default = "default_hessian")]
    pub hessian: String,
    /// Warp/weft anisotropy (none: isotropic).
    #[serde(default)]
    pub anisotropy: Option<AnisotropySpec>,
    /// Bending plasticity (none: elastic).
    #[serde(default)]
    pub plasticity: Option<PlasticitySpec>,
    /// Rest angles to start from, one per hinge in hinge order (whitespace-separated numbers in a text
    /// file, relative to the scene file): a plastic run's `rest_angles_NNNN.txt`, to restart with its
    /// creases. Unset: the rest mesh's own. Radians in [−π, π].
    #[serde(default)]
    pub rest_angles: Option<PathBuf>,
}

/// `[bending.plasticity]`: after every accepted (sub)step a hinge bent more than its yield angle away from
/// its rest angle yields (see `hinge_core::energy::Plasticity`).
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlasticitySpec {
    /// The initial yield angle (rad, ≥ 0).
    pub yield_angle: f64,
    /// Linear hardening: yield-angle growth per radian of accumulated plastic angle (≥ 0; default 0).
    #[serde(default)]
    pub hardening: f64,
}

/// A run-time ψ with the capacity its expression needs: 8 hoisted values per hinge (the fast default), or 32.
#[derive(Debug, Clone)]
pub enum CustomPsi {
    /// Up to 8 hoisted values.
    Small(RuntimePsi),
    /// Up to 32.
    Large(RuntimePsi<32>),
}

impl CustomPsi {
    /// Compiles `expr` with `values`, in the smallest capacity that holds it.
    ///
    /// # Errors
    /// The expression's one-line error.
    pub fn new(expr: &str, values: Vec<(String, ParamValue)>) -> Result<Self, String> {
        match RuntimePsi::new(expr, values.clone()) {
            Ok(p) => Ok(CustomPsi::Small(p)),
            Err(RuntimePsiError::TooManyHoisted { .. }) => {
                RuntimePsi::<32>::with_capacity(expr, values)
                    .map(CustomPsi::Large)
                    .map_err(|e| e.to_string())
            }
            Err(e) => Err(e.to_string()),
        }
    }
}

/// A custom ψ parameter's value in a scene.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum ParamSpec {
    /// One value for all hinges.
    Number(f64),
    /// One value per hinge.
    List(Vec<f64>),
    /// A file of per-hinge values (resolved when the scene is loaded).
    File(String),
}

fn default_calibration() -> String {
    "eq11".into()
}

impl BendingSpec {
    /// [`BendingSpec::hessian`] parsed.
    ///
    /// # Errors
    /// A line naming the key and the modes when the name is none of them.
    pub fn hessian_mode(&self) -> Result<HessianMode, String> {
        HessianMode::from_name(&self.hessian).ok_or_else(|| {
            format!(
                "bending.hessian: unknown `{}` ({})",
                self.hessian,
                HessianMode::ALL.map(HessianMode::name).join(", ")
            )
        })
    }
}

fn default_hessian() -> String {
    HessianMode::Exact.name().into()
}

impl Default for BendingSpec {
    fn default() -> Self {
        Self {
            energy: "tan-bending".into(),
            psi: None,
            params: Default::default(),
            damping: 0.0,
            calibration: default_calibration(),
            hessian: default_hessian(),
            anisotropy: None,
            plasticity: None,
            rest_angles: None,
        }
    }
}

/// `[bending.anisotropy]`: warp/weft bending (see `hinge_core::anisotropy`). Every hinge's ψ is multiplied
/// by `1 + warp·sin²φ + weft·cos²φ`, φ the angle between its rest edge and the warp direction.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AnisotropySpec {
    /// `k_warp / k_bend`: extra stiffness of folds across the warp (that bend the warp threads).
    #[serde(default)]
    pub warp: f64,
    /// `k_weft / k_bend`: extra stiffness of folds along the warp (that bend the weft threads).
    #[serde(default)]
    pub weft: f64,
    /// The warp direction: a vector `[x, y, z]` (projected onto the surface), or `"uv"` for the direction
    /// of increasing u of the mesh's texture coordinates (a grid's u runs along x).
    #[serde(default = "default_warp_direction")]
    pub direction: DirectionSpec,
}

/// The warp direction of [`AnisotropySpec`].
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(untagged)]
pub enum DirectionSpec {
    /// A constant direction.
    Vector([f64; 3]),
    /// `uv`.
    Name(String),
}

fn default_contact_model() -> String {
    "penalty".into()
}

fn default_warp_direction() -> DirectionSpec {
    DirectionSpec::Vector([1.0, 0.0, 0.0])
}

/// A sphere (`center`, `radius`) or a plane (`point`, `normal`) with penalty `stiffness` and `margin`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// `sphere` or `plane`.
    pub kind: String,
    /// Sphere centre.
    pub center: Option<[f64; 3]>,
    /// Sphere radius.
    pub radius: Option<f64>,
    /// A point of the plane.
    pub point: Option<[f64; 3]>,
    /// Plane normal.
    pub normal: Option<[f64; 3]>,
    /// Penalty stiffness.
    pub stiffness: f64,
    /// Contact margin.
    #[serde(default)]
    pub margin: f64,
    /// Smoothing length ε of a C² penalty (`hinge_energies::contact::Contact::with_smoothing`; 0, the
    /// default: the quadratic penalty).
    #[serde(default)]
    pub smoothing: f64,
    /// `penalty` (the default) or `barrier`: a logarithmic barrier reaching `margin` from the obstacle, with
    /// steps bounded so that no vertex reaches it (`hinge_energies::contact::Contact::with_barrier`).
    #[serde(default = "default_contact_model")]
    pub model: String,
    /// A prescribed rigid motion (as `[[pins.groups]]`' `motion`): the sphere's centre, or the plane's point
    /// and normal, move with it; the obstacle given is its position at t = 0.
    pub motion: Option<MotionSpec>,
}

/// Pinned vertices: explicit indices and/or every vertex whose rest x is at most `x_at_most`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinSpec {
    /// Vertex indices, from 0 in the mesh's vertex order (for a mesh file, the order of its vertex records:
    /// OBJ vertex N, which OBJ counts from 1, is N − 1 here).
    #[serde(default)]
    pub vertices: Vec<usize>,
    /// Pin every vertex with rest x ≤ this.
    pub x_at_most: Option<f64>,
    /// Grid scenes: pin the first N vertex columns (x = 0, h_x, …): two columns clamp the edge.
    pub clamp_columns: Option<usize>,
    /// Pin groups with a prescribed motion (`[[pins.groups]]`).
    #[serde(default)]
    pub groups: Vec<PinGroupSpec>,
}

/// `[[pins.groups]]`: vertices moved along a prescribed path from their rest positions, optionally
/// released (unpinned) at a time.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PinGroupSpec {
    /// Vertex indices, from 0 in the mesh's vertex order (for a mesh file, the order of its vertex records:
    /// OBJ vertex N, which OBJ counts from 1, is N − 1 here).
    #[serde(default)]
    pub vertices: Vec<usize>,
    /// Also every vertex with rest x ≥ this.
    pub x_at_least: Option<f64>,
    /// Also every vertex with rest x ≤ this.
    pub x_at_most: Option<f64>,
    /// The motion.
    pub motion: MotionSpec,
    /// Time (s) from which the group is free: it is released at the first frame starting at or after it.
    pub release: Option<f64>,
}

/// A prescribed motion of a pin group: the target of a vertex with rest position p at time t.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct MotionSpec {
    /// `fixed` (p), `translation` (p + velocity·t), `rotation` (p turned about the line through `center`
    /// along `axis` by angular_velocity·t, right-handed) or `keyframes` (p + the offset interpolated
    /// linearly between `times` — from zero at t = 0 to the first —, held after the last).
    pub kind: String,
    /// Translation velocity (m/s).
    pub velocity: Option<[f64; 3]>,
    /// Rotation axis.
    pub axis: Option<[f64; 3]>,
    /// A point on the rotation axis.
    pub center: Option<[f64; 3]>,
    /// Angular velocity (rad/s).
    pub angular_velocity: Option<f64>,
    /// Keyframe times (s), increasing.
    pub times: Option<Vec<f64>>,
    /// Keyframe offsets (m), one per time.
    pub offsets: Option<Vec<[f64; 3]>>,
}

/// A checked pin group.
#[derive(Debug, Clone)]
pub struct PinGroup {
    /// Its vertices (sorted, no duplicates).
    pub vertices: Vec<usize>,
    /// Its motion.
    pub motion: Motion,
    /// Release time.
    pub release: Option<f64>,
}

pub use hinge_energies::motion::Motion;

/// Newton and linear-solver settings.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// `faer-llt`, `faer-lu`, `pcg-jacobi`, `chebyshev-jacobi` or `dense`.
    #[serde(default = "default_backend")]
    pub backend: String,
    /// The fill-reducing ordering of `faer-llt`: `auto` (default: nested dissection or AMD, whichever
    /// leaves the smaller factor), `amd` or `nested-dissection` (see `hinge_solver::ordering`).
    #[serde(default = "default_ordering")]
    pub ordering: String,
    /// Newton iteration limit per step (1 to 1 000 000; a static solve allows itself at least 2 000).
    #[serde(default = "default_iterations")]
    pub max_iterations: usize,
    /// Newton gradient tolerance: stop when ‖∇F‖ ≤ this (N; non-negative, 0 leaves convergence to the
    /// relative and step tests).
    #[serde(default = "default_tolerance")]
    pub gradient_tolerance: f64,
    /// A frame whose step fails is retried in substeps, halving down to `dt / 2^max_substep_halvings`
    /// (0 to 30; default 5, i.e. dt/32) before the run stops.
    #[serde(default = "default_halvings")]
    pub max_substep_halvings: u32,
    /// `shifted-exact` (default: the exact Hessian with a diagonal shift raised until it factors) or
    /// `project-on-demand` (each energy's definite Hessian after a failed factorization; see
    /// `hinge_solver::newton`).
    #[serde(default = "default_globalization")]
    pub globalization: String,
    /// Also stop when ‖∇F‖ ≤ this × ‖∇F‖ at the step's start (unit-free; unset: off).
    #[serde(default)]
    pub relative_gradient_tolerance: Option<f64>,
    /// Also stop when no vertex moves by more than this × the mean rest edge length in a step (unit-free;
    /// unset: off).
    #[serde(default)]
    pub relative_step_tolerance: Option<f64>,
    /// After a full step of a shifted or definite Newton system, keep doubling it while the incremental
    /// potential decreases (default true; false gives the Newton path of versions before it).
    #[serde(default = "default_extrapolate")]
    pub extrapolate: bool,
    /// Start the shift ladder near the last shift that factored, in this step or an earlier one (default
    /// true; false: every step climbs it from the smallest shift, as versions before it did; see
    /// `hinge_solver::newton::NewtonParams::remember_shift`).
    #[serde(default = "default_remember_shift")]
    pub remember_shift: bool,
    /// Try each exact or shifted Newton step corrected by geodesic acceleration (a second-order term
    /// from one extra gradient evaluation) before the plain line search (default true; false: the Newton
    /// path of versions before it; see `hinge_solver::newton::NewtonParams::geodesic_acceleration`).
    #[serde(default = "default_geodesic_acceleration")]
    pub geodesic_acceleration: bool,
    /// `shifted-exact` in a time step: when an iteration's diagonal shift exceeds this many times the
    /// largest inertia term m/Δt² of a vertex, it takes the definite Hessian instead, until `definite_hold`
    /// full steps (non-negative; `inf`: never; default 1000; see
    /// `hinge_solver::newton::NewtonParams::definite_shift_ratio`).
    #[serde(default = "default_definite_shift_ratio")]
    pub definite_shift_ratio: f64,
    /// Full steps taken with the definite Hessian once an iteration switched to it (`project-on-demand`,
    /// or a shift above `definite_shift_ratio`) before the exact Hessian is tried again (at least 1;
    /// default 1; see `hinge_solver::newton::NewtonParams::definite_hold`).
    #[serde(default = "default_definite_hold")]
    pub definite_hold: usize,
    /// `--static` with the StVK membrane: reach the equilibrium through softer membranes first
    /// (`hinge_solver::statics`; default true; false: one Newton solve at the scene's material).
    #[serde(default = "default_membrane_continuation")]
    pub membrane_continuation: bool,
    /// `implicit-euler` (default: Newton on the incremental potential) or `symplectic-euler` (explicit,
    /// `substeps` per frame; stable only below `2/ω_max`, see `hinge_solver::explicit` and `hinge
    /// stability`). The Newton keys apply to implicit Euler and to `--static`.
    #[serde(default = "default_integrator")]
    pub integrator: String,
    /// Explicit substeps per frame (`symplectic-euler` only; default 1).
    #[serde(default = "default_substeps")]
    pub substeps: usize,
}

fn default_integrator() -> String {
    "implicit-euler".into()
}

fn default_substeps() -> usize {
    1
}

fn default_extrapolate() -> bool {
    true
}

fn default_geodesic_acceleration() -> bool {
    true
}

fn default_definite_shift_ratio() -> f64 {
    hinge_solver::newton::DEFINITE_SHIFT_RATIO
}

fn default_definite_hold() -> usize {
    hinge_solver::newton::DEFINITE_HOLD
}

fn default_membrane_continuation() -> bool {
    true
}

fn default_remember_shift() -> bool {
    true
}

fn default_globalization() -> String {
    "shifted-exact".into()
}

fn default_halvings() -> u32 {
    5
}

fn default_ordering() -> String {
    "auto".into()
}

fn default_backend() -> String {
    "faer-llt".into()
}
fn default_iterations() -> usize {
    100
}
fn default_tolerance() -> f64 {
    1e-6
}

impl Default for SolverSpec {
    fn default() -> Self {
        Self {
            backend: default_backend(),
            ordering: default_ordering(),
            max_iterations: default_iterations(),
            gradient_tolerance: default_tolerance(),
            max_substep_halvings: default_halvings(),
            globalization: default_globalization(),
            relative_gradient_tolerance: None,
            relative_step_tolerance: None,
            extrapolate: default_extrapolate(),
            remember_shift: default_remember_shift(),
            geodesic_acceleration: default_geodesic_acceleration(),
            definite_shift_ratio: default_definite_shift_ratio(),
            definite_hold: default_definite_hold(),
            membrane_continuation: default_membrane_continuation(),
            integrator: default_integrator(),
            substeps: default_substeps(),
        }
    }
}

/// Parses scene TOML; `origin` names the text in errors.
///
/// # Errors
/// One line naming the key path of an unknown key or invalid value.
pub fn parse(text: &str, origin: &str) -> Result<Scene, String> {
    let mut scene = parse_unchecked(text, origin)?;
    scene
        .read_param_files(None)
        .map_err(|m| format!("{origin}: {m}"))?;
    scene.validate().map_err(|m| format!("{origin}: {m}"))?;
    Ok(scene)
}

/// Deserializes a scene without the value checks (parameter files are still paths).
fn parse_unchecked(text: &str, origin: &str) -> Result<Scene, String> {
    let de = toml::Deserializer::parse(text)
        .map_err(|e| format!("{origin}: {}", one_line(&e.to_string())))?;
    let scene: Scene = serde_path_to_error::deserialize(de).map_err(|e| {
        let path = e.path().to_string();
        format!(
            "{origin}: {}: {}",
            if path == "." {
                "(top level)".into()
            } else {
                path
            },
            one_line(&e.inner().to_string())
        )
    })?;
    Ok(scene)
}

/// A parser's message on one line, with number literals longer than 24 characters (the TOML parser
/// quotes `1e308` as its 309 digits) in their short form ([`Num`]).
fn one_line(s: &str) -> String {
    let joined = s.split_whitespace().collect::<Vec<_>>().join(" ");
    let mut out = String::with_capacity(joined.len());
    let mut run = String::new();
    let flush = |run: &mut String, out: &mut String| {
        match run.parse::<f64>() {
            Ok(v) if run.len() > 24 => out.push_str(&Num(v).to_string()),
            _ => out.push_str(run),
        }
        run.clear();
    };
    for c in joined.chars() {
        if c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '+' | '-') {
            run.push(c);
        } else {
            flush(&mut run, &mut out);
            out.push(c);
        }
    }
    flush(&mut run, &mut out);
    out
}

/// A built-in scene by name, or a TOML file by path.
///
/// # Errors
/// Unknown scene, unreadable file, or a parse/validation error.
pub fn load(name_or_path: &str) -> Result<(Scene, Option<PathBuf>), String> {
    if let Some((_, text)) = BUILT_IN.iter().find(|(n, _)| *n == name_or_path) {
        return parse(text, name_or_path).map(|s| (s, None));
    }
    if name_or_path.ends_with(".toml") || Path::new(name_or_path).exists() {
        let text =
            std::fs::read_to_string(name_or_path).map_err(|e| format!("{name_or_path}: {e}"))?;
        let dir = Path::new(name_or_path).parent().map(Path::to_path_buf);
        let mut scene = parse_unchecked(&text, name_or_path)?;
        scene.base.clone_from(&dir);
        scene
            .read_param_files(dir.as_deref())
            .map_err(|m| format!("{name_or_path}: {m}"))?;
        scene
            .validate()
            .map_err(|m| format!("{name_or_path}: {m}"))?;
        return Ok((scene, dir));
    }
    Err(format!(
        "unknown scene `{name_or_path}` (built-in: {}; or give a .toml file)",
        BUILT_IN.map(|b| b.0).join(", ")
    ))
}

fn positive(name: &str, v: f64) -> Result<(), String> {
    if v > 0.0 && v.is_finite() {
        Ok(())
    } else {
        Err(format!(
            "{name}: must be positive and finite, got {}",
            Num(v)
        ))
    }
}

impl Scene {
    /// The custom ψ of `[bending]` (`energy = "custom"`), with `k` defaulting to `material_k` when the
    /// expression reads it and `[bending.params]` does not set it.
    ///
    /// # Errors
    /// The expression's error (with its column), or a parameter file that was not resolved.
    pub fn custom_psi(&self, material_k: f64) -> Result<CustomPsi, String> {
        let expr = self.bending.psi.as_deref().unwrap_or_default();
        let mut values: Vec<(String, ParamValue)> = Vec::new();
        for (name, v) in &self.bending.params {
            let value = match v {
                ParamSpec::Number(x) => ParamValue::Scalar(*x),
                ParamSpec::List(xs) => ParamValue::PerHinge(xs.clone()),
                ParamSpec::File(f) => {
                    return Err(format!("bending.params.{name}: file `{f}` was not read"));
                }
            };
            values.push((name.clone(), value));
        }
        if !self.bending.params.contains_key("k") {
            let mut names: Vec<String> = values.iter().map(|v| v.0.clone()).collect();
            names.push("k".into());
            if hinge_core::psi::runtime::reads_parameter(expr, &names, "k") {
                values.push(("k".into(), ParamValue::Scalar(material_k)));
            }
        }
        CustomPsi::new(expr, values)
    }

    /// Reads the per-hinge parameter files of `[bending.params]` (paths relative to `dir`).
    fn read_param_files(&mut self, dir: Option<&Path>) -> Result<(), String> {
        for (name, v) in &mut self.bending.params {
            if let ParamSpec::File(f) = v {
                let path = dir.map_or_else(|| PathBuf::from(&*f), |d| d.join(&*f));
                let text = std::fs::read_to_string(&path)
                    .map_err(|e| format!("bending.params.{name}: {}: {e}", path.display()))?;
                let mut xs = Vec::new();
                for (k, tok) in text.split_whitespace().enumerate() {
                    xs.push(tok.parse::<f64>().map_err(|_| {
                        format!(
                            "bending.params.{name}: {}: value {} `{tok}` is not a number",
                            path.display(),
                            k + 1
                        )
                    })?);
                }
                *v = ParamSpec::List(xs);
            }
        }
        Ok(())
    }

    /// Value checks serde cannot express, each naming the key path.
    fn validate(&self) -> Result<(), String> {
        positive("dt", self.dt)?;
        if !(self.drag >= 0.0 && self.drag.is_finite()) {
            return Err(format!(
                "drag: must be non-negative, got {}",
                Num(self.drag)
            ));
        }
        positive("material.young", self.material.young)?;
        positive("material.thickness", self.material.thickness)?;
        positive("material.density", self.material.density)?;
        let (lower, upper) = POISSON_BOUNDS;
        if !(self.material.poisson > lower && self.material.poisson < upper) {
            return Err(format!(
                "material.poisson: must lie in ({lower}, {upper}), got {}",
                Num(self.material.poisson)
            ));
        }
        if !(self.bending.damping >= 0.0 && self.bending.damping.is_finite()) {
            return Err(format!(
                "bending.damping: must be non-negative, got {}",
                Num(self.bending.damping)
            ));
        }
        if !["implicit-euler", "symplectic-euler"].contains(&self.solver.integrator.as_str()) {
            return Err(format!(
                "solver.integrator: unknown `{}` (implicit-euler, symplectic-euler)",
                self.solver.integrator
            ));
        }
        if !(1..=10_000_000).contains(&self.solver.substeps) {
            return Err(format!(
                "solver.substeps: must be from 1 to 10 000 000, got {}",
                self.solver.substeps
            ));
        }
        // A budget beyond a million Newton iterations per step is a run that never ends, not a limit.
        if !(1..=hinge_solver::newton::MAX_ITERATIONS_CEILING).contains(&self.solver.max_iterations)
        {
            return Err(format!(
                "solver.max_iterations: must be from 1 to {}, got {}",
                hinge_solver::newton::MAX_ITERATIONS_CEILING_TEXT,
                self.solver.max_iterations
            ));
        }
        if self.solver.max_substep_halvings > 30 {
            return Err(format!(
                "solver.max_substep_halvings: must be from 0 to 30, got {}",
                self.solver.max_substep_halvings
            ));
        }
        if let Some(p) = &self.bending.plasticity {
            for (key, v) in [("yield_angle", p.yield_angle), ("hardening", p.hardening)] {
                if !(v >= 0.0 && v.is_finite()) {
                    return Err(format!(
                        "bending.plasticity.{key}: must be non-negative and finite, got {}",
                        Num(v)
                    ));
                }
            }
        }
        if let Some(a) = &self.bending.anisotropy {
            hinge_core::anisotropy::Anisotropy::new(a.warp, a.weft)
                .map_err(|e| format!("bending.anisotropy: {e}"))?;
            match &a.direction {
                DirectionSpec::Vector(d) => {
                    if !(d.iter().all(|c| c.is_finite()) && d.iter().any(|&c| c != 0.0)) {
                        return Err(format!(
                            "bending.anisotropy.direction: {d:?} is zero or not finite"
                        ));
                    }
                }
                DirectionSpec::Name(n) if n == "uv" => {
                    if self.mesh.shape.is_some() {
                        return Err("bending.anisotropy.direction: \"uv\" needs texture coordinates, and a generated icosphere has none".into());
                    }
                }
                DirectionSpec::Name(n) => {
                    return Err(format!(
                        "bending.anisotropy.direction: unknown `{n}` (a vector [x, y, z] or \"uv\")"
                    ));
                }
            }
        }
        if hinge_solver::newton::Globalization::from_name(&self.solver.globalization).is_none() {
            return Err(format!(
                "solver.globalization: unknown `{}` (project-on-demand, shifted-exact)",
                self.solver.globalization
            ));
        }
        if self.solver.definite_hold == 0 {
            return Err("solver.definite_hold: must be at least 1, got 0".into());
        }
        if !(self.solver.definite_shift_ratio >= 0.0) {
            return Err(format!(
                "solver.definite_shift_ratio: must be non-negative (inf: never), got {}",
                Num(self.solver.definite_shift_ratio)
            ));
        }
        // 0 leaves convergence to the relative and step tests; a negative or NaN tolerance is a typo.
        if !(self.solver.gradient_tolerance >= 0.0 && self.solver.gradient_tolerance.is_finite()) {
            return Err(format!(
                "solver.gradient_tolerance: must be non-negative and finite, got {}",
                Num(self.solver.gradient_tolerance)
            ));
        }
        for (key, v) in [
            (
                "solver.relative_gradient_tolerance",
                self.solver.relative_gradient_tolerance,
            ),
            (
                "solver.relative_step_tolerance",
                self.solver.relative_step_tolerance,
            ),
        ] {
            if let Some(v) = v {
                positive(key, v)?;
            }
        }
        if !["eq11", "plate"].contains(&self.bending.calibration.as_str()) {
            return Err(format!(
                "bending.calibration: unknown `{}` (eq11, plate)",
                self.bending.calibration
            ));
        }
        self.bending.hessian_mode()?;
        if let Some(levels) = &self.mesh.resolutions {
            if levels.is_empty() || levels.iter().any(|c| c[0] == 0 || c[1] == 0) {
                return Err(
                    "mesh.resolutions: give at least one [cells_x, cells_y], each at least 1"
                        .into(),
                );
            }
            if self.mesh.obj.is_some() {
                return Err("mesh.resolutions: applies to grids only".into());
            }
        }
        if let Some(c) = self.pins.clamp_columns {
            if self.mesh.obj.is_some() {
                return Err("pins.clamp_columns: applies to grids only".into());
            }
            if c == 0 {
                return Err("pins.clamp_columns: must be at least 1".into());
            }
        }
        if self.bending.energy != "custom" && self.bending.energy.parse::<BuiltinBending>().is_err()
        {
            return Err(unknown_bending_energy(&self.bending.energy));
        }
        match (self.bending.energy == "custom", &self.bending.psi) {
            (true, None) => {
                return Err("bending.psi: `energy = \"custom\"` needs `psi = \"EXPR\"`".into());
            }
            (false, Some(_)) => {
                return Err(format!(
                    "bending.psi: only with `energy = \"custom\"` (energy is `{}`)",
                    self.bending.energy
                ));
            }
            (true, Some(_)) => {
                // Parsed here so a bad expression fails before any work, with its column.
                self.custom_psi(1.0)
                    .map_err(|e| format!("bending.psi: {e}"))?;
            }
            (false, None) => {}
        }
        if self.bending.energy != "custom" && !self.bending.params.is_empty() {
            return Err("bending.params: only with `energy = \"custom\"`".into());
        }
        match (&self.mesh.cells, &self.mesh.obj, &self.mesh.shape) {
            (Some(c), None, None) if c[0] >= 1 && c[1] >= 1 => {}
            (Some(_), None, None) => {
                return Err("mesh.cells: need at least one cell each way".into());
            }
            (None, Some(_), None) => {}
            (None, None, Some(shape)) => {
                if shape != "icosphere" {
                    return Err(format!("mesh.shape: unknown `{shape}` (icosphere)"));
                }
                match self.mesh.subdivisions {
                    Some(0..=7) => {}
                    Some(k) => return Err(format!("mesh.subdivisions: {k} is above 7")),
                    None => return Err("mesh: an icosphere needs `subdivisions`".into()),
                }
                positive(
                    "mesh.radius",
                    self.mesh
                        .radius
                        .ok_or("mesh: an icosphere needs `radius`")?,
                )?;
            }
            _ => {
                return Err(
                    "mesh: give exactly one of `cells` (a grid), `obj` (a file) or `shape`".into(),
                );
            }
        }
        for (axis, &v) in ["x", "y"].iter().zip(&self.mesh.size) {
            positive(&format!("mesh.size ({axis})"), v)?;
        }
        if let Some(c) = self.mesh.origin.iter().position(|v| !v.is_finite()) {
            return Err(format!(
                "mesh.origin: coordinate {c} must be finite, got {}",
                Num(self.mesh.origin[c])
            ));
        }
        if !["forward", "backward", "alternating"].contains(&self.mesh.diagonal.as_str()) {
            return Err(format!(
                "mesh.diagonal: unknown `{}` (forward, backward, alternating)",
                self.mesh.diagonal
            ));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            match (o.kind.as_str(), o.center, o.radius, o.point, o.normal) {
                ("sphere", Some(_), Some(r), None, None) => {
                    positive(&format!("obstacles[{i}].radius"), r)?
                }
                ("plane", None, None, Some(_), Some(_)) => {}
                ("sphere", ..) => {
                    return Err(format!(
                        "obstacles[{i}]: a sphere takes `center` and `radius`"
                    ));
                }
                ("plane", ..) => {
                    return Err(format!(
                        "obstacles[{i}]: a plane takes `point` and `normal`"
                    ));
                }
                (k, ..) => {
                    return Err(format!(
                        "obstacles[{i}].kind: unknown `{k}` (sphere, plane)"
                    ));
                }
            }
        }
        self.obstacle_motions()?;
        self.material.model()?;
        if ![
            "faer-llt",
            "faer-lu",
            "pcg-jacobi",
            "chebyshev-jacobi",
            "dense",
        ]
        .contains(&self.solver.backend.as_str())
        {
            return Err(format!("solver.backend: unknown `{}`", self.solver.backend));
        }
        if hinge_solver::ordering::FillOrdering::from_name(&self.solver.ordering).is_none() {
            return Err(format!(
                "solver.ordering: unknown `{}` (auto, amd, nested-dissection)",
                self.solver.ordering
            ));
        }
        if self.frames == 0 {
            return Err("frames: must be at least 1".into());
        }
        if self.frames > crate::limits::MAX_FRAMES {
            return Err(format!(
                "frames: {} is more than the limit of {} frames per run",
                self.frames,
                crate::limits::MAX_FRAMES
            ));
        }
        Ok(())
    }

    /// Scales a grid's cells so that it has `cells_x` cells along x (y scaled alike), or, for scenes that
    /// list `mesh.resolutions`, selects entry `cells_x` (1-based).
    pub fn set_resolution(&mut self, cells_x: usize) -> Result<(), String> {
        if self.mesh.shape.is_some() {
            if cells_x > 7 {
                return Err(format!(
                    "--resolution {cells_x}: an icosphere has subdivision levels 0 to 7"
                ));
            }
            self.mesh.subdivisions = Some(cells_x);
            return Ok(());
        }
        let Some(c) = self.mesh.cells.as_mut() else {
            return Err("--resolution applies to grid scenes only".into());
        };
        if let Some(levels) = &self.mesh.resolutions {
            let counts: Vec<String> = levels
                .iter()
                .enumerate()
                .map(|(i, l)| format!("{} = {} vertices", i + 1, (l[0] + 1) * (l[1] + 1)))
                .collect();
            return match cells_x.checked_sub(1).and_then(|i| levels.get(i)) {
                Some(level) => {
                    *c = *level;
                    Ok(())
                }
                None => Err(format!(
                    "--resolution {cells_x}: scene `{}` has resolutions {}",
                    self.name,
                    counts.join(", ")
                )),
            };
        }
        if cells_x < 2 {
            return Err("--resolution must be at least 2".into());
        }
        let y = ((c[1] as f64) * cells_x as f64 / c[0] as f64)
            .round()
            .max(1.0) as usize;
        *c = [cells_x, y];
        Ok(())
    }

    /// The pinned vertices of `rest` (explicit, `x_at_most`, `clamp_columns`), sorted, without repeats.
    ///
    /// # Errors
    /// `clamp_columns` wider than the grid.
    pub fn pinned(&self, rest: &TriMesh) -> Result<Vec<usize>, String> {
        let mut pinned = self.fixed_pins(rest)?;
        for g in self.pin_groups(rest)? {
            pinned.extend(g.vertices);
        }
        pinned.sort_unstable();
        pinned.dedup();
        Ok(pinned)
    }

    /// The motion of each obstacle (`[[obstacles]] motion`; `None` for a fixed one), checked.
    ///
    /// # Errors
    /// A one-line message naming the obstacle and key.
    pub fn obstacle_motions(&self) -> Result<Vec<Option<Motion>>, String> {
        self.obstacles
            .iter()
            .enumerate()
            .map(|(i, o)| {
                o.motion
                    .as_ref()
                    .map(|m| motion(&format!("obstacles[{i}]"), m))
                    .transpose()
            })
            .collect()
    }

    /// The pin groups of `[[pins.groups]]`, checked: a vertex follows at most one group, and none of them
    /// is one `[pins]` holds fixed (either way one of the two would be ignored without a word).
    ///
    /// # Errors
    /// A one-line message naming the group and key, or the first vertex two groups (or a group and the
    /// fixed pins) share.
    pub fn pin_groups(&self, rest: &TriMesh) -> Result<Vec<PinGroup>, String> {
        let groups = self
            .pins
            .groups
            .iter()
            .enumerate()
            .map(|(i, g)| pin_group(i, g, rest))
            .collect::<Result<Vec<_>, _>>()?;
        if groups.is_empty() {
            return Ok(groups);
        }
        let fixed = self.fixed_pins(rest)?;
        // Owner of each vertex: usize::MAX for none, groups.len() for the fixed pins.
        let mut owner = vec![usize::MAX; rest.n_vertices()];
        for &v in &fixed {
            if let Some(o) = owner.get_mut(v) {
                *o = groups.len();
            }
        }
        for (i, g) in groups.iter().enumerate() {
            for &v in &g.vertices {
                match owner[v] {
                    usize::MAX => owner[v] = i,
                    o if o == groups.len() => {
                        return Err(format!(
                            "pins.groups[{i}]: vertex {v} is also held fixed by [pins] (a vertex follows one motion or none)"
                        ));
                    }
                    o => {
                        return Err(format!(
                            "pins.groups[{i}]: vertex {v} is also in pins.groups[{o}] (a vertex follows one motion or none)"
                        ));
                    }
                }
            }
        }
        Ok(groups)
    }

    /// The pins without a motion (`[pins]` `vertices`, `x_at_most`, `clamp_columns`).
    ///
    /// # Errors
    /// A one-line message naming the key.
    pub fn fixed_pins(&self, rest: &TriMesh) -> Result<Vec<usize>, String> {
        let mut pinned = self.pins.vertices.clone();
        if let Some(xmax) = self.pins.x_at_most {
            pinned.extend((0..rest.n_vertices()).filter(|&v| rest.positions()[v].x <= xmax));
        }
        if let (Some(cols), Some(cells)) = (self.pins.clamp_columns, self.mesh.cells) {
            if cols > cells[0] {
                return Err(format!(
                    "pins.clamp_columns: {cols} columns, but the grid has {} vertex columns",
                    cells[0] + 1
                ));
            }
            pinned.extend((0..rest.n_vertices()).filter(|v| v % (cells[0] + 1) < cols));
        }
        pinned.sort_unstable();
        pinned.dedup();
        Ok(pinned)
    }

    /// The texture coordinates of the rest mesh's triangles (one entry per triangle of `rest`): a mesh
    /// file's own (read again from the file), a grid's planar ones (u along x, v along y, both from 0 to 1
    /// across the grid).
    ///
    /// # Errors
    /// A one-line message: an unreadable file, a file whose mesh is not `rest`, a mesh without texture
    /// coordinates (naming the first triangle without them).
    pub fn rest_uvs(&self, rest: &TriMesh) -> Result<Vec<Option<TriangleUv>>, String> {
        if let Some(obj) = &self.mesh.obj {
            let path = self.base.as_deref().map_or(obj.clone(), |b| b.join(obj));
            let file = hinge_core::meshio::read_mesh(&path).map_err(|e| e.to_string())?;
            if file.mesh.triangles() != rest.triangles() {
                return Err(format!(
                    "{}: the file's triangles are not the rest mesh's",
                    path.display()
                ));
            }
            if file.uvs.is_empty() {
                return Err(format!(
                    "bending.anisotropy.direction = \"uv\": {} has no texture coordinates",
                    path.display()
                ));
            }
            return Ok(file.uvs);
        }
        if self.mesh.shape.is_some() {
            return Err(
                "bending.anisotropy.direction = \"uv\": a generated icosphere has no texture coordinates"
                    .into(),
            );
        }
        let o = self.mesh.origin;
        let [sx, sy] = self.mesh.size;
        let x = rest.positions();
        Ok(rest
            .triangles()
            .iter()
            .map(|t| Some(t.map(|v| [(x[v].x - o[0]) / sx, (x[v].y - o[1]) / sy])))
            .collect())
    }

    /// The rest mesh.
    ///
    /// # Errors
    /// A one-line message (unreadable or invalid mesh file, invalid grid, a mesh too large for the memory
    /// available: [`crate::limits::memory`] at [`crate::limits::RUN_BYTES_PER_VERTEX`]).
    pub fn rest_mesh(&self, base: Option<&Path>) -> Result<TriMesh, String> {
        self.rest_mesh_numbered(base).map(|(mesh, _)| mesh)
    }

    /// The rest mesh and, for a mesh file, how the file counts its vertices and faces (errors about the
    /// mesh are then told in the file's numbering).
    ///
    /// # Errors
    /// As [`Scene::rest_mesh`].
    pub fn rest_mesh_numbered(
        &self,
        base: Option<&Path>,
    ) -> Result<(TriMesh, Option<hinge_core::meshio::FileNumbering>), String> {
        if let Some(obj) = &self.mesh.obj {
            let path = base.map_or(obj.clone(), |b| b.join(obj));
            let (mesh, numbering) = crate::files::read_numbered(&path)?;
            // Read, the mesh costs little; a run on it far more.
            crate::limits::memory(
                mesh.n_vertices() as u128,
                crate::limits::RUN_BYTES_PER_VERTEX,
                &format!("mesh.obj: {}", path.display()),
            )?;
            return Ok((mesh, Some(numbering)));
        }
        let o = Vector3::from(self.mesh.origin);
        if self.mesh.shape.is_some() {
            let level = self.mesh.subdivisions.unwrap_or(0);
            crate::limits::memory(
                hinge_core::shapes::icosphere_counts(level).0,
                crate::limits::RUN_BYTES_PER_VERTEX,
                &format!("mesh: icosphere level {level}"),
            )?;
            let m = hinge_core::shapes::icosphere(
                self.mesh.subdivisions.unwrap_or(0),
                self.mesh.radius.unwrap_or(1.0),
            )
            .map_err(|e| format!("mesh: {e}"))?;
            let moved = m.positions().iter().map(|p| p + o).collect();
            return m
                .with_positions(moved)
                .map(|m| (m, None))
                .map_err(|e| format!("mesh: {e}"));
        }
        let c = self.mesh.cells.unwrap_or([1, 1]);
        crate::limits::memory(
            hinge_core::grid::counts(c[0], c[1]).0,
            crate::limits::RUN_BYTES_PER_VERTEX,
            &format!("mesh: a {}×{} grid", c[0], c[1]),
        )?;
        let diagonal = match self.mesh.diagonal.as_str() {
            "forward" => Diagonal::Forward,
            "backward" => Diagonal::Backward,
            _ => Diagonal::Alternating,
        };
        let g = grid(c[0], c[1], self.mesh.size[0], self.mesh.size[1], diagonal)
            .map_err(|e| format!("mesh: {e}"))?;
        let moved = g.positions().iter().map(|p| p + o).collect();
        g.with_positions(moved)
            .map(|m| (m, None))
            .map_err(|e| format!("mesh: {e}"))
    }
}

/// Checks pin group `i`.
fn pin_group(i: usize, g: &PinGroupSpec, rest: &TriMesh) -> Result<PinGroup, String> {
    let n = rest.n_vertices();
    let key = |k: &str| format!("pins.groups[{i}].{k}");
    let mut vertices = g.vertices.clone();
    if let Some(&v) = vertices.iter().find(|&&v| v >= n) {
        return Err(format!(
            "{}: vertex {v} does not exist (the mesh has {n} vertices, numbered from 0)",
            key("vertices")
        ));
    }
    if let Some(x) = g.x_at_least {
        vertices.extend((0..n).filter(|&v| rest.positions()[v].x >= x));
    }
    if let Some(x) = g.x_at_most {
        vertices.extend((0..n).filter(|&v| rest.positions()[v].x <= x));
    }
    vertices.sort_unstable();
    vertices.dedup();
    if vertices.is_empty() {
        return Err(format!("pins.groups[{i}]: selects no vertex"));
    }
    if let Some(r) = g.release
        && !(r >= 0.0 && r.is_finite())
    {
        return Err(format!(
            "{}: must be non-negative, got {}",
            key("release"),
            Num(r)
        ));
    }
    let motion = motion(&format!("pins.groups[{i}]"), &g.motion)?;
    Ok(PinGroup {
        vertices,
        motion,
        release: g.release,
    })
}

/// Checks a [`MotionSpec`] whose keys are under `prefix` (`pins.groups[0]`, `obstacles[1]`).
fn motion(prefix: &str, m: &MotionSpec) -> Result<Motion, String> {
    let key = |k: &str| format!("{prefix}.{k}");
    let finite3 = |v: &[f64; 3]| v.iter().all(|c| c.is_finite());
    let need = |name: &str, v: Option<[f64; 3]>| -> Result<Vector3<f64>, String> {
        match v {
            Some(a) if finite3(&a) => Ok(Vector3::from(a)),
            Some(a) => Err(format!(
                "{}: {a:?} is not finite",
                key(&format!("motion.{name}"))
            )),
            None => Err(format!(
                "{}: a `{}` motion needs it",
                key(&format!("motion.{name}")),
                m.kind
            )),
        }
    };
    Ok(match m.kind.as_str() {
        "fixed" => Motion::Fixed,
        "translation" => Motion::Translation(need("velocity", m.velocity)?),
        "rotation" => {
            let axis = need("axis", m.axis)?;
            if !(axis.norm() > 0.0) {
                return Err(format!("{}: is zero", key("motion.axis")));
            }
            let w = m.angular_velocity.ok_or_else(|| {
                format!(
                    "{}: a `rotation` motion needs it",
                    key("motion.angular_velocity")
                )
            })?;
            if !w.is_finite() {
                return Err(format!(
                    "{}: {w} is not finite",
                    key("motion.angular_velocity")
                ));
            }
            Motion::Rotation {
                center: need("center", m.center)?,
                axis: axis.normalize(),
                angular_velocity: w,
            }
        }
        "keyframes" => {
            let (Some(times), Some(offsets)) = (&m.times, &m.offsets) else {
                return Err(format!(
                    "{}: a `keyframes` motion needs `times` and `offsets`",
                    key("motion")
                ));
            };
            if times.len() != offsets.len() || times.is_empty() {
                return Err(format!(
                    "{}: {} times for {} offsets (one offset per time, at least one)",
                    key("motion"),
                    times.len(),
                    offsets.len()
                ));
            }
            if !(times[0] > 0.0 && times.iter().all(|t| t.is_finite()))
                || times.windows(2).any(|w| !(w[1] > w[0]))
                || !offsets.iter().all(finite3)
            {
                return Err(format!(
                    "{}: times must be finite, positive and increasing, offsets finite",
                    key("motion")
                ));
            }
            Motion::Keyframes(
                times
                    .iter()
                    .zip(offsets)
                    .map(|(t, o)| (*t, Vector3::from(*o)))
                    .collect(),
            )
        }
        other => {
            return Err(format!(
                "{}: unknown `{other}` (fixed, translation, rotation, keyframes)",
                key("motion.kind")
            ));
        }
    })
}
