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

import numpy as _np
import scipy.sparse as _sp

from . import _hinge

__all__ = ["BendingModel", "hinges", "energies"]


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


def hinges(V, F):
    """The (h, 4) int64 array of hinge stencils (x0, x1, x2, x3) of a mesh, in hinge order."""
    return _hinge.hinges(_vertices(V), _faces(F))


def energies():
    """The built-in energies: a list of (name, ψ text, {parameter: default})."""
    return _hinge.energies()


class BendingModel:
    """A hinge bending energy bound to a rest mesh.

    ``BendingModel(V, F, energy="discrete-shells", method="refactored", threads=None, **params)`` for a
    built-in energy, or ``BendingModel(V, F, psi="k * a * (theta - theta_bar).powi(2)", k=1.0)`` for any ψ
    of the language. ``method`` is ``"refactored"`` (the triangle-refactored Hessian), ``"per_hinge"`` or
    ``"autodiff"``; ``threads`` sets the size of the model's own thread pool (default: all cores).
    """

    def __init__(self, V, F, energy=None, psi=None, method="refactored", threads=None, **params):
        if energy is None and psi is None:
            energy = "discrete-shells"
        if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool)):
            raise ValueError(f"threads must be an integer, got {threads!r}")
        p = {k: _param(k, v) for k, v in params.items()}
        self._m = _hinge.BendingModel(_vertices(V), _faces(F), energy, psi, method, threads, p)
        indptr, indices = self._m.pattern()
        self._indptr, self._indices = indptr, indices
        self.n_vertices = self._m.n_vertices
        self.n_hinges = self._m.n_hinges

    @property
    def hinges(self):
        """(h, 4) int64 array of hinge stencils, hinge order (the order of per-hinge parameters)."""
        return self._m.hinges

    @property
    def energy(self):
        """The energy's name (``"custom"`` for a ψ string)."""
        return self._m.energy

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
        E, g, data = self._m.evaluate_raw(self._x(X), True, bool(hessian))
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
        for name, a in (("g_out", g_out), ("data_out", data_out)):
            if a is not None and not (isinstance(a, _np.ndarray) and a.dtype == _np.float64
                                      and a.ndim == 1 and a.flags.c_contiguous and a.flags.writeable):
                raise ValueError(f"{name} must be a writable contiguous 1-D float64 array")
        return self._m.evaluate_into(self._x(X), g_out, data_out)

    def set_step(self, X_prev, dt):
        """Starts a time step (for energies that read ``theta_prev`` and ``dt``)."""
        self._m.set_step(self._x(X_prev), float(dt))

    def set_parameter(self, name, value):
        """Changes a parameter after set-up (re-hoisted)."""
        self._m.set_parameter(name, _param(name, value))

    def set_rest_angles(self, theta_bar):
        """Sets every hinge's rest angle (hinge order)."""
        a = _np.ascontiguousarray(_np.asarray(theta_bar), dtype=_np.float64)
        if a.ndim != 1:
            raise ValueError("theta_bar must be a 1-D array with one value per hinge")
        self._m.set_rest_angles(a)
