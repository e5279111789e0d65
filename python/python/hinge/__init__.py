"""hinge: hinge-based bending energies on triangle meshes, with exact forces and sparse Hessians.

    >>> import numpy as np, hinge
    >>> V = np.array([[0, 1, 0], [0, 0, 0], [1, 0, 0], [1, 1, 0]], float)
    >>> F = np.array([[0, 1, 2], [3, 2, 1]])
    >>> model = hinge.BendingModel(V, F, energy="tan-bending", k=1.0)
    >>> E, g, H = model.evaluate(V)

Meshes are numpy arrays: ``V`` float (n, 3), ``F`` integer (m, 3), any integer dtype, C or Fortran order
(converted once, without a copy when already float64 / int64 C-contiguous). Gradients are 3n vectors
(x0, y0, z0, x1, ...), Hessians ``scipy.sparse.csr_matrix`` of shape (3n, 3n), full and symmetric.

Energies: the built-ins (``hinge.energies()``) or any ``psi="EXPR"`` in the expression language of the Rust
derive (the same text), with its parameters as keyword arguments: numbers, or arrays with one value per
hinge in hinge order (``model.hinges`` / ``hinge.hinges(V, F)``). Every error raises ``ValueError``.
"""

import os as _os
import warnings as _warnings

import numpy as _np
import scipy.sparse as _sp

from . import _hinge

DEFINITE_SHIFT_RATIO = _hinge.DEFINITE_SHIFT_RATIO
"""The default ``definite_shift_ratio`` of :class:`ImplicitEuler` (Rust ``hinge_solver::newton::DEFINITE_SHIFT_RATIO``)."""
DEFINITE_HOLD = _hinge.DEFINITE_HOLD
"""The default ``definite_hold`` of :func:`solve_static` and :class:`ImplicitEuler` (Rust
``hinge_solver::newton::DEFINITE_HOLD``)."""

__all__ = ["DEFINITE_SHIFT_RATIO", "DEFINITE_HOLD", "BendingModel", "System", "MeshWarning", "ImplicitEuler", "solve_static", "run_scene", "hinges", "energies",
           "adjoint_gradient", "fit", "fit_scene", "read_mesh", "write_mesh", "threads"]


def _vertices(V):
    V = _np.asarray(V)
    if V.dtype.kind not in "fiu":
        raise ValueError(f"V must be a float array, got dtype {V.dtype}")
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    return _np.ascontiguousarray(V, dtype=_np.float64)


