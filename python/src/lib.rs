//! The `hinge` Python module's native part (`hinge._hinge`): bending models on numpy meshes, evaluated with
//! the GIL released. The pure-Python layer (`python/hinge/__init__.py`) converts dtypes and layouts (without
//! copying when they already fit) and builds the scipy matrix.
//!
//! Every error of the library becomes a `ValueError` with its message; nothing panics across the boundary
//! (no `unwrap` on user data here either).

mod system;

use hinge_cli::scene::CustomPsi;
use hinge_core::bending::{BendingModel, HessianMode, Method, Parallelism, Request};
use hinge_core::bending::{Evaluation, Scratch};
use hinge_core::export::CsrLayout;
use hinge_core::layout::Positions;
use hinge_core::nalgebra::Vector3;
use hinge_core::psi::runtime::{ParamValue, RuntimePsi};
use hinge_core::{TriMesh, topology};
use hinge_energies::bending::{BuiltinBending, ViscousDamping};
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1, PyReadonlyArray2, PyReadwriteArray1,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A built-in hinge energy: name, ψ in the derive's language (the text of its `#[psi(…)]`), the
/// parameters with their defaults.
type EnergyEntry = (&'static str, &'static str, &'static [(&'static str, f64)]);

/// The built-in hinge energies: the elastic ones of [`BuiltinBending`] (names and ψ text kept there), then
/// [`ViscousDamping`] (its `NAME` and `PSI_SOURCE`).
fn builtin_energies() -> impl Iterator<Item = EnergyEntry> {
    BuiltinBending::ALL
        .into_iter()
        .map(|b| -> EnergyEntry { (b.name(), b.psi_source(), &[("k", 1.0)]) })
        .chain([(
            ViscousDamping::NAME,
            ViscousDamping::PSI_SOURCE,
            &[("kd", 1.0)][..],
        )])
}