def _faces(F):
    F = _np.asarray(F)
    if F.dtype.kind not in "iu":
        raise ValueError(f"F must be an integer array, got dtype {F.dtype}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"F must have shape (m, 3), got {F.shape}")
    if F.dtype.kind == "u" and F.size and F.max() > _np.iinfo(_np.int64).max:
        raise ValueError("F has a vertex index beyond int64")
    return _np.ascontiguousarray(F, dtype=_np.int64)


def _param(name, value):
    if _np.isscalar(value):
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ValueError(f"parameter `{name}` must be a number or an array of numbers") from None
    a = _np.asarray(value)
    if a.dtype.kind not in "fiu" or a.ndim != 1:
        raise ValueError(f"parameter `{name}` must be a number or a 1-D array with one value per hinge")
    return _np.ascontiguousarray(a, dtype=_np.float64)


def _number(name, value):
    """A real number (int, float, numpy scalar or 0-d array; not a bool) as float, else ValueError; whether
    it is finite and in range is the Rust side's to say, naming the parameter."""
    if isinstance(value, _np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bool, _np.bool_)) or not isinstance(value, (int, float, _np.integer, _np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(f"{name} is too large for a float: {value!r}") from None


def _count(name, value, minimum=0):
    """A whole number in [minimum, 2⁶³) (int, numpy integer, or a float with an integral value) as int, else
    ValueError."""
    if isinstance(value, _np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (float, _np.floating)) and _np.isfinite(value) and float(value).is_integer():
        value = int(value)
    if isinstance(value, (bool, _np.bool_)) or not isinstance(value, (int, _np.integer)):
        raise ValueError(f"{name} must be a whole number, got {value!r}")
    if not minimum <= int(value) < 2**63:
        raise ValueError(f"{name} must be at least {minimum} (and below 2**63), got {value!r}")
    return int(value)


def _vector3(name, value):
    """Three real numbers as a list of floats, else ValueError."""
    try:
        v = list(value)
    except TypeError:
        raise ValueError(f"{name} must have 3 components (numbers), got {value!r}") from None
    if len(v) != 3:
        raise ValueError(f"{name} must have 3 components, got {len(v)}")
    return [_number(f"{name}[{i}]", c) for i, c in enumerate(v)]


def _names(name, value):
    """One name or an iterable of names as a list of strings, else ValueError."""
    if isinstance(value, str):
        return [value]
    try:
        names = list(value)
    except TypeError:
        raise ValueError(f"{name} must be a string or a list of strings, got {value!r}") from None
    return [_string(f"{name}[{i}]", v) for i, v in enumerate(names)]


def _string(name, value):
    if not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {value!r}")
    return value


def hinges(V, F):
    """The (h, 4) int64 array of hinge stencils (x0, x1, x2, x3) of a mesh, in hinge order."""
    return _hinge.hinges(_vertices(V), _faces(F))


def read_mesh(path):
    """``(V, F)`` of a mesh file — OBJ, OFF, PLY or STL, by extension — as float64 (n, 3) and int64 (m, 3)
    arrays. Polygons are fan-triangulated, STL corners welded where their positions are equal (vertices in
    order of first appearance); a malformed file or one no hinge energy takes (a non-manifold edge, opposite
    orientations) raises ``ValueError`` naming the face and line as the file counts them."""
    return _hinge.read_mesh(str(path))


def write_mesh(path, V, F):
    """Writes ``(V, F)`` in the format of the extension: OBJ, OFF, binary PLY or binary STL (single
    precision)."""
    _hinge.write_mesh(str(path), _vertices(V), _faces(F))


def energies():
    """The built-in energies: a list of (name, ψ text, {parameter: default})."""
    return _hinge.energies()


class threads:
    """``with hinge.threads(n): ...``: the package's calls made from this thread inside the block
    (evaluations, solves, steps, scenes, fits) run on a pool of ``n`` worker threads instead of rayon's
    global pool (all cores). Contexts nest (the innermost wins) and apply to the thread that opened them
    only; a ``BendingModel`` built with its own ``threads=`` keeps its pool. Results are bitwise the same
    for any thread count."""

    def __init__(self, n):
        if isinstance(n, bool) or not isinstance(n, int):
            raise ValueError(f"threads must be an int, got {n!r}")
        if n < 1:
            raise ValueError("threads must be at least 1")
        self._n = n

    def __enter__(self):
        _hinge._push_threads(self._n)
        return self

    def __exit__(self, *exc):
        _hinge._pop_threads()
        return False


class BendingModel:
    """A hinge bending energy bound to a rest mesh.

    ``BendingModel(V, F, energy="discrete-shells", method="refactored", threads=None, **params)`` for a
    built-in energy, or ``BendingModel(V, F, psi="k * a * (theta - theta_bar).powi(2)", k=1.0)`` for any ψ
    of the language. ``method`` is ``"refactored"`` (the triangle-refactored Hessian), ``"per_hinge"`` or
    ``"autodiff"``; ``threads`` sets the size of the model's own thread pool (default: all cores).
    ``hessian`` chooses the Hessian: ``"exact"``, ``"gauss-newton"`` (``max(ψ″, 0) ∇θ∇θᵀ``) or
    ``"projected"`` (each hinge's 12×12 Hessian with its negative eigenvalues clamped to zero, for
    projected-Newton solvers); the energy and gradient are exact in every mode.
    """

    def __init__(self, V, F, energy=None, psi=None, method="refactored", threads=None, hessian="exact",
                 **params):
        if energy is None and psi is None:
            energy = "discrete-shells"
        if threads is not None:
            threads = _count("threads", threads, minimum=1)
        p = {k: _param(k, v) for k, v in params.items()}
        energy = None if energy is None else _string("energy", energy)
        psi = None if psi is None else _string("psi", psi)
        self._m = _hinge.BendingModel(_vertices(V), _faces(F), energy, psi, _string("method", method), threads,
                                      p, _string("hessian", hessian))
        indptr, indices = self._m.pattern()
        self._indptr, self._indices = indptr, indices
        self.n_vertices = self._m.n_vertices
        self.n_hinges = self._m.n_hinges
        _warn_stiff_rest(self._m.stiff_rest())

    @property
    def hinges(self):
        """(h, 4) int64 array of hinge stencils, hinge order (the order of per-hinge parameters)."""
        return self._m.hinges

    @property
    def energy(self):
        """The energy's name (``"custom"`` for a ψ string)."""
        return self._m.energy

    @property
    def hessian(self):
        """The Hessian the model assembles: ``"exact"``, ``"gauss-newton"`` or ``"projected"``."""
        return self._m.hessian

    def _x(self, X):
        X = _np.asarray(X)
        if X.dtype.kind not in "fiu":
            raise ValueError(f"positions must be a float array, got dtype {X.dtype}")
        if X.shape != (self.n_vertices, 3):
            raise ValueError(f"positions must have shape ({self.n_vertices}, 3), got {X.shape}")
        return _np.ascontiguousarray(X, dtype=_np.float64)

    def pattern(self):
        """``(indptr, indices)`` of the Hessian's full CSR structure (fixed for the model)."""
        return self._indptr, self._indices

    @property
    def nnz(self):
        """Stored values of the CSR Hessian."""
        return self._m.nnz

    def evaluate(self, X, hessian=True):
        """``(E, g, H)`` at positions ``X`` (n, 3); ``(E, g)`` with ``hessian=False``."""
        E, g, data = self._m.evaluate_raw(self._x(X), True, _flag("hessian", hessian))
        if not hessian:
            return E, g
        n = 3 * self.n_vertices
        H = _sp.csr_matrix((data, self._indices, self._indptr), shape=(n, n))
        return E, g, H

    def energy_value(self, X):
        """E alone (no gradient, no Hessian: the cheapest evaluation)."""
        E, _, _ = self._m.evaluate_raw(self._x(X), False, False)
        return E

    def evaluate_into(self, X, g_out, data_out=None):
        """Evaluates into ``g_out`` (float64, 3n) and ``data_out`` (float64, ``nnz``, in ``pattern()``
        order; None skips the Hessian). Returns E."""
        if g_out is None:
            raise ValueError("g_out must be a writable contiguous 1-D float64 array, got None")
        for name, a in (("g_out", g_out), ("data_out", data_out)):
            if a is not None and not (isinstance(a, _np.ndarray) and a.dtype == _np.float64
                                      and a.ndim == 1 and a.flags.c_contiguous and a.flags.writeable):
                raise ValueError(f"{name} must be a writable contiguous 1-D float64 array")
        return self._m.evaluate_into(self._x(X), g_out, data_out)

    def set_step(self, X_prev, dt):
        """Starts a time step (for energies that read ``theta_prev`` and ``dt``)."""
        self._m.set_step(self._x(X_prev), _number("dt", dt))

    def set_parameter(self, name, value):
        """Changes a parameter after set-up (re-hoisted)."""
        self._m.set_parameter(name, _param(name, value))

    def rest_stiffening(self):
        """How much stiffer each hinge is at its rest angle than flat: ``psi''(theta_bar) / psi''(0)`` (hinge
        order; tan bending's ``1 / cos(theta_bar / 2)**4``, over 1e6 for a crease folded beyond 3.09 rad,
        which conditions Newton's systems badly). NaN where ``psi''(0)`` is not positive."""
        return self._m.rest_stiffening()

    def set_rest_angles(self, theta_bar):
        """Sets every hinge's rest angle (hinge order)."""
        try:
            a = _np.ascontiguousarray(_np.asarray(theta_bar), dtype=_np.float64)
        except (TypeError, ValueError):
            raise ValueError("theta_bar must be a 1-D array of numbers with one value per hinge") from None
        if a.ndim != 1:
            raise ValueError("theta_bar must be a 1-D array with one value per hinge")
        self._m.set_rest_angles(a)


class MeshWarning(UserWarning):
    """A mesh hinge can use but that may not be what was meant: vertices in no triangle, vertices split
    along a seam, or rest creases folded so far that the bending energy is a million times stiffer there than
    flat (tan bending near θ̄ = ±π). ``run_scene`` also raises it for a mesh that starts inside an obstacle,
    and for vertices that a penalty obstacle let through its surface during the run, or that a step carried
    through a penalty sphere and out again between two frames (once per obstacle)."""


def _warn_stiff_rest(note):
    if note:
        _warnings.warn(f"{note} (vertices from 0); Newton may need many iterations and substeps", MeshWarning,
                       stacklevel=3)


class System:
    """Energies composed on one rest mesh, with pinned vertices::

        s = hinge.System(V, F)
        s.add_bending(energy="tan-bending", k=1e-3)     # or psi="…", with its parameters
        s.add_membrane(young=2e5, poisson=0.3, thickness=5e-4)
        s.add_gravity(density=0.1)
        s.add_sphere(center=(0, 0, 0), radius=0.25, stiffness=2e3, margin=5e-3)
        s.pin([0, 1, 2])
        E, g, H = s.evaluate(X)

    Terms: ``add_bending``, ``add_membrane``, ``add_springs``, ``add_gravity``, ``add_drag``, ``add_sphere``,
    ``add_plane``. Each is checked when added (bad parameters raise ``ValueError`` naming it).
    """

    def __init__(self, V, F):
        self._s = _hinge.System(_vertices(V), _faces(F))
        self.n_vertices = self._s.n_vertices
        unused = self._s.unreferenced_vertices
        if unused:
            _warnings.warn(
                f"{len(unused)} of the vertices are in no triangle (the first: vertex {unused[0]}); they have "
                "no mass and no stiffness, and the solvers hold them where they are",
                MeshWarning,
                stacklevel=2,
            )
        seam = self._s.coincident_vertices
        if seam:
            v, first = seam[0]
            _warnings.warn(
                f"{len(seam)} vertices lie exactly on another vertex (the first: vertex {v} on vertex {first}); "
                "nothing couples them, so the surface is cut there (split along UV seams?): merge them if "
                "they should be one",
                MeshWarning,
                stacklevel=2,
            )

    @property
    def unreferenced_vertices(self):
        """The vertices in no triangle, ascending (held where they are by the solvers)."""
        return list(self._s.unreferenced_vertices)

    @property
    def coincident_vertices(self):
        """``(vertex, first)`` pairs: triangle vertices at exactly the position of the lower-numbered
        ``first`` (a mesh split along seams is cut there)."""
        return [tuple(p) for p in self._s.coincident_vertices]

    def add_bending(self, energy=None, psi=None, hessian="exact", method="refactored", **params):
        """A hinge bending term (a built-in ``energy`` or a ``psi`` string, with its parameters);
        ``hessian`` as in ``BendingModel``: ``"exact"``, ``"gauss-newton"`` or ``"projected"`` (the scene
        key ``bending.hessian``; with the last two no Newton direction is exact: in ``solve_static`` and
        ``ImplicitEuler`` the step tests never end a solve and geodesic acceleration is off);
        ``method`` as in ``BendingModel``: ``"refactored"`` (the default), ``"per_hinge"`` or
        ``"autodiff"``."""
        if energy is None and psi is None:
            energy = "discrete-shells"
        energy = None if energy is None else _string("energy", energy)
        psi = None if psi is None else _string("psi", psi)
        _warn_stiff_rest(self._s.add_bending(energy, psi, {k: _param(k, v) for k, v in params.items()},
                                             _string("hessian", hessian), _string("method", method)))
        return self

    def add_membrane(self, young, poisson, thickness, kind="stvk"):
        """A membrane: ``kind`` "stvk" (St. Venant-Kirchhoff), "corotational" (k/2 A |F - R|^2 with
        k = young * thickness / (1 + poisson), exact Hessian) or "neo-hookean" (compressible neo-Hookean
        with St. Venant-Kirchhoff's Lame constants, infinite energy at zero area, exact Hessian). Parameters
        (``parameters``, ``adjoint_gradient``): ``membrane.young``, ``membrane.poisson`` and
        ``membrane.thickness`` (``neo-hookean-membrane.…`` for "neo-hookean"), or
        ``corotational-membrane.stiffness``."""
        self._s.add_membrane(_number("young", young), _number("poisson", poisson),
                             _number("thickness", thickness), _string("kind", kind))
        return self

    def add_springs(self, k, compressive=True):
        self._s.add_springs(_number("k", k), _flag("compressive", compressive))
        return self

    def add_gravity(self, density, g=(0.0, 0.0, -9.81)):
        self._s.add_gravity(_number("density", density), _vector3("g", g))
        return self

    def add_drag(self, density, rate):
        self._s.add_drag(_number("density", density), _number("rate", rate))
        return self

    def add_sphere(self, center, radius, stiffness, margin=0.0, smoothing=0.0, barrier=False):
        """Penalty contact with a sphere; ``smoothing`` > 0 (a length) makes the penalty C² over the first
        ``smoothing`` of penetration into the margin (0: the quadratic penalty). ``barrier=True``: a
        logarithmic barrier reaching ``margin`` (> 0) from the obstacle instead, infinite on it; the solvers
        then never let a vertex reach the obstacle, and a vertex on or inside it raises ``ValueError``."""
        self._s.add_sphere(_vector3("center", center), _number("radius", radius), _number("stiffness", stiffness),
                           _number("margin", margin), _number("smoothing", smoothing), _flag("barrier", barrier))
        return self

    def add_plane(self, point, normal, stiffness, margin=0.0, smoothing=0.0, barrier=False):
        """Penalty contact with a plane (vertices pushed to the side ``normal`` points to); ``smoothing`` and
        ``barrier`` as for ``add_sphere``."""
        self._s.add_plane(_vector3("point", point), _vector3("normal", normal), _number("stiffness", stiffness),
                          _number("margin", margin), _number("smoothing", smoothing), _flag("barrier", barrier))
        return self

    def pin(self, vertices):
        v = _np.asarray(vertices)
        if v.dtype.kind not in "iu" or v.ndim != 1:
            raise ValueError("pin takes a 1-D integer array of vertex indices")
        self._s.pin([int(i) for i in v])
        return self

    @property
    def pinned(self):
        return self._s.pinned

    @property
    def terms(self):
        """The terms' names, in order; the k-th term of a name an earlier term has is ``NAME#k``, as in
        parameter names (two ``psi=`` terms: ``"custom"`` and ``"custom#2"``)."""
        return self._s.term_names()

    def _x(self, X):
        X = _np.asarray(X)
        if X.dtype.kind not in "fiu" or X.shape != (self.n_vertices, 3):
            raise ValueError(f"positions must be a float array of shape ({self.n_vertices}, 3), got "
                             f"{X.dtype} {X.shape}")
        return _np.ascontiguousarray(X, dtype=_np.float64)

    def parameters(self):
        """The differentiable parameters as ``[(name, length)]``, named ``TERM.NAME`` (``"tan-bending.k"``,
        ``"tan-bending.theta_bar"`` (rest angles), ``"membrane.young"``, ``"gravity.g"``, ``"custom#2.k"`` for
        the second ``psi=`` term ...; ``TERM`` as in ``terms``)."""
        return self._s.parameters()

    def parameter(self, name):
        """The values of parameter ``name`` as an array."""
        return _np.asarray(self._s.parameter(_string("name", name)))

    def set_parameter(self, name, values):
        """Sets parameter ``name`` (a number, or as many values as it has)."""
        try:
            v = _np.atleast_1d(_np.asarray(values, dtype=_np.float64))
        except (TypeError, ValueError):
            raise ValueError(f"parameter {name!r}: values must be a number or a 1-D array of numbers") from None
        if v.ndim != 1:
            raise ValueError(f"parameter {name!r}: values must be a number or a 1-D array")
        self._s.set_parameter(_string("name", name), [float(x) for x in v])
        return self

    def evaluate(self, X, hessian=True, definite=False):
        """``(E, g, H)`` of the whole system (``(E, g)`` with ``hessian=False``). ``definite=True`` gives the
        positive semi-definite Hessian Newton's ``project-on-demand`` uses instead of the exact one (per
        term: Gauss–Newton hinges, membrane stress clamped to its positive part in the geometric stiffness,
        compressive spring and obstacle-curvature terms dropped); energy and gradient stay exact."""
        E, g, data = self._s.evaluate_raw(self._x(X), _flag("hessian", hessian), _flag("definite", definite))
        if not hessian:
            return E, g
        indptr, indices = self._s.pattern()
        n = 3 * self.n_vertices
        return E, g, _sp.csr_matrix((data, indices, indptr), shape=(n, n))


def solve_static(system, X0, max_iterations=500, gradient_tolerance=1e-8, globalization="shifted-exact",
                 extrapolate=True, membrane_continuation=True, relative_gradient_tolerance=0.0,
                 relative_step_tolerance=0.0, remember_shift=True, geodesic_acceleration=True,
                 definite_hold=_hinge.DEFINITE_HOLD):
    """The static equilibrium from ``X0`` (pinned vertices held at their ``X0`` positions), by Newton on the
    system's energy, at most ``max_iterations`` Newton iterations (1 to 1 000 000, as in scene files).
    Returns ``(X, stats)`` with ``stats`` a dict (``newton_iterations``,
    ``line_search_steps``, ``factorizations``, ``definite_iterations``, ``accelerated_iterations``,
    ``final_gradient_norm``,
    ``gradient_norms``, ``largest_residual``: ``(vertex, force)``, the free vertex whose force ‖∂E/∂x_v‖ is
    largest at ``X`` and that force, or None when nothing is free; a solve that fails raises ``ValueError``
    naming that vertex where it stopped). A solve stops when the gradient norm is at most ``gradient_tolerance`` (absolute, in
    the system's force units; 0 leaves convergence to the other stopping tests, as in scene files).
    ``globalization`` is ``"shifted-exact"`` (the exact Hessian, a diagonal shift when it
    does not factor) or ``"project-on-demand"`` (each energy's definite Hessian after a failed factorization);
    ``extrapolate`` tries longer steps after a full shifted or definite one (as the scene keys
    ``solver.globalization`` and ``solver.extrapolate``). With ``membrane_continuation`` (as the scene key
    ``solver.membrane_continuation``), a thin shell's membrane (StVK, or the co-rotational one through its
    stiffness) is first softened to about the inverse of its membrane/bending stiffness ratio and raised
    back in stages, each a Newton solve from the last (all counted in the stats): thin stiff strips then
    take tens of iterations instead of hundreds.

    Unit-free stopping tests, off (0) by default, as the scene keys of the same names: a solve also stops
    when the gradient norm is at most ``relative_gradient_tolerance`` times its norm at the start, or after
    an exact Newton step that moved no vertex farther than ``relative_step_tolerance`` times the rest mesh's
    mean edge length. ``remember_shift`` (the scene key ``solver.remember_shift``) starts each diagonal-shift
    ladder near the last shift that factored, in this solve or (for a stepper) an earlier step; ``False``
    makes every solve independent of the ones before it. ``geodesic_acceleration`` (the scene key
    ``solver.geodesic_acceleration``) first tries each exact or shifted Newton step corrected by a
    second-order term (one extra gradient evaluation and triangular solve); ``False`` gives plain Newton
    steps. ``definite_hold`` (the scene key ``solver.definite_hold``, at least 1, default ``DEFINITE_HOLD``
    = 1): once an iteration took each energy's definite Hessian (``"project-on-demand"`` after a failed
    factorization, or the stepper's ``definite_shift_ratio``), that many full steps are taken with it
    before the exact Hessian is tried again."""
    return _hinge.solve_static(system._s, system._x(X0), _count("max_iterations", max_iterations),
                               _number("gradient_tolerance", gradient_tolerance),
                               _globalization(globalization), _flag("extrapolate", extrapolate),
                               _flag("membrane_continuation", membrane_continuation),
                               _tolerance("relative_gradient_tolerance", relative_gradient_tolerance),
                               _tolerance("relative_step_tolerance", relative_step_tolerance),
                               _flag("remember_shift", remember_shift),
                               _flag("geodesic_acceleration", geodesic_acceleration),
                               _count("definite_hold", definite_hold, 1))


def _globalization(name):
    if name not in ("shifted-exact", "project-on-demand"):
        raise ValueError(f'globalization must be "shifted-exact" or "project-on-demand", got {name!r}')
    return name


def _tolerance(name, value):
    return _number(f"{name} (0: off)", value)


def _flag(name, value):
    if not isinstance(value, bool):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return value


def adjoint_gradient(system, X, dloss_dx, parameters):
    """``dL/dp`` at an equilibrium ``X`` of ``system`` (pins eliminated) for a loss ``L(X)`` whose gradient with
    respect to the positions is ``dloss_dx`` (shape (n, 3)): ``-lambda^T dg/dp`` with ``H lambda = dL/dx``, ``H``
    the exact Hessian at ``X``. Returns a dict name -> array, one entry per parameter value. Raises
    ``ValueError`` when ``X`` is not a strict minimum (indefinite Hessian) or a name is unknown."""
    return _hinge.adjoint_gradient(system._s, system._x(X), system._x(dloss_dx), _names("parameters", parameters))


def fit(system, X0, target, parameters, max_iterations=50, gradient_tolerance=1e-9, membrane_continuation=True):
    """Fits system parameters (``TERM.NAME``, see ``System.parameters``) so that the static equilibrium
    matches ``target`` (shape (n, 3); loss: summed squared vertex distances), by L-BFGS with adjoint gradients;
    parameters whose values are all positive stay positive (fitted on a log scale), and one an energy bounds
    (a membrane's ``poisson``, in (-1, 0.5)) stays inside its interval (fitted on a logistic scale). The first
    equilibrium, from ``X0``, goes through the membrane continuation of ``solve_static`` when
    ``membrane_continuation`` is set; the fit's solves start from it. Returns ``(X, info)``: the fitted
    equilibrium and a dict with ``fitted`` (name -> value or array), ``loss``, ``iterations``, ``equilibria``,
    ``newton_iterations`` (all of them, the first equilibrium's included), ``stop`` and ``fields``: for every
    parameter with more than one value, ``{"entries", "without_effect", "determined"}`` — how many of its
    values move nothing, and how many independent combinations of the others the target determines (one
    static shape often determines fewer per-hinge values than there are; the fit then returns one of many
    fields that give the same equilibrium). The system keeps the fitted values. ``max_iterations`` (L-BFGS
    iterations) is 0 to 1 000 000; 0 evaluates the start only."""
    return _hinge.fit(system._s, system._x(X0), system._x(target), _names("parameters", parameters),
                      _count("max_iterations", max_iterations), _number("gradient_tolerance", gradient_tolerance),
                      _flag("membrane_continuation", membrane_continuation))


def fit_scene(scene, target, keys, max_iterations=50, smoothness=0.0):
    """``hinge fit`` from Python: the scene keys (``"material.young"``, ``"material.thickness"``,
    ``"material.poisson"``, ``"material.density"``, ``"bending.params.NAME"``, ``"bending.rest_angles"``) that
    make the scene's static
    equilibrium match ``target`` (a mesh file path, or an (n, 3) array). Returns ``(X, info)`` like ``fit``;
    keys that cannot be told apart from the target raise ``ValueError``. ``max_iterations`` is 0 to 1 000 000
    and ``smoothness`` (the regularizer's weight, as ``hinge fit --smoothness``) non-negative."""
    if not isinstance(target, str):
        try:
            target = _np.ascontiguousarray(_np.asarray(target, dtype=_np.float64))
        except (TypeError, ValueError):
            raise ValueError("target must be a mesh file path or an (n, 3) array of numbers") from None
    return _hinge.fit_scene(str(scene), target, _names("keys", keys), _count("max_iterations", max_iterations),
                            _number("smoothness", smoothness))


class ImplicitEuler:
    """Implicit Euler on a system: ``stepper = hinge.ImplicitEuler(system, X0, dt, density)``, then
    ``X, stats = stepper.step()`` per frame (a failing step is retried in substeps; a frame that cannot be
    taken raises ``ValueError``, naming the vertex with the largest residual force where its last attempt
    stopped, and leaves positions, velocities and time as they were). ``globalization``,
    ``extrapolate``, ``relative_gradient_tolerance``, ``relative_step_tolerance``, ``remember_shift`` and
    ``geodesic_acceleration`` as in
    ``solve_static`` (the relative gradient test is against the gradient at the step's start, the inertial
    prediction). ``definite_shift_ratio`` (the scene key ``solver.definite_shift_ratio``, >= 0, default
    ``DEFINITE_SHIFT_RATIO`` = 1000, the Rust default):
    with ``"shifted-exact"``, an iteration whose diagonal shift would exceed this many times the largest
    inertia term m/dt² of a vertex takes each energy's definite Hessian instead, until ``definite_hold`` full
    steps; ``float("inf")`` never does (the shift alone). ``definite_hold`` as in ``solve_static``."""

    def __init__(self, system, X0, dt, density, V0=None, max_iterations=50, gradient_tolerance=1e-8,
                 globalization="shifted-exact", extrapolate=True, relative_gradient_tolerance=0.0,
                 relative_step_tolerance=0.0, remember_shift=True, geodesic_acceleration=True,
                 definite_shift_ratio=_hinge.DEFINITE_SHIFT_RATIO, definite_hold=_hinge.DEFINITE_HOLD):
        V0 = None if V0 is None else system._x(V0)
        self._t = _hinge.ImplicitEuler(system._s, system._x(X0), _number("dt", dt), _number("density", density), V0,
                                       _count("max_iterations", max_iterations),
                                       _number("gradient_tolerance", gradient_tolerance),
                                       _globalization(globalization), _flag("extrapolate", extrapolate),
                                       _tolerance("relative_gradient_tolerance", relative_gradient_tolerance),
                                       _tolerance("relative_step_tolerance", relative_step_tolerance),
                                       _flag("remember_shift", remember_shift),
                                       _flag("geodesic_acceleration", geodesic_acceleration),
                                       _number("definite_shift_ratio", definite_shift_ratio),
                                       _count("definite_hold", definite_hold, 1))

    def step(self):
        return self._t.step()

    @property
    def x(self):
        return self._t.x

    @property
    def v(self):
        return self._t.v

    @property
    def time(self):
        return self._t.time


def run_scene(scene, frames=None, trace=False, checkpoint=None, resume=None, checkpoint_every=None):
    """Simulates a built-in scene (``"drape"``, ``"shell-drop"``, ``"beam1"`` …) or a TOML scene file as
    ``hinge run`` does. Returns ``(V, F, X, summary)``: the rest mesh, every frame's positions as a
    (frames, n, 3) array, and the run's counts (a dict; per frame in ``frame_newton_iterations``,
    ``frame_factorizations``, ``frame_substeps``). With ``trace=True``, ``summary["trace"]`` is a (k, 11)
    array with a row per accepted Newton iteration, as ``hinge run --trace`` prints them: frame (from 0),
    iteration (from 1 in each solve), F, ‖∇F‖, ‖Δx‖, α (the line search's step length), shift, definite
    (1 for a step with the definite Hessian of ``globalization = "project-on-demand"``, else 0),
    accelerated (1 for a step corrected by geodesic acceleration, else 0), and where the residual is: the
    vertex (a row of ``V``) whose free coordinates carry the largest force ‖∂F/∂x_v‖ at the new iterate,
    and that force (−1 and 0 when no coordinate is free); the flag columns add up to the summary's
    ``definite_iterations`` and ``accelerated_iterations``. A run that fails raises ``ValueError`` whose
    message names the vertex with the largest residual force where the solve stopped.

    ``checkpoint`` (a path): the run writes its state there when it ends, is interrupted or fails (then
    the last good frame's, which the ``ValueError`` names), as ``hinge run`` writes ``checkpoint.txt``.
    ``resume`` (a path): continue from such a file — ``X`` holds the frames after its frame, up to
    ``frames`` (the scene's by default), ``summary["resumed_after_frame"]`` is that frame (``None`` for a
    run from rest) and the trace counts frames from it. With the scene unchanged the frames are bitwise
    those of the run that did not stop; the scene may change (``dt``, contact, solver keys) as long as its
    mesh has the checkpoint's vertices. A checkpoint that does not fit raises ``ValueError``.
    ``checkpoint_every`` (a positive integer, with ``checkpoint``): also write it after every N-th frame, so
    that a process killed outright resumes from at most N frames back."""
    if frames is not None and (not isinstance(frames, int) or isinstance(frames, bool)):
        raise ValueError(f"frames must be an integer, got {frames!r}")
    if frames is not None:
        frames = _count("frames", frames)
    if not isinstance(trace, bool):
        raise ValueError(f"trace must be True or False, got {trace!r}")
    paths = []
    for name, p in (("checkpoint", checkpoint), ("resume", resume)):
        if p is not None and not isinstance(p, (str, _os.PathLike)):
            raise ValueError(f"{name} must be a path, got {p!r}")
        paths.append(None if p is None else _os.fspath(p))
    if checkpoint_every is not None:
        if checkpoint is None:
            raise ValueError("checkpoint_every needs checkpoint, the file to write")
        checkpoint_every = _count("checkpoint_every", checkpoint_every, minimum=1)
    return _hinge.run_scene(str(scene), frames, trace, *paths, checkpoint_every)