pub(crate) fn value_error(e: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A per-hinge method by its name (`refactored`, `per_hinge`, `autodiff`), or `ValueError`.
pub(crate) fn parse_method(method: &str) -> PyResult<Method> {
    Method::from_name(method).ok_or_else(|| {
        value_error(format!(
            "unknown method `{method}` ({})",
            Method::ALL.map(Method::name).join(", ")
        ))
    })
}

/// A hinge Hessian mode by its name (`exact`, `gauss-newton`, `projected`), or `ValueError`.
pub(crate) fn parse_hessian(hessian: &str) -> PyResult<HessianMode> {
    HessianMode::from_name(hessian).ok_or_else(|| {
        value_error(format!(
            "unknown hessian `{hessian}` ({})",
            HessianMode::ALL.map(HessianMode::name).join(", ")
        ))
    })
}

/// A bending term's name, ψ text and parameters.
pub(crate) type PsiSpec = (String, String, Vec<(String, ParamValue)>);

/// The (name, ψ text, parameters) of a bending term: a built-in `energy` with its defaults overridden, or a
/// `psi` string with the parameters given.
pub(crate) fn psi_spec(
    energy: Option<&str>,
    psi: Option<&str>,
    params: Option<&Bound<'_, PyDict>>,
) -> PyResult<PsiSpec> {
    let mut given: Vec<(String, ParamValue)> = Vec::new();
    if let Some(d) = params {
        for (k, v) in d.iter() {
            let name: String = k.extract()?;
            given.push((name.clone(), param_value(&name, &v)?));
        }
    }
    Ok(match (energy, psi) {
        (Some(_), Some(_)) => {
            return Err(value_error("give one of `energy` and `psi`, not both"));
        }
        (None, Some(expr)) => ("custom".to_string(), expr.to_string(), given),
        (e, None) => {
            let e = e.unwrap_or("discrete-shells");
            let Some((name, text, defaults)) = builtin_energies().find(|x| x.0 == e) else {
                let known: Vec<&str> = builtin_energies().map(|x| x.0).collect();
                return Err(value_error(format!(
                    "unknown energy `{e}` (known: {})",
                    known.join(", ")
                )));
            };
            let mut values: Vec<(String, ParamValue)> = defaults
                .iter()
                .map(|(k, v)| (k.to_string(), ParamValue::Scalar(*v)))
                .collect();
            for (k, v) in given {
                match values.iter_mut().find(|(n, _)| *n == k) {
                    Some(slot) => slot.1 = v,
                    None => {
                        let names: Vec<&str> = defaults.iter().map(|d| d.0).collect();
                        return Err(value_error(format!(
                            "energy `{name}` has no parameter `{k}` (it has: {})",
                            names.join(", ")
                        )));
                    }
                }
            }
            (name.to_string(), text.to_string(), values)
        }
    })
}

/// `(indptr, indices)` of a CSR matrix.
pub(crate) type CsrStructure<'py> = (Bound<'py, PyArray1<i64>>, Bound<'py, PyArray1<i64>>);

/// A model with the capacity its expression needs.
enum Inner {
    Small(BendingModel<RuntimePsi>),
    Large(BendingModel<RuntimePsi<32>>),
}

macro_rules! with_model {
    ($inner:expr, $m:ident => $body:expr) => {
        match $inner {
            Inner::Small($m) => $body,
            Inner::Large($m) => $body,
        }
    };
}

/// A hinge energy bound to a rest mesh.
#[pyclass(module = "hinge._hinge", name = "BendingModel")]
struct Model {
    inner: Inner,
    method: Method,
    pool: Option<rayon::ThreadPool>,
    csr: CsrLayout,
    n_vertices: usize,
    hinges: Vec<[usize; 4]>,
    energy: String,
    /// Evaluation buffers kept between calls (`evaluate_into` allocates nothing per call); a mutex because
    /// a Python object may be used from several threads.
    buffers: std::sync::Mutex<(Scratch, Evaluation)>,
}

pub(crate) fn mesh_from(
    v: &PyReadonlyArray2<'_, f64>,
    f: &PyReadonlyArray2<'_, i64>,
) -> PyResult<TriMesh> {
    let (vs, fs) = (v.shape(), f.shape());
    if vs.len() != 2 || vs[1] != 3 {
        return Err(value_error(format!("V must have shape (n, 3), got {vs:?}")));
    }
    if fs.len() != 2 || fs[1] != 3 {
        return Err(value_error(format!("F must have shape (m, 3), got {fs:?}")));
    }
    let pos = v.as_slice().map_err(value_error)?;
    let tri = f.as_slice().map_err(value_error)?;
    let mut tris = Vec::with_capacity(fs[0]);
    for (t, c) in tri.chunks_exact(3).enumerate() {
        let mut out = [0usize; 3];
        for k in 0..3 {
            out[k] = usize::try_from(c[k]).map_err(|_| {
                value_error(format!(
                    "face {t} has a negative vertex index {} (vertex indices count from 0)",
                    c[k]
                ))
            })?;
        }
        tris.push(out);
    }
    let x = pos.as_vectors().map_err(value_error)?.to_vec();
    TriMesh::new(x, tris).map_err(value_error)
}

fn param_value(name: &str, v: &Bound<'_, PyAny>) -> PyResult<ParamValue> {
    if let Ok(x) = v.extract::<f64>() {
        return Ok(ParamValue::Scalar(x));
    }
    match v.extract::<PyReadonlyArray1<'_, f64>>() {
        Ok(a) => Ok(ParamValue::PerHinge(a.as_array().to_vec())),
        Err(_) => Err(value_error(format!(
            "parameter `{name}` must be a number or a 1-D float64 array with one value per hinge"
        ))),
    }
}

impl Model {
    /// Runs `f` without the GIL on the model's own pool, or as [`detached`] does.
    fn install<R: Send>(&self, py: Python<'_>, f: impl FnOnce() -> R + Send) -> R {
        match &self.pool {
            Some(p) => py.detach(|| p.install(f)),
            None => detached(py, f),
        }
    }
}

thread_local! {
    /// The pools of the `hinge.threads(n)` contexts open on this thread, innermost last.
    static POOLS: std::cell::RefCell<Vec<std::sync::Arc<rayon::ThreadPool>>> =
        const { std::cell::RefCell::new(Vec::new()) };
}

/// A pool of `n` worker threads (1 ≤ n ≤ 1024), or `ValueError`.
fn thread_pool(n: usize) -> PyResult<rayon::ThreadPool> {
    if n == 0 {
        return Err(value_error("threads must be at least 1"));
    }
    if n > 1024 {
        return Err(value_error(format!("threads = {n}: at most 1024")));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .map_err(value_error)
}

/// Runs `f` without the GIL, on the pool of the innermost `hinge.threads` context open on this thread
/// (rayon's global pool outside any).
pub(crate) fn detached<R: Send>(py: Python<'_>, f: impl FnOnce() -> R + Send) -> R {
    let pool = POOLS.with(|p| p.borrow().last().cloned());
    py.detach(move || match pool {
        Some(p) => p.install(f),
        None => f(),
    })
}

/// How often [`interruptible`] lets Python look for Ctrl-C.
const SIGNAL_POLL: std::time::Duration = std::time::Duration::from_millis(50);

/// Runs `f(stop)` without the GIL (on the pool [`detached`] would use) on a worker thread, while this
/// thread lets Python check its signals every [`SIGNAL_POLL`]: when a check raises (Ctrl-C's
/// `KeyboardInterrupt`, or whatever a Python signal handler raises), `stop` is raised, which the solvers
/// read before each Newton iteration (and the explicit integrator before each substep), and `f` is waited
/// for. Returns `f`'s result and the exception, for the caller to raise once its state is consistent (a
/// solve that saw the flag has left its state untouched; one that finished first has committed it).
/// Long calls (static solves, time steps, whole scenes) use it: without it Ctrl-C waited for them to end.
pub(crate) fn interruptible<R: Send>(
    py: Python<'_>,
    f: impl FnOnce(&std::sync::Arc<std::sync::atomic::AtomicBool>) -> R + Send,
) -> (R, Option<PyErr>) {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::mpsc::{RecvTimeoutError, channel};
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let pool = POOLS.with(|p| p.borrow().last().cloned());
    py.detach(|| {
        std::thread::scope(|scope| {
            let (done, finished) = channel::<()>();
            let flag = &stop;
            let worker = scope.spawn(move || {
                let r = match pool {
                    Some(p) => p.install(|| f(flag)),
                    None => f(flag),
                };
                // The receiver outlives the worker: it is waited for below.
                let _ = done.send(());
                r
            });
            let mut signal = None;
            // Until the worker is done (or panicked: the join below passes the panic on).
            while let Err(RecvTimeoutError::Timeout) = finished.recv_timeout(SIGNAL_POLL) {
                if signal.is_none()
                    && let Err(e) = Python::attach(|py| py.check_signals())
                {
                    stop.store(true, Ordering::SeqCst);
                    signal = Some(e);
                }
            }
            match worker.join() {
                Ok(r) => (r, signal),
                Err(panic) => std::panic::resume_unwind(panic),
            }
        })
    })
}

/// Opens a `hinge.threads(n)` context on this thread: the calls of the package run on `n` threads until
/// the matching [`pop_threads`].
#[pyfunction]
#[pyo3(name = "_push_threads")]
fn push_threads(n: usize) -> PyResult<()> {
    let pool = std::sync::Arc::new(thread_pool(n)?);
    POOLS.with(|p| p.borrow_mut().push(pool));
    Ok(())
}

/// Closes the innermost `hinge.threads` context of this thread.
#[pyfunction]
#[pyo3(name = "_pop_threads")]
fn pop_threads() -> PyResult<()> {
    POOLS
        .with(|p| p.borrow_mut().pop())
        .map(|_| ())
        .ok_or_else(|| value_error("no hinge.threads context is open on this thread"))
}

/// The number of threads the package's calls from this thread run on now.
#[pyfunction]
#[pyo3(name = "_current_threads")]
fn current_threads(py: Python<'_>) -> usize {
    detached(py, rayon::current_num_threads)
}

#[pymethods]
impl Model {
    /// `BendingModel(V, F, energy=None, psi=None, method="refactored", threads=None, params={},
    /// hessian="exact")`.
    #[new]
    #[pyo3(signature = (v, f, energy=None, psi=None, method="refactored", threads=None, params=None, hessian="exact"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        v: PyReadonlyArray2<'_, f64>,
        f: PyReadonlyArray2<'_, i64>,
        energy: Option<&str>,
        psi: Option<&str>,
        method: &str,
        threads: Option<usize>,
        params: Option<&Bound<'_, PyDict>>,
        hessian: &str,
    ) -> PyResult<Self> {
        let method = parse_method(method)?;
        let mode = parse_hessian(hessian)?;
        let (label, text, values) = psi_spec(energy, psi, params)?;
        let pool = threads.map(thread_pool).transpose()?;
        let mesh = mesh_from(&v, &f)?;
        let inner = detached(py, || -> Result<Inner, String> {
            let e = |e: hinge_core::EvalError| e.to_string();
            Ok(match CustomPsi::new(&text, values)? {
                CustomPsi::Small(p) => Inner::Small(BendingModel::new(&mesh, p).map_err(e)?),
                CustomPsi::Large(p) => Inner::Large(BendingModel::new(&mesh, p).map_err(e)?),
            })
        });
        let mut inner = inner.map_err(value_error)?;
        with_model!(&mut inner, m => m.set_hessian_mode(mode)).map_err(value_error)?;
        let (csr, hinges, buffers) = with_model!(&inner, m => (
            CsrLayout::new(m.pattern()),
            m.topology().hinges().iter().map(|h| h.vertices).collect::<Vec<_>>(),
            (m.new_scratch(), m.new_output()),
        ));
        Ok(Self {
            inner,
            method,
            pool,
            csr,
            n_vertices: mesh.n_vertices(),
            hinges,
            energy: label,
            buffers: std::sync::Mutex::new(buffers),
        })
    }

    /// The stencil vertices `(x0, x1, x2, x3)` of every hinge, in hinge order (the order per-hinge parameter
    /// arrays follow): an (h, 4) int64 array.
    #[getter]
    fn hinges<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let rows: Vec<Vec<i64>> = self
            .hinges
            .iter()
            .map(|h| h.iter().map(|&v| v as i64).collect())
            .collect();
        PyArray2::from_vec2(py, &rows).map_err(value_error)
    }

    /// Number of vertices of the rest mesh.
    #[getter]
    fn n_vertices(&self) -> usize {
        self.n_vertices
    }

    /// Number of hinges (interior edges).
    #[getter]
    fn n_hinges(&self) -> usize {
        self.hinges.len()
    }

    /// The Hessian the model assembles: `exact`, `gauss-newton` or `projected`.
    #[getter]
    fn hessian(&self) -> &'static str {
        with_model!(&self.inner, m => m.hessian_mode().name())
    }

    /// The energy's name (`custom` for a ψ string).
    #[getter]
    fn energy(&self) -> &str {
        &self.energy
    }

    /// The full symmetric CSR structure of the Hessian: `(indptr, indices)` (int64), fixed for the model.
    fn pattern<'py>(&self, py: Python<'py>) -> CsrStructure<'py> {
        let p: Vec<i64> = self.csr.row_ptr().iter().map(|&x| x as i64).collect();
        let c: Vec<i64> = self.csr.col_idx().iter().map(|&x| x as i64).collect();
        (p.into_pyarray(py), c.into_pyarray(py))
    }

    /// Number of stored values of the full CSR Hessian.
    #[getter]
    fn nnz(&self) -> usize {
        self.csr.nnz()
    }

    /// `(E, g, data)` at positions `x` ((n, 3) float64, C order): `data` the CSR values in `pattern()` order
    /// (None without `hessian`), `g` of length 3n (None without `gradient`).
    #[pyo3(signature = (x, gradient=true, hessian=true))]
    #[allow(clippy::type_complexity)]
    fn evaluate_raw<'py>(
        &self,
        py: Python<'py>,
        x: PyReadonlyArray2<'py, f64>,
        gradient: bool,
        hessian: bool,
    ) -> PyResult<(
        f64,
        Option<Bound<'py, PyArray1<f64>>>,
        Option<Bound<'py, PyArray1<f64>>>,
    )> {
        let pos = self.positions(&x)?;
        let request = Request {
            value: true,
            gradient,
            hessian,
            definite: false,
        };
        let method = self.method;
        let nnz = self.csr.nnz();
        let result = self.install(py, || -> Result<(f64, Vec<f64>, Vec<f64>), String> {
            let (energy, g, h) = self.run(pos, request, method)?;
            let mut data = Vec::new();
            if hessian {
                data = vec![0.0; nnz];
                self.csr.scatter(&h, &mut data).map_err(|e| e.to_string())?;
            }
            Ok((energy, g, data))
        });
        let (energy, g, data) = result.map_err(value_error)?;
        Ok((
            energy,
            gradient.then(|| g.into_pyarray(py)),
            hessian.then(|| data.into_pyarray(py)),
        ))
    }

    /// Evaluates into caller arrays (no allocation of outputs): `g_out` float64 of length 3n, `data_out`
    /// float64 of length `nnz` (or None to skip the Hessian). Returns E.
    #[pyo3(signature = (x, g_out, data_out=None))]
    fn evaluate_into(
        &self,
        py: Python<'_>,
        x: PyReadonlyArray2<'_, f64>,
        mut g_out: PyReadwriteArray1<'_, f64>,
        data_out: Option<PyReadwriteArray1<'_, f64>>,
    ) -> PyResult<f64> {
        let pos = self.positions(&x)?;
        let g = g_out.as_slice_mut().map_err(value_error)?;
        if g.len() != 3 * self.n_vertices {
            return Err(value_error(format!(
                "g_out has {} entries, need 3n = {}",
                g.len(),
                3 * self.n_vertices
            )));
        }
        let mut data_out = data_out;
        let data = match data_out.as_mut() {
            Some(d) => {
                let s = d.as_slice_mut().map_err(value_error)?;
                if s.len() != self.csr.nnz() {
                    return Err(value_error(format!(
                        "data_out has {} entries, need nnz = {}",
                        s.len(),
                        self.csr.nnz()
                    )));
                }
                Some(s)
            }
            None => None,
        };
        let request = Request {
            value: true,
            gradient: true,
            hessian: data.is_some(),
            definite: false,
        };
        let method = self.method;
        let r = self.install(py, move || -> Result<f64, String> {
            let mut guard = self
                .buffers
                .lock()
                .map_err(|_| "evaluation buffers poisoned".to_string())?;
            let (scratch, out) = &mut *guard;
            with_model!(&self.inner, m => m
                .evaluate_into(pos, request, method, Parallelism::Rayon, scratch, out)
                .map_err(|e| e.to_string())?);
            g.copy_from_slice(&out.gradient);
            if let Some(d) = data {
                self.csr
                    .scatter(&out.hessian, d)
                    .map_err(|e| e.to_string())?;
            }
            Ok(out.energy)
        });
        r.map_err(value_error)
    }

    /// Starts a time step for energies that use `theta_prev` and `dt` (viscous damping): θ at the end of the
    /// previous step from `x_prev`, and the step `dt`.
    fn set_step(&mut self, x_prev: PyReadonlyArray2<'_, f64>, dt: f64) -> PyResult<()> {
        let pos = self.positions(&x_prev)?;
        with_model!(&mut self.inner, m => m.set_step(pos, dt)).map_err(value_error)
    }

    /// Sets a parameter after set-up (a number, or one value per hinge) and re-hoists.
    fn set_parameter(&mut self, name: &str, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let v = param_value(name, value)?;
        let mut err = None;
        let r = with_model!(&mut self.inner, m => m.update_psi(|p| {
            if let Err(e) = p.set_parameter(name, v.clone()) {
                err = Some(e);
            }
        }));
        if let Some(e) = err {
            return Err(value_error(e));
        }
        r.map_err(value_error)
    }

    /// Sets the rest angle θ̄ of every hinge (hinge order).
    fn set_rest_angles(&mut self, theta_bar: PyReadonlyArray1<'_, f64>) -> PyResult<()> {
        let t = theta_bar.as_array().to_vec();
        with_model!(&mut self.inner, m => m.set_rest_angles(&t)).map_err(value_error)
    }

    /// The set-up warning of rest hinges at least [`hinge_cli::run::STIFF_REST`] times stiffer than flat
    /// (vertices numbered from 0), if any.
    fn stiff_rest(&self) -> Option<String> {
        with_model!(&self.inner, m => hinge_cli::run::StiffRest::of(m)).map(|s| s.describe(None))
    }

    /// ψ″(θ̄) / ψ″(0) of every hinge (hinge order; NaN where ψ″(0) is not positive and finite, ∞ where
    /// ψ″(θ̄) is not finite).
    fn rest_stiffening<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let r = with_model!(&self.inner, m => m.rest_stiffening());
        r.into_iter()
            .map(|r| r.unwrap_or(f64::NAN))
            .collect::<Vec<_>>()
            .into_pyarray(py)
    }
}

impl Model {
    /// One evaluation in the kept buffers: energy, gradient (empty unless requested) and the Hessian values
    /// in the model's storage order (empty unless requested), copied out for the caller's new arrays.
    fn run(
        &self,
        pos: &[Vector3<f64>],
        request: Request,
        method: Method,
    ) -> Result<(f64, Vec<f64>, Vec<f64>), String> {
        let mut guard = self
            .buffers
            .lock()
            .map_err(|_| "evaluation buffers poisoned".to_string())?;
        let (scratch, out) = &mut *guard;
        with_model!(&self.inner, m => m
            .evaluate_into(pos, request, method, Parallelism::Rayon, scratch, out)
            .map_err(|e| e.to_string())?);
        let g = if request.gradient {
            out.gradient.clone()
        } else {
            Vec::new()
        };
        let h = if request.hessian {
            out.hessian.clone()
        } else {
            Vec::new()
        };
        Ok((out.energy, g, h))
    }

    fn positions<'a>(&self, x: &'a PyReadonlyArray2<'_, f64>) -> PyResult<&'a [Vector3<f64>]> {
        let s = x.shape();
        if s.len() != 2 || s[1] != 3 || s[0] != self.n_vertices {
            return Err(value_error(format!(
                "positions must have shape ({}, 3), got {s:?}",
                self.n_vertices
            )));
        }
        let flat = x.as_slice().map_err(value_error)?;
        flat.as_vectors().map_err(value_error)
    }
}

/// The hinges of a mesh before any model is built: an (h, 4) int64 array of stencil vertices, hinge order.
#[pyfunction]
fn hinges<'py>(
    py: Python<'py>,
    v: PyReadonlyArray2<'py, f64>,
    f: PyReadonlyArray2<'py, i64>,
) -> PyResult<Bound<'py, PyArray2<i64>>> {
    let mesh = mesh_from(&v, &f)?;
    let h = topology::hinges(&mesh).map_err(value_error)?;
    let rows: Vec<Vec<i64>> = h
        .iter()
        .map(|h| h.vertices.iter().map(|&v| v as i64).collect())
        .collect();
    PyArray2::from_vec2(py, &rows).map_err(value_error)
}

/// `(V, F)` of a mesh file (OBJ, OFF, PLY or STL, by extension): polygons fanned, STL corners welded, and
/// the hinge topology checked, every error in the file's numbering.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn read_mesh<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<i64>>)> {
    let file = hinge_core::meshio::read_mesh(&path).map_err(value_error)?;
    file.topology().map_err(value_error)?;
    let v: Vec<Vec<f64>> = file
        .mesh
        .positions()
        .iter()
        .map(|p| vec![p.x, p.y, p.z])
        .collect();
    let f: Vec<Vec<i64>> = file
        .mesh
        .triangles()
        .iter()
        .map(|t| t.iter().map(|&v| v as i64).collect())
        .collect();
    Ok((
        PyArray2::from_vec2(py, &v).map_err(value_error)?,
        PyArray2::from_vec2(py, &f).map_err(value_error)?,
    ))
}

/// Writes `(V, F)` in the format of `path`'s extension (OBJ, OFF, binary PLY, binary STL).
#[pyfunction]
fn write_mesh(
    path: std::path::PathBuf,
    v: PyReadonlyArray2<'_, f64>,
    f: PyReadonlyArray2<'_, i64>,
) -> PyResult<()> {
    let mesh = mesh_from(&v, &f)?;
    hinge_core::meshio::write_mesh(&path, mesh.positions(), mesh.triangles()).map_err(value_error)
}

/// The built-in energies: a list of (name, ψ text, {parameter: default}).
#[pyfunction]
fn energies(py: Python<'_>) -> PyResult<Vec<(String, String, Py<PyDict>)>> {
    builtin_energies()
        .map(|(n, t, p)| {
            let d = PyDict::new(py);
            for (k, v) in p.iter() {
                d.set_item(k, v)?;
            }
            Ok((n.to_string(), t.to_string(), d.unbind()))
        })
        .collect()
}

#[pymodule]
fn _hinge(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add(
        "DEFINITE_SHIFT_RATIO",
        hinge_solver::newton::DEFINITE_SHIFT_RATIO,
    )?;
    m.add("DEFINITE_HOLD", hinge_solver::newton::DEFINITE_HOLD)?;
    m.add_class::<Model>()?;
    m.add_class::<system::PySystem>()?;
    m.add_class::<system::PyStepper>()?;
    m.add_function(wrap_pyfunction!(system::solve_static, m)?)?;
    m.add_function(wrap_pyfunction!(system::run_scene, m)?)?;
    m.add_function(wrap_pyfunction!(system::adjoint_gradient, m)?)?;
    m.add_function(wrap_pyfunction!(system::fit, m)?)?;
    m.add_function(wrap_pyfunction!(system::fit_scene, m)?)?;
    m.add_function(wrap_pyfunction!(hinges, m)?)?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(write_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(energies, m)?)?;
    m.add_function(wrap_pyfunction!(push_threads, m)?)?;
    m.add_function(wrap_pyfunction!(pop_threads, m)?)?;
    m.add_function(wrap_pyfunction!(current_threads, m)?)?;
    Ok(())
}
