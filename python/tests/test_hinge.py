"""The Python face of hinge: derivatives against finite differences, methods and ψ strings against each
other, numpy dtypes and layouts, per-hinge parameters, threads, the GIL, and ValueError for bad input."""

import inspect
import re
import threading
import time
import warnings

import numpy as np
import pytest
import scipy.sparse as sp

import hinge


def sheet(nx, ny, seed, jitter=0.2):
    """An irregular sheet: random diagonals, jittered positions, random numbering and corner rotations."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(float) / max(nx, ny)
    V[:, :2] += rng.uniform(-jitter, jitter, size=(V.shape[0], 2)) / max(nx, ny)
    idx = lambda i, j: i * (ny + 1) + j
    F = []
    for i in range(nx):
        for j in range(ny):
            a, b, c, d = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            if rng.random() < 0.5:
                F += [[a, b, c], [a, c, d]]
            else:
                F += [[a, b, d], [b, c, d]]
    F = np.array(F)
    F = np.array([np.roll(f, rng.integers(3)) for f in F])
    perm = rng.permutation(V.shape[0])
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    return V[perm], inv[F]


def closed_sphere(seed, levels=2):
    """A closed mesh: an octahedron subdivided `levels` times onto the unit sphere, randomly numbered with
    rotated corners."""
    V = [np.array(v, float) for v in [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]]
    F = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]
    for _ in range(levels):
        mid, G = {}, []

        def m(a, b):
            key = (min(a, b), max(a, b))
            if key not in mid:
                V.append((V[a] + V[b]) / 2)
                mid[key] = len(V) - 1
            return mid[key]
        for a, b, c in F:
            ab, bc, ca = m(a, b), m(b, c), m(c, a)
            G += [(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)]
        F = G
    V = np.array([v / np.linalg.norm(v) for v in V])
    rng = np.random.default_rng(seed)
    F = np.array([np.roll(f, rng.integers(3)) for f in F])
    perm = rng.permutation(V.shape[0])
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    return V[perm], inv[F]


def bent(V, seed, amp=0.05):
    rng = np.random.default_rng(seed)
    X = V.copy()
    X[:, 2] += 0.3 * np.sin(3.0 * V[:, 0]) * np.cos(2.0 * V[:, 1])
    return X + rng.uniform(-amp, amp, size=V.shape) * 0.1


@pytest.mark.parametrize("energy", ["discrete-shells", "tan-bending", "willmore", "bridson"])
def test_gradient_and_hessian_match_finite_differences(energy):
    V, F = sheet(5, 4, 1)
    X = bent(V, 2)
    m = hinge.BendingModel(V, F, energy=energy, k=1.3)
    E, g, H = m.evaluate(X)
    assert isinstance(H, sp.csr_matrix) and H.shape == (3 * len(V), 3 * len(V))
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    h = 1e-6
    fd_g = np.zeros_like(g)
    fd_H = np.zeros((g.size, g.size))
    for i in range(g.size):
        Xp, Xm = X.copy(), X.copy()
        Xp.flat[i] += h
        Xm.flat[i] -= h
        (ep, gp), (em, gm) = m.evaluate(Xp, hessian=False), m.evaluate(Xm, hessian=False)
        fd_g[i] = (ep - em) / (2 * h)
        fd_H[i] = (gp - gm) / (2 * h)
    assert np.abs(g - fd_g).max() <= 1e-6 * max(1.0, np.abs(g).max())
    assert np.abs(H.toarray() - fd_H).max() <= 1e-5 * max(1.0, np.abs(fd_H).max())


def test_methods_agree_and_psi_strings_equal_the_builtins_bitwise():
    V, F = sheet(6, 6, 3)
    X = bent(V, 4)
    ref = hinge.BendingModel(V, F, energy="tan-bending", k=0.7)
    E, g, H = ref.evaluate(X)
    for method in ["per_hinge", "autodiff"]:
        E2, g2, H2 = hinge.BendingModel(V, F, energy="tan-bending", method=method, k=0.7).evaluate(X)
        assert abs(E - E2) <= 1e-12 * abs(E)
        assert np.abs(g - g2).max() <= 1e-11 * np.abs(g).max()
        assert abs(H - H2).max() <= 1e-10 * abs(H).max()
    text = dict((n, t) for n, t, _ in hinge.energies())["tan-bending"]
    E3, g3, H3 = hinge.BendingModel(V, F, psi=text, k=0.7).evaluate(X)
    assert E3 == E and np.array_equal(g3, g) and np.array_equal(H3.data, H.data)


def test_projected_hessian_is_the_sum_of_per_hinge_projections():
    """hessian="projected" against each hinge's exact Hessian (a model of its two triangles alone)
    projected by numpy's eigh; "gauss-newton" is PSD too; energy and gradient never change."""
    V, F = sheet(4, 3, 11)
    X = bent(V, 12)
    X[:, 2] += 0.25 * np.sin(5.0 * V[:, 0] + 1.0) * np.cos(4.0 * V[:, 1])
    exact = hinge.BendingModel(V, F, energy="tan-bending", k=0.9)
    E, g, H = exact.evaluate(X)
    Hd = H.toarray()
    assert exact.hessian == "exact"
    assert np.linalg.eigvalsh(Hd).min() < -1e-3 * np.abs(Hd).max(), "indefinite at this state"
    n = 3 * len(V)
    expected = np.zeros((n, n))
    for idx in exact.hinges:
        one = hinge.BendingModel(V[idx], np.array([[0, 1, 2], [3, 2, 1]]), energy="tan-bending", k=0.9)
        _, _, h = one.evaluate(X[idx])
        w, U = np.linalg.eigh(h.toarray())
        dofs = (3 * idx[:, None] + np.arange(3)).ravel()
        expected[np.ix_(dofs, dofs)] += (U * np.maximum(w, 0.0)) @ U.T
    # The methods agree to these tolerances on exact Hessians too (test_methods_agree_...).
    for method, tol in [("refactored", 1e-12), ("per_hinge", 1e-10), ("autodiff", 1e-10)]:
        proj = hinge.BendingModel(V, F, energy="tan-bending", k=0.9, method=method, hessian="projected")
        assert proj.hessian == "projected"
        Ep, gp, Hp = proj.evaluate(X)
        assert abs(Ep - E) <= 1e-12 * abs(E) and np.abs(gp - g).max() <= 1e-11 * np.abs(g).max()
        assert np.abs(Hp.toarray() - expected).max() <= tol * np.abs(expected).max(), method
    gn = hinge.BendingModel(V, F, energy="tan-bending", k=0.9, hessian="gauss-newton")
    Hg = gn.evaluate(X)[2].toarray()
    assert np.linalg.eigvalsh(Hg).min() >= -1e-13 * np.abs(Hg).max()
    with pytest.raises(ValueError, match="unknown hessian `nope`"):
        hinge.BendingModel(V, F, hessian="nope")
    with pytest.raises(ValueError, match="hessian must be a string"):
        hinge.BendingModel(V, F, hessian=1)


def test_threads_context_sets_the_pool_of_the_calls_in_it():
    default = hinge._hinge._current_threads()
    V, F = sheet(5, 4, 17)
    X = bent(V, 18)
    s = hinge.System(V, F).add_bending(energy="tan-bending", k=0.8).add_membrane(2e5, 0.3, 5e-4)
    m = hinge.BendingModel(V, F, energy="tan-bending", k=0.8)
    E, g, H = s.evaluate(X)
    Em, gm, Hm = m.evaluate(X)
    with hinge.threads(default + 1):
        assert hinge._hinge._current_threads() == default + 1
        with hinge.threads(1):
            assert hinge._hinge._current_threads() == 1
            E1, g1, H1 = s.evaluate(X)
            Em1, gm1, Hm1 = m.evaluate(X)
        assert hinge._hinge._current_threads() == default + 1
        E3, g3, H3 = s.evaluate(X)
    assert hinge._hinge._current_threads() == default
    # Bitwise the same results for any thread count.
    for a, b in [(E1, E), (E3, E), (Em1, Em)]:
        assert a == b
    for a, b in [(g1, g), (g3, g), (gm1, gm)]:
        assert np.array_equal(a, b)
    for a, b in [(H1, H), (H3, H), (Hm1, Hm)]:
        assert np.array_equal(a.toarray(), b.toarray())
    # An exception inside the block closes the context; other threads do not see it.
    with pytest.raises(RuntimeError):
        with hinge.threads(2):
            raise RuntimeError("inside")
    assert hinge._hinge._current_threads() == default
    import threading
    seen = []
    with hinge.threads(default + 1):
        t = threading.Thread(target=lambda: seen.append(hinge._hinge._current_threads()))
        t.start()
        t.join()
        assert hinge._hinge._current_threads() == default + 1
    assert seen == [default]
    for bad in [0, -1, 2.0, True, "2"]:
        with pytest.raises(ValueError):
            hinge.threads(bad)
    with pytest.raises(ValueError, match="at most 1024"):
        with hinge.threads(5000):
            pass
    with pytest.raises(ValueError, match="no hinge.threads context"):
        hinge._hinge._pop_threads()


@pytest.mark.parametrize("mesh", ["sheet", "closed"])
def test_system_bending_methods_agree_and_each_term_is_its_model(mesh):
    # An irregular sheet (boundary) and a closed subdivided octahedron, both randomly numbered with rotated
    # corners, bent and wrinkled; tan bending (built in) and a psi string, each by the three per-hinge
    # methods, beside a membrane.
    V, F = sheet(5, 4, 17) if mesh == "sheet" else closed_sphere(23)
    X = bent(V, 18)
    X[:, 2] += 0.2 * np.sin(5.0 * V[:, 0]) * np.cos(4.0 * V[:, 1])
    membrane = hinge.System(V, F).add_membrane(2e5, 0.3, 5e-4)
    Em, gm, Hm = membrane.evaluate(X)
    for spec in [dict(energy="tan-bending", k=0.8), dict(psi="k * a * (theta - theta_bar).powi(2)", k=1.3)]:
        ref = None
        for method in ["refactored", "per_hinge", "autodiff"]:
            s = hinge.System(V, F).add_bending(method=method, **spec).add_membrane(2e5, 0.3, 5e-4)
            E, g, H = s.evaluate(X)
            Eb, gb, Hb = hinge.BendingModel(V, F, method=method, **spec).evaluate(X)
            # The system's bending term is the model with that method (plus the membrane).
            assert abs(E - (Eb + Em)) <= 1e-14 * abs(E)
            assert np.abs(g - (gb + gm)).max() <= 1e-14 * np.abs(g).max()
            assert np.abs((H - (Hb + Hm)).toarray()).max() <= 1e-14 * np.abs(H).max()
            # The three methods compute the same Hessian by different routes (closed form per triangle,
            # per hinge, num-dual): equal to a few ulps of its size.
            if ref is None:
                ref = (E, g, H)
            else:
                assert abs(E - ref[0]) <= 1e-14 * abs(E)
                assert np.abs(g - ref[1]).max() <= 1e-13 * np.abs(g).max()
                assert np.abs((H - ref[2]).toarray()).max() <= 1e-12 * np.abs(H).max()
    with pytest.raises(ValueError, match=r"unknown method `nope` \(refactored, per_hinge, autodiff\)"):
        hinge.System(V, F).add_bending(energy="tan-bending", method="nope")
    with pytest.raises(ValueError, match="method must be a string"):
        hinge.System(V, F).add_bending(energy="tan-bending", method=3)


def test_system_definite_hessian_is_psd_and_exact_where_nothing_is_clamped():
    V, F = sheet(5, 4, 17)
    # Bending alone: the definite Hessian is the Gauss-Newton one of the bending model.
    X = bent(V, 18)
    X[:, 2] += 0.2 * np.sin(5.0 * V[:, 0]) * np.cos(4.0 * V[:, 1])
    s = hinge.System(V, F).add_bending(energy="tan-bending", k=0.8)
    E, g, H = s.evaluate(X)
    Ed, gd, Hd = s.evaluate(X, definite=True)
    assert Ed == E and np.array_equal(gd, g)
    Hgn = hinge.BendingModel(V, F, energy="tan-bending", k=0.8, hessian="gauss-newton").evaluate(X)[2]
    assert np.abs((Hd - Hgn).toarray()).max() <= 1e-13 * np.abs(Hgn).max()
    # A membrane in tension: nothing to clamp, the definite Hessian is the exact one.
    m = hinge.System(V, F).add_membrane(2e5, 0.3, 5e-4)
    stretched = V * np.array([1.1, 1.05, 1.0])
    H = m.evaluate(stretched)[2]
    assert np.abs((m.evaluate(stretched, definite=True)[2] - H).toarray()).max() <= 1e-12 * np.abs(H).max()
    # Compressed, bent and pressed into a sphere: exact indefinite, definite positive semi-definite.
    full = (hinge.System(V, F).add_bending(energy="tan-bending", k=0.8).add_membrane(2e5, 0.3, 5e-4)
            .add_gravity(0.1).add_sphere((0.5, 0.5, -0.98), 1.0, 2e3, margin=0.01))
    squeezed = X * np.array([0.9, 0.95, 1.0])
    H = full.evaluate(squeezed)[2].toarray()
    Hd = full.evaluate(squeezed, definite=True)[2].toarray()
    assert np.linalg.eigvalsh(H).min() < -1e-6 * np.abs(H).max()
    assert np.linalg.eigvalsh(Hd).min() >= -1e-12 * np.abs(Hd).max()
    # A bending term in the projected mode keeps it in definite evaluations (projected Newton's Hessian):
    # the bending model's projected Hessian plus the other terms' definite ones.
    proj = (hinge.System(V, F).add_bending(energy="tan-bending", hessian="projected", k=0.8)
            .add_membrane(2e5, 0.3, 5e-4))
    rest_of_it = hinge.System(V, F).add_membrane(2e5, 0.3, 5e-4)
    Hb = hinge.BendingModel(V, F, energy="tan-bending", k=0.8, hessian="projected").evaluate(squeezed)[2]
    want = (Hb + rest_of_it.evaluate(squeezed, definite=True)[2]).toarray()
    for definite in [True, False]:
        got = proj.evaluate(squeezed, definite=definite)[2].toarray()
        if definite:
            assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()
        else:  # the exact membrane is indefinite under compression
            assert np.abs(got - want).max() > 1e-6 * np.abs(want).max()
    with pytest.raises(ValueError, match="unknown hessian `nope`"):
        hinge.System(V, F).add_bending(energy="tan-bending", hessian="nope")


def test_per_hinge_parameters_follow_the_hinge_order():
    V, F = sheet(4, 5, 5)
    X = bent(V, 6)
    hs = hinge.hinges(V, F)
    m = hinge.BendingModel(V, F, energy="discrete-shells", k=np.full(len(hs), 2.0))
    assert np.array_equal(m.hinges, hs) and m.n_hinges == len(hs)
    E, g, H = m.evaluate(X)
    E2, g2, H2 = hinge.BendingModel(V, F, energy="discrete-shells", k=2.0).evaluate(X)
    assert E == E2 and np.array_equal(g, g2) and np.array_equal(H.data, H2.data)
    # Stiffness on one hinge only: the energy is that hinge's own.
    k = np.zeros(len(hs))
    k[3] = 1.0
    e_one = hinge.BendingModel(V, F, energy="discrete-shells", k=k).energy_value(X)
    Vh = V[hs[3]]
    Xh = X[hs[3]]
    e_alone = hinge.BendingModel(Vh, np.array([[0, 1, 2], [3, 2, 1]]), energy="discrete-shells").energy_value(Xh)
    assert abs(e_one - e_alone) <= 1e-12 * abs(e_alone)


def test_dtypes_and_layouts_give_the_same_numbers():
    V, F = sheet(4, 4, 7)
    X = bent(V, 8)
    ref = hinge.BendingModel(V, F, energy="willmore").evaluate(X)
    for Fv in [F.astype(np.int32), np.asfortranarray(F), F.astype(np.uint16), F.astype(np.int8)]:
        for Vv in [V, np.asfortranarray(V)]:
            out = hinge.BendingModel(Vv, Fv, energy="willmore").evaluate(np.asfortranarray(X))
            assert out[0] == ref[0] and np.array_equal(out[1], ref[1])


def test_evaluate_into_and_pattern():
    V, F = sheet(5, 5, 9)
    X = bent(V, 10)
    m = hinge.BendingModel(V, F, psi="k * a * if theta < theta_bar { (theta - theta_bar).powi(2) } else { 2.0 * (theta - theta_bar).powi(2) }", k=1.1)
    E, g, H = m.evaluate(X)
    indptr, indices = m.pattern()
    assert np.array_equal(indptr, H.indptr) and np.array_equal(indices, H.indices)
    g_out, data_out = np.zeros(3 * len(V)), np.zeros(m.nnz)
    E2 = m.evaluate_into(X, g_out, data_out)
    assert E2 == E and np.array_equal(g_out, g) and np.array_equal(data_out, H.data)
    assert m.evaluate_into(X, g_out) == E
    with pytest.raises(ValueError):
        m.evaluate_into(X, np.zeros(5), data_out)
    with pytest.raises(ValueError):
        m.evaluate_into(X, g_out.astype(np.float32))


def test_threads_give_identical_bits():
    V, F = sheet(60, 60, 11)
    X = bent(V, 12)
    outs = [hinge.BendingModel(V, F, energy="tan-bending", threads=t).evaluate(X) for t in (1, 2, 3)]
    for E, g, H in outs[1:]:
        assert E == outs[0][0] and np.array_equal(g, outs[0][1]) and np.array_equal(H.data, outs[0][2].data)


def test_evaluation_releases_the_gil():
    V, F = sheet(300, 300, 13, jitter=0.1)
    X = bent(V, 14)
    m = hinge.BendingModel(V, F, energy="tan-bending", threads=1)
    m.evaluate(X)
    count = [0]
    stop = [False]

    def spin():
        while not stop[0]:
            count[0] += 1

    t = threading.Thread(target=spin)
    t.start()
    time.sleep(0.05)
    c0 = count[0]
    start = time.perf_counter()
    m.evaluate(X)
    m.evaluate(X)
    elapsed = time.perf_counter() - start
    c1 = count[0]
    stop[0] = True
    t.join()
    # The other thread kept counting while the evaluations ran (it could not with the GIL held).
    assert elapsed > 0.05 and c1 - c0 > 10_000, (elapsed, c1 - c0)


def test_damping_step_and_parameter_updates():
    V, F = sheet(4, 4, 15)
    X = bent(V, 16)
    d = hinge.BendingModel(V, F, energy="viscous-damping", kd=0.5)
    d.set_step(X, 0.01)
    assert d.energy_value(X) == 0.0
    assert d.energy_value(bent(V, 17)) > 0.0
    m = hinge.BendingModel(V, F, psi="k * a * (theta - theta_bar).powi(2)", k=1.0)
    m.set_parameter("k", 3.0)
    fresh = hinge.BendingModel(V, F, psi="k * a * (theta - theta_bar).powi(2)", k=3.0)
    assert m.energy_value(X) == fresh.energy_value(X)
    m.set_rest_angles(np.zeros(m.n_hinges))
    flat = hinge.BendingModel(V, F, psi="k * a * theta.powi(2)", k=3.0)
    assert m.energy_value(X) == flat.energy_value(X)
    with pytest.raises(ValueError, match="no parameter `q`"):
        m.set_parameter("q", 1.0)


def bad(**kw):
    V, F = sheet(3, 3, 18)
    args = dict(V=V, F=F)
    args.update(kw)
    V, F = args.pop("V"), args.pop("F")
    return lambda: hinge.BendingModel(V, F, **args)


@pytest.mark.parametrize(
    "make, message",
    [
        (bad(V=np.zeros((4, 2))), "shape"),
        (bad(F=np.zeros((3, 4), int)), "shape"),
        (bad(F=np.array([[0.0, 1.0, 2.0]])), "integer"),
        (bad(F=np.array([[0, 1, 99]])), "99"),
        (bad(F=np.array([[0, -1, 2]])), "negative"),
        (bad(F=np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])), "manifold"),
        (bad(V=np.full((16, 3), np.nan)), "finite"),
        (bad(energy="bending"), "unknown energy"),
        (bad(energy="tan-bending", stiffness=1.0), "no parameter `stiffness`"),
        (bad(energy="tan-bending", k=np.ones(3)), "hinges"),
        (bad(energy="tan-bending", k="soft"), "number"),
        (bad(psi="k * (theta +* 2)", k=1.0), "column 13"),
        (bad(psi="k * tehta", k=1.0), "did you mean `theta`"),
        (bad(psi="theta.powi(2)", k=1.0), "not used"),
        (bad(energy="tan-bending", psi="theta"), "not both"),
        (bad(method="fast"), "unknown method"),
        (bad(threads=0), "threads"),
        (bad(threads=1.5), "threads"),
    ],
)
def test_bad_input_raises_value_error(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_bad_positions_raise_value_error():
    V, F = sheet(3, 3, 19)
    m = hinge.BendingModel(V, F)
    with pytest.raises(ValueError, match="shape"):
        m.evaluate(V[:-1])
    X = V.copy()
    X[5, 1] = np.inf
    with pytest.raises(ValueError, match="vertex 5"):
        m.evaluate(X)
    with pytest.raises(ValueError):
        m.evaluate(V.astype(str))
    # A ψ that is not finite at some hinge: a typed error naming the hinge, not a silent NaN.
    V2 = np.array([[0, 1, 0], [0, 0, 0], [1, 0, 0], [1, 1, 0]], float)
    F2 = np.array([[0, 1, 2], [3, 2, 1]])
    t = hinge.BendingModel(V2, F2, psi="k * ln(theta - 10.0)", k=1.0)
    with pytest.raises(ValueError, match="hinge 0"):
        t.evaluate(V2)


def test_system_composes_energies_and_matches_its_parts():
    V, F = sheet(6, 6, 21)
    X = bent(V, 22)
    s = hinge.System(V, F)
    s.add_bending(energy="tan-bending", k=1e-3).add_membrane(2e5, 0.3, 5e-4).add_gravity(0.1)
    s.add_sphere((0.5, 0.5, -0.2), 0.3, 2e3, margin=5e-3).add_springs(10.0, compressive=False)
    assert s.terms == ["tan-bending", "membrane", "gravity", "contact-sphere", "mass-spring"]
    E, g, H = s.evaluate(X)
    Eb, gb, Hb = hinge.BendingModel(V, F, energy="tan-bending", k=1e-3).evaluate(X)
    rest = hinge.System(V, F).add_membrane(2e5, 0.3, 5e-4).add_gravity(0.1)
    rest.add_sphere((0.5, 0.5, -0.2), 0.3, 2e3, margin=5e-3).add_springs(10.0, compressive=False)
    Er, gr, Hr = rest.evaluate(X)
    assert abs(E - (Eb + Er)) <= 1e-12 * abs(E)
    assert np.abs(g - (gb + gr)).max() <= 1e-12 * np.abs(g).max()
    assert abs(H - (Hb + Hr)).max() <= 1e-12 * abs(H).max()
    # Gradient against finite differences of the whole system.
    h = 1e-7
    i = 17
    Xp, Xm = X.copy(), X.copy()
    Xp.flat[i] += h
    Xm.flat[i] -= h
    fd = (s.evaluate(Xp, hessian=False)[0] - s.evaluate(Xm, hessian=False)[0]) / (2 * h)
    assert abs(fd - g[i]) <= 1e-5 * max(1.0, abs(g[i]))


def clamped_sheet(seed, k, young):
    """A 0.3 m sheet (8 × 3 cells, jittered) with discrete-shells bending `k`, a 1 mm membrane of `young`
    and gravity, clamped along its first column: `(V, F, system, clamped vertices)`."""
    V, F = sheet(8, 3, seed, jitter=0.05)
    V = V * [0.3, 0.3, 1.0]
    s = hinge.System(V, F).add_bending(energy="discrete-shells", k=k).add_membrane(young, 0.3, 1e-3)
    s.add_gravity(0.5)
    clamp = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 8)
    s.pin(clamp)
    return V, F, s, clamp


def test_newton_globalization_and_extrapolation_switches():
    # A sheet started compressed to 85% of its width buckles: its exact Hessian is indefinite at the start.
    V, F, s, clamp = clamped_sheet(29, 1e-3, 1e5)
    X0 = V.copy()
    X0[:, 0] *= 0.85
    X0[:, 2] += 1e-4 * np.sin(np.pi * V[:, 0] / 0.3)
    results = {}
    for g in ("shifted-exact", "project-on-demand"):
        for e in (True, False):
            X, st = hinge.solve_static(s, X0, gradient_tolerance=1e-9, globalization=g, extrapolate=e)
            assert st["final_gradient_norm"] <= 1e-9
            results[(g, e)] = (X, st)
    # The shift never asks for the definite Hessian; project on demand does, here.
    assert all(results[("shifted-exact", e)][1]["definite_iterations"] == 0 for e in (True, False))
    assert results[("project-on-demand", False)][1]["definite_iterations"] > 0
    # The switches change the path (counts differ somewhere), not the problem: each end is an equilibrium.
    counts = {k: (st["newton_iterations"], st["line_search_steps"]) for k, (_, st) in results.items()}
    assert len(set(counts.values())) > 1, counts
    free = np.setdiff1d(np.arange(len(V)), clamp)
    for X, _ in results.values():
        _, g = s.evaluate(X, hessian=False)
        assert np.abs(g.reshape(-1, 3)[free]).max() <= 1e-9
    for bad in ({"globalization": "projected"}, {"extrapolate": 1}):
        with pytest.raises(ValueError):
            hinge.solve_static(s, X0, **bad)
        with pytest.raises(ValueError):
            hinge.ImplicitEuler(s, V, 0.01, 0.1, **bad)
    # The stepper takes them too.
    t = hinge.ImplicitEuler(s, V, 0.01, 0.1, globalization="project-on-demand", extrapolate=False)
    X, st = t.step()
    assert st["final_gradient_norm"] <= 1e-8 and "definite_iterations" in st


def test_unit_free_stopping_tests_shift_memory_and_acceleration_from_python():
    V, F, s, clamp = clamped_sheet(31, 1e-3, 1e5)
    X0 = V.copy()
    X0[:, 0] *= 0.85
    X0[:, 2] += 1e-4 * np.sin(np.pi * V[:, 0] / 0.3)
    opts = dict(gradient_tolerance=1e-11, membrane_continuation=False)
    Xa, sa = hinge.solve_static(s, X0, **opts)
    # The relative gradient test ends the solve once the gradient fell 1e4-fold from its start.
    Xr, sr = hinge.solve_static(s, X0, relative_gradient_tolerance=1e-4, **opts)
    g0 = sr["gradient_norms"][0]
    assert g0 == sa["gradient_norms"][0]
    assert sr["final_gradient_norm"] <= 1e-4 * g0
    assert all(g > 1e-4 * g0 for g in sr["gradient_norms"][:-1])
    assert sr["newton_iterations"] < sa["newton_iterations"]
    # The relative step test: stop after an exact Newton step that moved no vertex farther than 1e-3 mean
    # edge lengths; that is before the absolute gradient test.
    Xs, ss = hinge.solve_static(s, X0, relative_step_tolerance=1e-3, **opts)
    assert ss["newton_iterations"] < sa["newton_iterations"]
    free = np.setdiff1d(np.arange(len(V)), clamp)
    edge = np.mean([np.linalg.norm(V[a] - V[b]) for f in F for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))])
    # Near the solution the last step is the error of the iterate before it: the end is within a small
    # multiple of the tolerance of the tightly converged equilibrium.
    assert np.abs(Xs - Xa)[free].max() <= 1e-3 * edge
    # The shift memory acts across the stages of the membrane continuation (one Newton for all of them): on
    # a stiffer, thinner sheet it changes the path, not the equilibrium.
    V2, _, s2, _ = clamped_sheet(31, 1e-5, 1e7)
    Y0 = V2.copy()
    Y0[:, 0] *= 0.85
    Y0[:, 2] += 1e-4 * np.sin(np.pi * V2[:, 0] / 0.3)
    paths = {}
    for remember in (True, False):
        Y, st = hinge.solve_static(s2, Y0, gradient_tolerance=1e-9, remember_shift=remember)
        assert st["final_gradient_norm"] <= 1e-9
        paths[remember] = (st["newton_iterations"], st["factorizations"])
    assert paths[True] != paths[False], paths
    # Geodesic acceleration changes the path, not the equilibrium; without it no step is corrected.
    ends = {}
    for accelerate in (True, False):
        Y, st = hinge.solve_static(s2, Y0, gradient_tolerance=1e-9, geodesic_acceleration=accelerate)
        assert st["final_gradient_norm"] <= 1e-9
        assert (st["accelerated_iterations"] > 0) == accelerate, st["accelerated_iterations"]
        ends[accelerate] = Y
    assert np.abs(ends[True] - ends[False]).max() <= 1e-3 * edge
    t = hinge.ImplicitEuler(s, X0, 0.01, 0.1, gradient_tolerance=1e-9, geodesic_acceleration=False)
    assert all(st["accelerated_iterations"] == 0 for _, st in [t.step() for _ in range(2)])
    # The stepper takes the same keyword arguments; without the shift memory it repeats itself exactly.
    runs = []
    for _ in range(2):
        t = hinge.ImplicitEuler(s, X0, 0.01, 0.1, gradient_tolerance=1e-9, remember_shift=False)
        steps = [t.step() for _ in range(2)]
        assert all(st["final_gradient_norm"] <= 1e-9 for _, st in steps)
        runs.append((steps[-1][0], [st["factorizations"] for _, st in steps]))
    assert np.array_equal(runs[0][0], runs[1][0]) and runs[0][1] == runs[1][1]
    t = hinge.ImplicitEuler(s, X0, 0.01, 0.1, relative_gradient_tolerance=1e-3, gradient_tolerance=1e-12)
    X, st = t.step()
    assert st["final_gradient_norm"] <= 1e-3 * st["gradient_norms"][0]
    # gradient_tolerance = 0, as scene files allow it: the relative test alone ends the solve, at the same
    # iterate (the absolute test of 1e-12 N above never fired first).
    t0 = hinge.ImplicitEuler(s, X0, 0.01, 0.1, relative_gradient_tolerance=1e-3, gradient_tolerance=0.0)
    X0b, st0 = t0.step()
    assert st0["gradient_norms"] == st["gradient_norms"] and np.array_equal(X0b, X)
    Xz, sz = hinge.solve_static(s, X0, gradient_tolerance=0.0, relative_gradient_tolerance=1e-4,
                                membrane_continuation=False)
    assert np.array_equal(Xz, Xr) and sz["gradient_norms"] == sr["gradient_norms"]
    for bad in ({"relative_gradient_tolerance": -1.0}, {"relative_step_tolerance": float("nan")},
                {"relative_gradient_tolerance": "1e-3"}, {"remember_shift": 1},
                {"geodesic_acceleration": "yes"}):
        with pytest.raises(ValueError):
            hinge.solve_static(s, X0, **bad)
        with pytest.raises(ValueError):
            hinge.ImplicitEuler(s, V, 0.01, 0.1, **bad)
    # definite_shift_ratio (the stepper's only): 0 turns every shifted iteration to the definite Hessian,
    # inf never does; both converge.
    definite = {}
    for ratio in (0.0, float("inf")):
        t = hinge.ImplicitEuler(s, X0, 0.01, 0.1, gradient_tolerance=1e-9, definite_shift_ratio=ratio)
        steps = [t.step() for _ in range(2)]
        assert all(st["final_gradient_norm"] <= 1e-9 for _, st in steps)
        definite[ratio] = sum(st["definite_iterations"] for _, st in steps)
    assert definite[float("inf")] == 0 and definite[0.0] > 0, definite
    for bad in (-1.0, float("nan"), "1", True):
        with pytest.raises(ValueError):
            hinge.ImplicitEuler(s, V, 0.01, 0.1, definite_shift_ratio=bad)
    # The default is the Rust constant (exported, not repeated), 1000 as the docstring says.
    default = inspect.signature(hinge.ImplicitEuler).parameters["definite_shift_ratio"].default
    assert default is hinge.DEFINITE_SHIFT_RATIO and default == 1000.0
    assert "DEFINITE_SHIFT_RATIO`` = 1000" in hinge.ImplicitEuler.__doc__
    # definite_hold: with every shifted iteration definite, holding the definite Hessian for 3 full steps
    # instead of 1 changes the steps, and both converge; project on demand in statics takes it too.
    counts = {}
    for hold in (1, 3):
        t = hinge.ImplicitEuler(s, X0, 0.01, 0.1, gradient_tolerance=1e-9, definite_shift_ratio=0.0,
                                definite_hold=hold)
        steps = [t.step() for _ in range(2)]
        assert all(st["final_gradient_norm"] <= 1e-9 for _, st in steps)
        counts[hold] = [(st["newton_iterations"], st["factorizations"], st["definite_iterations"])
                        for _, st in steps]
    assert counts[1] != counts[3], counts
    Xh, sh = hinge.solve_static(s, X0, globalization="project-on-demand", definite_hold=2)
    assert sh["final_gradient_norm"] <= 1e-8
    for bad in (0, -1, 1.5, "2", True):
        with pytest.raises(ValueError, match="definite_hold"):
            hinge.ImplicitEuler(s, V, 0.01, 0.1, definite_hold=bad)
        with pytest.raises(ValueError, match="definite_hold"):
            hinge.solve_static(s, X0, definite_hold=bad)
    for f in (hinge.ImplicitEuler, hinge.solve_static):
        default = inspect.signature(f).parameters["definite_hold"].default
        assert default is hinge.DEFINITE_HOLD and default == 1


def test_membrane_continuation_reaches_the_same_equilibrium_in_fewer_iterations():
    # A 0.3 m × 1.25 cm strip, 0.1 mm thick, Y = 1e10 Pa, clamped at one end, bends down by half its length
    # under its own weight: the stiff membrane makes plain Newton slow (179 iterations against 25).
    V, F = sheet(60, 5, 31, jitter=0.05)
    V = V * [0.3, 0.0125 * 60 / 5, 1.0]
    young, h, nu = 1e10, 1e-4, 0.3
    d = young * h**3 / (12 * (1 - nu * nu))
    s = hinge.System(V, F).add_bending(energy="tan-bending", k=d).add_membrane(young, nu, h)
    s.add_gravity(0.1)
    s.pin(np.flatnonzero(V[:, 0] <= 0.3 / 60 * 1.5))
    runs = {}
    for on in (True, False):
        X, st = hinge.solve_static(s, V, gradient_tolerance=1e-9, membrane_continuation=on)
        assert st["final_gradient_norm"] <= 1e-9
        runs[on] = (X, st["newton_iterations"])
    (X1, n1), (X0, n0) = runs[True], runs[False]
    assert X1[:, 2].min() < -0.1  # a large deflection
    assert np.abs(X1 - X0).max() <= 1e-7, np.abs(X1 - X0).max()
    assert 2 * n1 < n0, (n1, n0)
    with pytest.raises(ValueError):
        hinge.solve_static(s, V, membrane_continuation="yes")


def test_membrane_continuation_scales_every_membrane():
    # The stiff strip of the test above with its membrane split into two terms of half the Young's modulus
    # (the same energy): the continuation softens both alike (stages from their summed stiffness), so the
    # same equilibrium in as many iterations (up to rounding); both parameters are back to their values.
    V, F = sheet(60, 5, 31, jitter=0.05)
    V = V * [0.3, 0.0125 * 60 / 5, 1.0]
    young, h, nu = 1e10, 1e-4, 0.3
    d = young * h**3 / (12 * (1 - nu * nu))
    clamp = np.flatnonzero(V[:, 0] <= 0.3 / 60 * 1.5)
    runs = []
    for parts in (1, 2):
        s = hinge.System(V, F).add_bending(energy="tan-bending", k=d)
        for _ in range(parts):
            s.add_membrane(young / parts, nu, h)
        s.add_gravity(0.1).pin(clamp)
        X, st = hinge.solve_static(s, V, gradient_tolerance=1e-9)
        assert st["final_gradient_norm"] <= 1e-9
        runs.append((X, st["newton_iterations"]))
    assert s.terms == ["tan-bending", "membrane", "membrane#2", "gravity"]
    assert s.parameter("membrane.young")[0] == young / 2 and s.parameter("membrane#2.young")[0] == young / 2
    (X1, n1), (X2, n2) = runs
    assert np.abs(X1 - X2).max() <= 1e-7, np.abs(X1 - X2).max()
    print("one membrane / two halves, Newton iterations:", n1, n2)
    assert n2 <= n1 + 2, (n1, n2)


def test_static_solve_without_a_stvk_membrane():
    # The membrane continuation scales the StVK membrane; a system without one (springs in the plane, or
    # the co-rotational membrane) is solved by plain Newton, with or without the option.
    V, F = sheet(8, 3, 23, jitter=0.05)
    V = V * [0.3, 0.3, 1.0]
    clamp = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 8)
    free = np.setdiff1d(np.arange(len(V)), clamp)
    for membrane in ("springs", "corotational"):
        s = hinge.System(V, F).add_bending(energy="discrete-shells", k=1e-2).add_gravity(0.5)
        if membrane == "springs":
            s.add_springs(1e3)
        else:
            s.add_membrane(1e6, 0.3, 1e-3, kind=membrane)
        s.pin(clamp)
        ends = []
        for on in (True, False):
            X, st = hinge.solve_static(s, V, gradient_tolerance=1e-10, membrane_continuation=on)
            _, g = s.evaluate(X, hessian=False)
            assert np.abs(g.reshape(-1, 3)[free]).max() <= 1e-10
            assert np.array_equal(X[clamp], V[clamp]) and V[:, 2].min() - X[:, 2].min() > 0.01
            ends.append(X)
        assert np.array_equal(ends[0], ends[1]), membrane


def test_membrane_continuation_of_the_corotational_membrane():
    # A 0.1 mm strip of Y = 1e10 Pa with the co-rotational membrane: its stiffness is what the continuation
    # scales. The same equilibrium, in fewer iterations.
    V, F = sheet(24, 3, 41, jitter=0.05)
    V = V * [0.3, 0.3, 1.0]
    s = hinge.System(V, F).add_bending(energy="discrete-shells", k=1e-3)
    s.add_membrane(1e10, 0.3, 1e-4, kind="corotational").add_gravity(0.5)
    clamp = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 12)
    s.pin(clamp)
    k = s.parameter("corotational-membrane.stiffness")
    runs = {}
    for on in (True, False):
        X, st = hinge.solve_static(s, V, gradient_tolerance=1e-9, membrane_continuation=on)
        assert st["final_gradient_norm"] <= 1e-9
        runs[on] = (X, st["newton_iterations"])
    assert np.array_equal(s.parameter("corotational-membrane.stiffness"), k)
    assert V[:, 2].min() - runs[True][0][:, 2].min() > 0.05
    assert np.abs(runs[True][0] - runs[False][0]).max() < 1e-8
    print("co-rotational strip, Newton iterations with / without the continuation:", runs[True][1], runs[False][1])
    assert 2 * runs[True][1] < runs[False][1]


def test_static_solve_reaches_equilibrium_and_holds_pins():
    V, F, s, clamp = clamped_sheet(23, 1e-2, 1e6)
    X, stats = hinge.solve_static(s, V)
    assert stats["final_gradient_norm"] <= 1e-8 and stats["newton_iterations"] > 0
    assert np.array_equal(X[clamp], V[clamp])
    assert X[:, 2].min() < -1e-4  # it sagged
    # At equilibrium the free gradient vanishes.
    _, g = s.evaluate(X, hessian=False)
    free = np.setdiff1d(np.arange(len(V)), clamp)
    assert np.abs(g.reshape(-1, 3)[free]).max() <= 1e-7


def test_vertices_in_no_triangle_are_held_and_change_nothing_else():
    # Two extra vertices in the middle of the numbering, in no triangle (as modelling tools leave them): no
    # mass, no stiffness. Held where they are, the others reach the same equilibrium on the same Newton path
    # (before, every Hessian was singular and needed a diagonal shift).
    V, F, s, clamp = clamped_sheet(23, 1e-2, 1e6)
    X, stats = hinge.solve_static(s, V)
    extra = [5, 11]
    slots = np.array([i for i in range(len(V) + 2) if i not in extra])
    V2 = np.full((len(V) + 2, 3), 4.0)
    V2[slots] = V
    with pytest.warns(hinge.MeshWarning, match="2 of the vertices are in no triangle .the first: vertex 5."):
        s2 = hinge.System(V2, slots[F])
    assert s2.unreferenced_vertices == extra and s2.coincident_vertices == []
    s2.add_bending(energy="discrete-shells", k=1e-2)
    s2.add_membrane(1e6, 0.3, 1e-3).add_gravity(0.5)
    s2.pin(slots[clamp])
    X2, stats2 = hinge.solve_static(s2, V2)
    assert stats2["newton_iterations"] == stats["newton_iterations"]
    assert stats2["factorizations"] == stats["factorizations"]
    assert np.abs(X2[slots] - X).max() <= 1e-12
    assert np.array_equal(X2[extra], V2[extra])
    assert list(s2.pinned) == sorted(slots[clamp])  # the user's pins, as given
    # Time stepping too.
    t = hinge.ImplicitEuler(s2, V2, 1 / 60, 0.5)
    for _ in range(3):
        X3, _ = t.step()
    assert np.isfinite(X3).all() and np.array_equal(X3[extra], V2[extra])


def test_derivatives_that_overflow_raise_naming_the_term_and_vertex():
    V, F = sheet(5, 4, 3, jitter=0.05)
    X = V.copy()
    X[:, 2] = 0.05 * np.sin(4 * V[:, 0]) * V[:, 1]
    ok = hinge.System(V, F).add_bending(energy="discrete-shells", k=0.01).add_membrane(1e305, 0.3, 5e-4)
    E, g, H = ok.evaluate(X)
    assert np.isfinite(H.data).all()
    s = hinge.System(V, F).add_bending(energy="discrete-shells", k=0.01).add_membrane(1e308, 0.3, 5e-4)
    with pytest.raises(ValueError, match=r"membrane, vertex \d+: its Hessian is not finite here"):
        s.evaluate(X)
    s.pin([0])
    with pytest.raises(ValueError, match=r"membrane, vertex \d+: its Hessian is not finite here"):
        hinge.solve_static(s, X)


def test_a_bending_model_whose_outputs_overflow_raises_instead_of_returning_inf():
    # Every hinge's psi, psi', psi'' is finite; their products with grad(theta), Hess(theta) and the sum over
    # hinges are not. Before, BendingModel.evaluate returned inf and NaN in its arrays.
    V, F = sheet(5, 4, 3, jitter=0.05)
    X = V.copy()
    X[:, 2] = 0.3 * np.sin(4 * V[:, 0]) * V[:, 1]
    big = hinge.BendingModel(V, F, psi="k * theta.powi(2)", k=1.5e307)
    with pytest.raises(ValueError, match=r"bending, vertex \d+: its gradient is not finite here"):
        big.evaluate(X)
    total = hinge.BendingModel(V, F, psi="k * 1e308", k=1.5)
    with pytest.raises(ValueError, match="bending: every hinge's energy is finite, their sum is not"):
        total.evaluate(X)
    # The same energies as a system's term: the system names the term (the check that was there before).
    for psi, k, what in (("k * theta.powi(2)", 1.5e307, "gradient"), ("k * 1e308", 1.5, "energy")):
        with pytest.raises(ValueError, match=f"its {what} is not finite"):
            hinge.System(V, F).add_bending(psi=psi, k=k).evaluate(X)
    E, g, H = hinge.BendingModel(V, F, psi="k * theta.powi(2)", k=1e300).evaluate(X)
    assert np.isfinite(E) and np.isfinite(g).all() and np.isfinite(H.data).all()


def test_a_mesh_split_along_a_seam_warns_and_is_cut_there():
    V, F = sheet(6, 5, 8, jitter=0.05)
    right = V[F].mean(axis=1)[:, 0] > 0.5
    seam = np.intersect1d(np.unique(F[~right]), np.unique(F[right]))
    copies = {int(v): len(V) + i for i, v in enumerate(seam)}
    V2 = np.vstack([V, V[seam]])
    F2 = F.copy()
    F2[right] = np.vectorize(lambda v: copies.get(int(v), v))(F[right])
    with pytest.warns(hinge.MeshWarning, match=f"{len(seam)} vertices lie exactly on another vertex"):
        s = hinge.System(V2, F2)
    assert s.coincident_vertices == sorted((copies[int(v)], int(v)) for v in seam)
    # Cut: the hinges whose two faces lie on different sides of the seam are gone, no others.
    side = {tuple(sorted(f)): r for f, r in zip(F.tolist(), right)}
    across = sum(side[tuple(sorted(h[:3]))] != side[tuple(sorted(h[1:]))] for h in hinge.hinges(V, F).tolist())
    assert across >= 4
    assert len(hinge.hinges(V2, F2)) == len(hinge.hinges(V, F)) - across
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert hinge.System(V, F).coincident_vertices == []


def test_implicit_euler_falls_and_comes_to_rest_on_a_plane():
    V, F = sheet(5, 5, 24, jitter=0.05)
    V = V * 0.2 + [0.0, 0.0, 0.05]
    s = hinge.System(V, F).add_bending(psi="k * a * (theta - theta_bar).powi(2)", k=1e-3)
    s.add_membrane(2e5, 0.3, 5e-4).add_gravity(0.1).add_plane((0, 0, 0), (0, 0, 1), 2e3, margin=1e-3)
    t = hinge.ImplicitEuler(s, V, 1 / 60, 0.1)
    for _ in range(40):
        X, stats = t.step()
        assert stats["max_final_gradient_norm"] <= 1e-8
    assert abs(t.time - 40 / 60) < 1e-12
    assert X[:, 2].min() > -2e-3 and X[:, 2].max() < 0.01  # on the plane
    assert np.abs(t.v).max() < 0.05


def _membrane_against_rigid_motion_and_differences(kind, rigid_energy, stretch):
    """A membrane of ``kind`` on an irregular sheet: zero energy and forces under a rigid motion (energy
    below ``rigid_energy``), and gradient and Hessian columns against central differences at a random
    deformation stretched by ``stretch``. Returns the sheet and the system."""
    V, F = sheet(5, 4, 31, jitter=0.05)
    s = hinge.System(V, F).add_membrane(1e3, 0.3, 1e-2, kind=kind)
    assert s.terms == [f"{kind}-membrane"]
    c, sn = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]])
    e0, g0 = s.evaluate(V @ R.T + [0.3, -0.2, 1.0], hessian=False)
    assert abs(e0) < rigid_energy and np.abs(g0).max() < 1e-12
    rng = np.random.default_rng(3)
    X = V * stretch + 0.02 * rng.standard_normal(V.shape)
    e, g, H = s.evaluate(X)
    H = H.toarray()
    assert e > 0
    h = 1e-6
    for i in rng.choice(X.size, 8, replace=False):
        Xp, Xm = X.copy(), X.copy()
        Xp.flat[i] += h
        Xm.flat[i] -= h
        (ep, gp), (em, gm) = s.evaluate(Xp, hessian=False), s.evaluate(Xm, hessian=False)
        assert abs((ep - em) / (2 * h) - g[i]) <= 1e-6 * max(1.0, abs(g[i]))
        assert np.abs((gp - gm) / (2 * h) - H[:, i]).max() <= 1e-5 * max(1.0, np.abs(H).max())
    return V, F, s


def test_corotational_membrane_matches_finite_differences_and_is_zero_under_rigid_motion():
    V, F, _ = _membrane_against_rigid_motion_and_differences("corotational", 1e-20, [1.1, 0.9, 1.0])
    with pytest.raises(ValueError, match="unknown `linear`"):
        hinge.System(V, F).add_membrane(1e3, 0.3, 1e-2, kind="linear")


def test_neo_hookean_membrane_matches_finite_differences_stvk_at_small_strain_and_its_continuation():
    V, F, s = _membrane_against_rigid_motion_and_differences("neo-hookean", 1e-14, [1.1, 0.8, 1.0])
    assert s.parameter("neo-hookean-membrane.young") == [1e3]
    # At a strain of 1e-4 it is the StVK membrane to first order.
    Y = V * [1.0 + 1e-4, 1.0 - 5e-5, 1.0]
    stvk = hinge.System(V, F).add_membrane(1e3, 0.3, 1e-2)
    e_nh, e_sv = s.evaluate(Y, hessian=False)[0], stvk.evaluate(Y, hessian=False)[0]
    assert abs(e_nh / e_sv - 1.0) < 1e-3
    # A stiff strip: the continuation scales its `young` and reaches the same equilibrium.
    W, G = sheet(24, 3, 41, jitter=0.05)
    W = W * [0.3, 0.3, 1.0]
    strip = hinge.System(W, G).add_bending(energy="discrete-shells", k=1e-3)
    strip.add_membrane(1e10, 0.3, 1e-4, kind="neo-hookean").add_gravity(0.5)
    strip.pin(np.flatnonzero(W[:, 0] <= W[:, 0].min() + 1e-9 + 0.3 / 12))
    ends = {}
    for on in (True, False):
        Xs, st = hinge.solve_static(strip, W, gradient_tolerance=1e-9, membrane_continuation=on)
        assert st["final_gradient_norm"] <= 1e-9
        ends[on] = (Xs, st["newton_iterations"])
    assert np.abs(ends[True][0] - ends[False][0]).max() < 1e-8
    print("neo-Hookean strip, Newton iterations with / without the continuation:", ends[True][1], ends[False][1])
    with pytest.raises(ValueError, match="stvk, corotational, neo-hookean"):
        hinge.System(V, F).add_membrane(1e3, 0.3, 1e-2, kind="linear")


def test_system_bad_input_raises_value_error():
    V, F = sheet(3, 3, 25)
    s = hinge.System(V, F)
    with pytest.raises(ValueError, match="no energies"):
        s.evaluate(V)
    for call, msg in [
        (lambda: s.add_membrane(-1.0, 0.3, 1e-3), "membrane"),
        (lambda: s.add_sphere((0, 0), 1.0, 1.0), "3 components"),
        (lambda: s.add_bending(energy="nope"), "unknown energy"),
        (lambda: s.pin([999]), "999"),
        (lambda: s.pin([-1]), "negative"),
        (lambda: hinge.solve_static(s.add_gravity(0.1), V[:-1]), "shape"),
        (lambda: hinge.ImplicitEuler(s, V, 1 / 60, -1.0), "density"),
        (lambda: hinge.ImplicitEuler(s, V, 0.0, 0.1), "dt"),
    ]:
        with pytest.raises(ValueError, match=msg):
            call()


def test_run_scene_gives_frames_like_the_cli(tmp_path):
    V, F, X, summary = hinge.run_scene("drape", frames=8)
    assert X.shape == (8, len(V), 3) and F.shape[1] == 3
    assert summary["frames"] == 8 and summary["newton_iterations"] > 0
    assert summary["max_final_gradient_norm"] <= 1e-6
    assert (X[-1, :, 2] < V[:, 2]).all()  # it fell
    toml = tmp_path / "bad.toml"
    toml.write_text('name = "x"\\nframes = 1\\ndt = -1.0\\n')
    with pytest.raises(ValueError, match="dt"):
        hinge.run_scene(str(toml))
    with pytest.raises(ValueError, match="unknown scene"):
        hinge.run_scene("nope")
    with pytest.raises(ValueError, match="frames"):
        hinge.run_scene("drape", frames=0)


# `shell-drop` at two subdivisions (162 vertices): a closed shell through its collapse on the plane.
SMALL_SHELL_DROP = """
name = "shell-drop-small"
frames = 30
dt = 0.016666666666666666
gravity = [0.0, 0.0, -9.81]

[mesh]
shape = "icosphere"
subdivisions = 2
radius = 0.5
origin = [0.0, 0.0, 0.55]

[material]
young = 2e5
poisson = 0.3
thickness = 5e-4
density = 0.1

[bending]
energy = "tan-bending"
damping = 0.0

[[obstacles]]
kind = "plane"
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]
stiffness = 2e3
margin = 0.005

[solver]
backend = "faer-llt"
max_iterations = 300
gradient_tolerance = 1e-6
"""


def check_trace(scene, frames):
    """A traced run against a plain one: the same run, a trace row per iteration of every frame."""
    _, _, X, plain = hinge.run_scene(scene, frames=frames)
    _, _, Xt, s = hinge.run_scene(scene, frames=frames, trace=True)
    assert "trace" not in plain
    # Tracing changes nothing of the run.
    assert np.array_equal(X, Xt)
    for key in ["newton_iterations", "factorizations", "line_search_steps", "max_final_gradient_norm",
                "accelerated_iterations", "definite_iterations"]:
        assert s[key] == plain[key], key
    # Geodesic acceleration (on by default) corrects some of the steps, never more than there are.
    assert 0 < s["accelerated_iterations"] <= s["newton_iterations"]
    its, facts, subs = s["frame_newton_iterations"], s["frame_factorizations"], s["frame_substeps"]
    assert len(its) == len(facts) == len(subs) == frames
    assert sum(its) == s["newton_iterations"] and sum(facts) == s["factorizations"]
    assert sum(subs) == s["substeps"] and all(f >= i for i, f in zip(its, facts))
    t = s["trace"]
    assert t.shape == (s["newton_iterations"], 11)
    # The flags are 0 or 1, and each column adds up to the summary's count.
    assert set(np.unique(t[:, 7:9])) <= {0.0, 1.0}
    assert t[:, 7].sum() == s["definite_iterations"]
    assert t[:, 8].sum() == s["accelerated_iterations"]
    for k in range(frames):
        rows = t[t[:, 0] == k]
        assert len(rows) == its[k], k
        # One solve per frame here (no substeps): iterations 1, 2, …, and the last at the tolerance.
        assert list(rows[:, 1]) == list(range(1, its[k] + 1)), k
        assert rows[-1, 3] <= 1e-6, k
    # Where the residual is: a vertex (a row of V) whose force is at most ‖∇F‖ and at least ‖∇F‖ / √n.
    n = X.shape[1]
    assert (t[:, 9] == np.round(t[:, 9])).all() and (t[:, 9] >= 0).all() and (t[:, 9] < n).all()
    assert (t[:, 10] <= t[:, 3]).all() and (t[:, 3] <= t[:, 10] * np.sqrt(n) * (1 + 1e-12)).all()
    # Extrapolated steps are in it.
    assert (t[:, 5] > 1).any()
    return t


def test_run_scene_counts_per_frame_and_traces_every_iteration(tmp_path):
    # A sheet over a sphere, and a closed shell collapsing on a plane: shifted steps, none definite.
    shell = tmp_path / "shell.toml"
    shell.write_text(SMALL_SHELL_DROP)
    for t in (check_trace("drape", 22), check_trace(str(shell), 30)):
        assert (t[:, 6] > 0).any() and not t[:, 7].any()
    # Project on demand marks its definite steps, and they are unshifted.
    pod = tmp_path / "pod.toml"
    pod.write_text(SMALL_SHELL_DROP.replace("[solver]", '[solver]\nglobalization = "project-on-demand"'))
    t = check_trace(str(pod), 30)
    assert t[:, 7].any() and (t[t[:, 7] == 1, 6] == 0).all()
    with pytest.raises(ValueError, match="trace"):
        hinge.run_scene("drape", frames=1, trace="yes")


def cantilever(k=1e-2, young=1e6):
    V, F = sheet(8, 3, 23, jitter=0.05)
    V = V * [0.3, 0.3, 1.0]
    s = hinge.System(V, F).add_bending(psi="k * a * (theta - theta_bar).powi(2)", k=k)
    s.add_membrane(young, 0.3, 1e-3).add_gravity(0.5)
    clamp = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 8)
    s.pin(clamp)
    return V, F, s


def test_parameters_are_listed_read_and_set():
    V, F, s = cantilever()
    names = dict(s.parameters())
    bending = [n for n in names if n.endswith(".k")][0]
    assert names[bending] == 1 and "membrane.young" in names and names["gravity.g"] == 3
    rest_angles = bending[: -len(".k")] + ".theta_bar"
    assert names[rest_angles] > 10
    assert s.parameter(bending)[0] == pytest.approx(1e-2)
    s.set_parameter(bending, 2e-2)
    assert s.parameter(bending)[0] == 2e-2
    with pytest.raises(ValueError, match="unknown"):
        s.parameter("membrane.nope")
    assert names["membrane.poisson"] == 1
    with pytest.raises(ValueError, match="poisson"):
        s.set_parameter("membrane.poisson", 0.5)
    with pytest.raises(ValueError, match="young"):
        s.set_parameter("membrane.young", -1.0)
    with pytest.raises(ValueError, match="values"):
        s.set_parameter("gravity.g", [1.0, 2.0])


def test_repeated_terms_are_numbered_in_parameter_names():
    V, F = sheet(5, 4, 31)
    X = V + np.stack([0 * V[:, 0], 0 * V[:, 0], 0.2 * np.sin(2 * V[:, 0])], axis=1)
    psi = "c * a * (theta - theta_bar).powi(2)"
    s = hinge.System(V, F).add_bending(psi=psi, c=1.0).add_bending(psi=psi, c=3.0)
    assert s.terms == ["custom", "custom#2"]
    names = dict(s.parameters())
    assert "custom.c" in names and "custom#2.c" in names
    s.set_parameter("custom#2.c", 5.0)
    assert s.parameter("custom.c")[0] == 1.0 and s.parameter("custom#2.c")[0] == 5.0
    one = lambda c: hinge.System(V, F).add_bending(psi=psi, c=c).evaluate(X)[0]
    assert s.evaluate(X)[0] == pytest.approx(one(1.0) + one(5.0), rel=1e-13)
    with pytest.raises(ValueError, match="unknown"):
        s.parameter("custom#3.c")


def test_adjoint_gradient_matches_finite_differences_of_resolved_equilibria():
    V, F, s = cantilever()
    bending = [n for n, _ in s.parameters() if n.endswith(".k")][0]
    X, _ = hinge.solve_static(s, V, gradient_tolerance=1e-11)
    T = X + np.stack([0 * V[:, 0], 0.01 * V[:, 0], -0.02 * V[:, 0] ** 2], axis=1)
    loss = lambda Y: float(((Y - T) ** 2).sum())
    names = [bending, "membrane.young", "membrane.poisson", "gravity.g"]
    d = hinge.adjoint_gradient(s, X, 2 * (X - T), names)
    steps = [(bending, 0, 1e-5), ("membrane.young", 0, 1e3), ("membrane.poisson", 0, 1e-3), ("gravity.g", 2, 1e-2)]
    for name, i, h in steps:
        base = s.parameter(name)
        vals = []
        for t in (h, -h, 2 * h, -2 * h):
            p = base.copy()
            p[i] += t
            s.set_parameter(name, p)
            Y, _ = hinge.solve_static(s, X, gradient_tolerance=1e-11)
            vals.append(loss(Y))
        s.set_parameter(name, base)
        d1, d2 = (vals[0] - vals[1]) / (2 * h), (vals[2] - vals[3]) / (4 * h)
        fd = (4 * d1 - d2) / 3
        assert abs(fd - d[name][i]) <= 1e-5 * abs(fd), (name, fd, d[name][i])


def test_fit_recovers_the_bending_stiffness():
    V, F, s = cantilever(k=1e-2)
    bending = [n for n, _ in s.parameters() if n.endswith(".k")][0]
    T, _ = hinge.solve_static(s, V, gradient_tolerance=1e-11)
    s.set_parameter(bending, 3e-2)
    X, info = hinge.fit(s, V, T, [bending])
    assert info["fitted"][bending] == pytest.approx(1e-2, rel=1e-4)
    assert s.parameter(bending)[0] == info["fitted"][bending]
    assert info["equilibria"] <= 25 and np.abs(X - T).max() < 1e-6
    assert info["fields"] == {}  # a scalar is not a field
    with pytest.raises(ValueError, match="twice"):
        hinge.fit(s, V, T, [bending, bending])
    with pytest.raises(ValueError, match="unknown"):
        hinge.fit(s, V, T, ["nothing.here"])


def test_fit_reports_how_many_rest_angles_a_static_shape_determines():
    # The clamped irregular sheet's rest angles: hinges with all four vertices pinned move nothing (counted
    # here from F and the clamp); the others' count of determined combinations (eigenvalues of the
    # correlation matrix of their equilibrium sensitivities at or above 1e-4) against the same count from
    # central differences of re-solved equilibria. Near flat, a rest angle moves the sheet through the
    # out-of-plane dofs only, so the count is near the free vertices' (31; this sagging soft sheet: 32).
    V, F, s = cantilever()
    rest_angles = [n for n, _ in s.parameters() if n.endswith(".theta_bar")][0]
    T, _ = hinge.solve_static(s, V, gradient_tolerance=1e-11)
    clamp = set(np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 8).tolist())
    faces_of = {}
    for k, f in enumerate(F):
        for i in range(3):
            a, b = sorted((int(f[i]), int(f[(i + 1) % 3])))
            faces_of.setdefault((a, b), []).append(k)
    hinges = [fs for fs in faces_of.values() if len(fs) == 2]
    inside = sum(all(int(v) in clamp for k in fs for v in F[k]) for fs in hinges)
    X, info = hinge.fit(s, V, T, [rest_angles], max_iterations=0)
    field = info["fields"][rest_angles]
    h, columns = 1e-4, []
    for i in range(len(hinges)):
        moved = []
        for delta in (h, -h):
            angles = np.zeros(len(hinges))
            angles[i] = delta
            s.set_parameter(rest_angles, angles)
            moved.append(hinge.solve_static(s, T, gradient_tolerance=1e-12)[0])
        columns.append(((moved[0] - moved[1]) / (2 * h)).ravel())
    s.set_parameter(rest_angles, np.zeros(len(hinges)))
    C = np.array(columns).T
    norms = np.linalg.norm(C, axis=0)
    kept = norms > 1e-12 * norms.max()
    U = C[:, kept] / norms[kept]
    determined = int((np.linalg.eigvalsh(U.T @ U) >= 1e-4).sum())
    print("rest angles:", field, "hinges inside the clamp:", inside, "free vertices:", len(V) - len(clamp),
          "central differences:", determined, "determined,", int((~kept).sum()), "without effect")
    assert field["entries"] == len(hinges)
    assert field["without_effect"] == inside == int((~kept).sum()) > 0
    assert field["determined"] == determined
    assert abs(determined - (len(V) - len(clamp))) <= 1


def test_fit_starts_from_the_equilibrium_the_membrane_continuation_reaches():
    # A 0.1 mm strip of Y = 1e10 Pa sagging under its weight: from flat its equilibrium takes hundreds of
    # Newton iterations without the membrane continuation. Its bending stiffness is fitted back from 3x.
    V, F = sheet(24, 3, 41, jitter=0.05)
    V = V * [0.3, 0.3, 1.0]
    s = hinge.System(V, F).add_bending(energy="discrete-shells", k=1e-3)
    s.add_membrane(1e10, 0.3, 1e-4).add_gravity(0.5)
    clamp = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 0.3 / 12)
    s.pin(clamp)
    bending = [n for n, _ in s.parameters() if n.endswith(".k")][0]
    T, st = hinge.solve_static(s, V, gradient_tolerance=1e-10)
    assert V[:, 2].min() - T[:, 2].min() > 0.05
    counts = {}
    for on in (True, False):
        s.set_parameter(bending, 3e-3)
        X, info = hinge.fit(s, V, T, [bending], membrane_continuation=on)
        assert info["fitted"][bending] == pytest.approx(1e-3, rel=1e-4)
        assert np.abs(X - T).max() < 1e-6
        counts[on] = info["newton_iterations"]
    # The fit's own solves (3x stiffer to the target's stiffness, from one equilibrium to the next) cost the
    # same either way; the first equilibrium is what the continuation saves (here 197 against 302 in all).
    print("Newton iterations of the fit with / without the continuation:", counts)
    assert counts[True] < counts[False], counts
    with pytest.raises(ValueError):
        hinge.fit(s, V, T, [bending], membrane_continuation="yes")


STRIP = """
name = "strip"
frames = 1
dt = 0.01

[mesh]
cells = [24, 2]
size = [0.2, 0.02]

[material]
young = YOUNG
poisson = 0.3
thickness = 5e-4
density = 0.5

[bending]
energy = "tan-bending"
calibration = "plate"

[pins]
clamp_columns = 2

[solver]
gradient_tolerance = 1e-9
"""


def test_fit_scene_recovers_young_s_modulus(tmp_path):
    good, wrong = tmp_path / "good.toml", tmp_path / "wrong.toml"
    good.write_text(STRIP.replace("YOUNG", "2e8"))
    wrong.write_text(STRIP.replace("YOUNG", "6e8"))
    V, F, _, _ = hinge.run_scene(str(good), frames=1)
    # No iterations: the equilibrium at the scene's own values, the target.
    T, info0 = hinge.fit_scene(str(good), V, ["material.young"], max_iterations=0)
    assert info0["iterations"] == 0 and info0["fitted"]["material.young"] == 2e8
    assert T[:, 2].min() < -1e-3  # it sagged
    X, info = hinge.fit_scene(str(wrong), T, ["material.young"])
    assert info["fitted"]["material.young"] == pytest.approx(2e8, rel=1e-4)
    assert info["equilibria"] <= 25 and np.abs(X - T).max() < 1e-6
    with pytest.raises(ValueError, match="unknown key"):
        hinge.fit_scene(str(wrong), T, ["material.nope"])
    with pytest.raises(ValueError, match="not separately identifiable"):
        hinge.fit_scene(str(wrong), T, ["material.young", "material.density"])
    with pytest.raises(ValueError, match="shape"):
        hinge.fit_scene(str(wrong), T[:-1], ["material.young"])
    with pytest.raises(ValueError, match="mesh file path"):
        hinge.fit_scene(str(wrong), 3, ["material.young"])



def test_poisson_s_ratio_is_fitted_inside_its_interval(tmp_path):
    # A hammock: an irregular renumbered sheet pinned along two opposite edges sags under its weight, held by
    # its membrane, whose Poisson ratio (truth 0.3) sets how it contracts across. Fitted back from 0.1 and
    # from just below the upper bound 0.5, every trial inside (-1, 0.5) (a value outside would be refused by
    # the membrane at the first trial, not halved).
    V, F = sheet(8, 8, 7, jitter=0.1)
    V = V * [0.3, 0.3, 1.0]
    s = hinge.System(V, F).add_bending(energy="discrete-shells", k=1e-6)
    s.add_membrane(1e5, 0.3, 1e-3).add_gravity(0.5)
    s.pin(np.flatnonzero((V[:, 0] <= V[:, 0].min() + 1e-9) | (V[:, 0] >= V[:, 0].max() - 1e-9)))
    T, _ = hinge.solve_static(s, V, gradient_tolerance=1e-11)
    assert T[:, 2].min() < -1e-3
    for start in (0.1, 0.499):
        s.set_parameter("membrane.poisson", start)
        X, info = hinge.fit(s, V, T, ["membrane.poisson"], max_iterations=100)
        print("membrane.poisson from", start, "->", info["fitted"]["membrane.poisson"], info["equilibria"], "equilibria")
        assert info["fitted"]["membrane.poisson"] == pytest.approx(0.3, abs=1e-4)
        assert s.parameter("membrane.poisson")[0] == info["fitted"]["membrane.poisson"]
        assert np.abs(X - T).max() < 1e-6
    # The scene key: the strip's plate stiffness depends on nu through 1/(1 - nu^2), its membrane takes nu.
    good, wrong = tmp_path / "good.toml", tmp_path / "wrong.toml"
    good.write_text(STRIP.replace("YOUNG", "2e8"))
    wrong.write_text(STRIP.replace("YOUNG", "2e8").replace("poisson = 0.3", "poisson = 0.15"))
    V, F, _, _ = hinge.run_scene(str(good), frames=1)
    T, _ = hinge.fit_scene(str(good), V, ["material.poisson"], max_iterations=0)
    X, info = hinge.fit_scene(str(wrong), T, ["material.poisson"])
    assert info["fitted"]["material.poisson"] == pytest.approx(0.3, abs=1e-4)
    with pytest.raises(ValueError, match="not separately identifiable"):
        hinge.fit_scene(str(wrong), T, ["material.poisson", "material.young"])


def test_smoothed_contact_is_c2_matches_finite_differences_and_rejects_bad_lengths():
    V, F = sheet(4, 4, 12, jitter=0.05)
    delta, eps, kappa = 0.05, 0.03, 300.0
    # Vertices at depths past ε, inside (0, ε) and outside the margin of the plane z = 0.
    X = V.copy()
    X[:, 2] = np.linspace(-0.02, 0.08, len(V))
    s = hinge.System(V, F).add_plane((0, 0, 0), (0, 0, 1), kappa, margin=delta, smoothing=eps)
    q = hinge.System(V, F).add_plane((0, 0, 0), (0, 0, 1), kappa, margin=delta)
    z = hinge.System(V, F).add_plane((0, 0, 0), (0, 0, 1), kappa, margin=delta, smoothing=0.0)
    e, g, H = s.evaluate(X)
    # The penalty written out here, per vertex of penetration p = δ − z.
    p = delta - X[:, 2]
    phi = np.where(p >= eps, 0.5 * kappa * (p * p - eps * p + eps * eps / 3),
                   np.where(p > 0, kappa * p**3 / (6 * eps), 0.0))
    assert (p > eps).any() and ((p > 0) & (p < eps)).any() and (p < 0).any()
    assert abs(e - phi.sum()) <= 1e-12 * phi.sum()
    h = 1e-7
    for i in range(len(V)):
        Xp, Xm = X.copy(), X.copy()
        Xp[i, 2] += h
        Xm[i, 2] -= h
        ep, gp = s.evaluate(Xp, hessian=False)
        em, gm = s.evaluate(Xm, hessian=False)
        assert abs((ep - em) / (2 * h) - g[3 * i + 2]) <= 1e-6 * kappa * delta
        assert abs((gp[3 * i + 2] - gm[3 * i + 2]) / (2 * h) - H[3 * i + 2, 3 * i + 2]) <= 1e-5 * kappa
    # Smoothing 0 is the quadratic penalty, bitwise; it differs from the smoothed one.
    eq, gq, Hq = q.evaluate(X)
    ez, gz, Hz = z.evaluate(X)
    assert eq == ez and np.array_equal(gq, gz) and (Hq != Hz).nnz == 0
    assert e < eq
    for bad in (-1e-3, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="smoothing"):
            hinge.System(V, F).add_sphere((0, 0, -1), 0.9, kappa, margin=delta, smoothing=bad)


def test_barrier_contact_matches_its_formula_keeps_a_fast_sheet_off_the_plane_and_names_a_vertex_inside():
    V, F = sheet(5, 5, 31, jitter=0.05)
    delta, kappa = 0.05, 300.0
    X = V.copy()
    X[:, 2] = np.linspace(0.002, 0.09, len(V))  # inside the barrier's reach and beyond it
    s = hinge.System(V, F).add_plane((0, 0, 0), (0, 0, 1), kappa, margin=delta, barrier=True)
    e, g, H = s.evaluate(X)
    d = X[:, 2]
    b = np.where(d < delta, -kappa * (d - delta) ** 2 * np.log(np.minimum(d, delta) / delta), 0.0)
    assert (d < delta).any() and (d > delta).any()
    assert abs(e - b.sum()) <= 1e-12 * b.sum()
    h = 1e-8
    for i in range(len(V)):
        Xp, Xm = X.copy(), X.copy()
        Xp[i, 2] += h
        Xm[i, 2] -= h
        ep, gp = s.evaluate(Xp, hessian=False)
        em, gm = s.evaluate(Xm, hessian=False)
        assert abs((ep - em) / (2 * h) - g[3 * i + 2]) <= 1e-5 * max(1.0, abs(g[3 * i + 2]))
        assert abs((gp[3 * i + 2] - gm[3 * i + 2]) / (2 * h) - H[3 * i + 2, 3 * i + 2]) <= 1e-4 * max(
            1.0, abs(H[3 * i + 2, 3 * i + 2]))
    # A vertex on the plane: ValueError naming it.
    X[7, 2] = -1e-3
    with pytest.raises(ValueError, match="vertex 7"):
        s.evaluate(X)
    with pytest.raises(ValueError, match="barrier"):
        hinge.System(V, F).add_plane((0, 0, 0), (0, 0, 1), kappa, margin=0.0, barrier=True)
    # A sheet thrown at the plane at 20 m/s (33 cm per step, from 5 cm above): no vertex ever reaches it,
    # and it comes to rest within the barrier's reach.
    W = V * 0.2 + [0.0, 0.0, 0.05]
    m = hinge.System(W, F).add_membrane(2e5, 0.3, 5e-4).add_gravity(0.1)
    m.add_plane((0, 0, 0), (0, 0, 1), 50.0, margin=5e-3, barrier=True)
    t = hinge.ImplicitEuler(m, W, 1 / 60, 0.1, V0=np.tile([0.0, 0.0, -20.0], (len(W), 1)))
    low = np.inf
    for _ in range(30):
        Y, stats = t.step()
        low = min(low, Y[:, 2].min())
    assert low > 0.0 and Y[:, 2].max() < 5e-3, (low, Y[:, 2].max())


def test_mesh_files_read_and_write_in_every_format(tmp_path):
    V, F = sheet(5, 4, 13, jitter=0.05)
    V = V.astype(np.float32).astype(np.float64)  # what STL stores
    for ext in ["obj", "off", "ply", "stl"]:
        path = tmp_path / f"m.{ext}"
        hinge.write_mesh(path, V, F)
        V2, F2 = hinge.read_mesh(path)
        assert V2.dtype == np.float64 and F2.dtype == np.int64
        if ext == "stl":
            # Welded in order of first appearance: the same triangles' positions.
            assert np.array_equal(V2[F2], V[F]) and len(V2) == len(V)
        else:
            assert np.array_equal(V2, V) and np.array_equal(F2, F)
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n# faces\nf 1 2 3\nf 2 4 9\n")
    with pytest.raises(ValueError, match=r"face 2 \(line 7\) names vertex 9"):
        hinge.read_mesh(bad)
    with pytest.raises(ValueError, match="unknown mesh file extension"):
        hinge.read_mesh(tmp_path / "m.stp")


def test_ctrl_c_ends_long_calls_with_keyboard_interrupt_and_the_state_kept():
    import _thread
    import signal

    def interrupted(call, after):
        timer = threading.Timer(after, _thread.interrupt_main)
        # Python's own Ctrl-C handler: a process started with SIGINT ignored (a background job of a
        # script, as CI may run this) has none, and interrupt_main then does nothing.
        handler = signal.signal(signal.SIGINT, signal.default_int_handler)
        timer.start()
        t = time.monotonic()
        try:
            with pytest.raises(KeyboardInterrupt):
                call()
        finally:
            timer.cancel()
            timer.join()
            signal.signal(signal.SIGINT, handler)
        # Before, the call ran to its end (minutes); now it ends within a Newton iteration.
        return time.monotonic() - t

    # A whole scene: shell-drop takes minutes.
    assert interrupted(lambda: hinge.run_scene("shell-drop"), 1.0) < 30
    # A static solve of a stiff thin sheet through the membrane continuation (6 561 vertices; uninterrupted
    # it spends its 500 iterations, two minutes on this VM): interrupted, it leaves the membrane's Young's
    # modulus as it was.
    V, F = sheet(80, 80, 31, jitter=0.05)
    s = hinge.System(V, F).add_bending(psi="k * a * (theta - theta_bar).powi(2)", k=1e-4)
    s.add_membrane(1e10, 0.3, 1e-4).add_gravity(0.1)
    s.pin(np.flatnonzero(V[:, 0] <= V[:, 0].min() + 1e-9 + 1 / 80))
    young = s.parameter("membrane.young")
    assert interrupted(lambda: hinge.solve_static(s, V), 0.5) < 30
    assert np.array_equal(s.parameter("membrane.young"), young)


def test_rest_stiffening_of_a_folded_crease():

    # Two triangles on the hinge (0,0,0)-(1,0,0), the wing vertex 3 turned by `fold` from flat.
    for fold in (0.0, 1.0, 2.5, 3.09, np.pi - 1e-4):
        V = np.array([[0.45, 0.8, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0],
                      [0.6, -0.9 * np.cos(fold), -0.9 * np.sin(fold)]])
        F = np.array([[0, 1, 2], [3, 2, 1]])
        closed = np.cos(fold / 2) ** -4
        stiff = closed >= 1e6
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            tan = hinge.BendingModel(V, F, energy="tan-bending", k=0.3)
            psi = hinge.BendingModel(
                V, F, psi="k * a * (2.0 * (theta / 2.0).tan() - 2.0 * (theta_bar / 2.0).tan()).powi(2)", k=0.3
            )
            s = hinge.System(V, F).add_bending(energy="tan-bending", k=0.3)
            shells = hinge.BendingModel(V, F, energy="discrete-shells", k=0.3)
            hinge.System(V, F).add_bending(energy="discrete-shells", k=0.3)
            linear = hinge.BendingModel(V, F, psi="k * a * theta", k=0.3)
        # A warning from each tan model and the System's tan term when the crease is stiff, else none.
        assert len(caught) == (3 if stiff else 0), (fold, [str(w.message) for w in caught])
        for w in caught:
            assert w.category is hinge.MeshWarning
            assert "1 rest hinge is at least 1e6 times stiffer than flat" in str(w.message)
            assert "between vertices 1 and 2" in str(w.message), str(w.message)
        t = tan.rest_stiffening()
        assert t.shape == (1,) and abs(t[0] - closed) <= 1e-9 * closed, (fold, t, closed)
        assert abs(psi.rest_stiffening()[0] - closed) <= 1e-9 * closed
        assert shells.rest_stiffening()[0] == 1.0
        # psi'' = 0 everywhere: no flat reference.
        assert np.isnan(linear.rest_stiffening()[0])
        assert s.terms == ["tan-bending"]


def test_run_scene_warns_of_a_stiff_rest_crease_as_a_mesh_warning(tmp_path, capfd):
    # The hinge's edge is the file's vertices 2 and 5 (from 0: 1 and 4); the wing vertex 3 is folded to
    # 1e-4 rad of flat (tan bending 1/cos^4 = 1.6e17 times stiffer there), or not folded at all.
    for fold, stiff in ((np.pi - 1e-4, True), (0.5, False)):
        obj = tmp_path / "pair.obj"
        obj.write_text(
            "# folded pair\nv 0.4 -0.9 0.5\nv 1 0 0.5\n"
            f"v 0.5 {0.8 * np.cos(fold)} {0.5 + 0.8 * np.sin(fold)}\n"
            "v 2 0 0.5\nv 0 0 0.5\nf 1 5 2\nf 3 2 5\nf 4 2 3\n"
        )
        scene = tmp_path / "pair.toml"
        scene.write_text(
            'name = "pair"\nframes = 2\ndt = 0.0166\ngravity = [0.0, 0.0, -9.81]\n[mesh]\nobj = "pair.obj"\n'
            "[material]\nyoung = 2e5\npoisson = 0.3\nthickness = 5e-4\ndensity = 0.1\n"
            '[bending]\nenergy = "tan-bending"\n'
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            _, _, X, summary = hinge.run_scene(str(scene))
        assert X.shape == (2, 5, 3) and summary["frames"] == 2
        messages = [str(w.message) for w in caught]
        assert len(caught) == (1 if stiff else 0), messages
        for w in caught:
            assert w.category is hinge.MeshWarning
            assert w.filename == __file__, w.filename
            assert "1 rest hinge is at least 1e6 times stiffer than flat" in str(w.message)
            assert "between vertices 1 and 4" in str(w.message) and "(vertices from 0)" in str(w.message)
        # Nothing is printed on the process's stderr: the warning is Python's to show or filter.
        assert capfd.readouterr().err == ""
    # Warnings as errors: the warning raises (as any Python warning would), no frames are returned.
    obj.write_text(obj.read_text().replace(f"{0.8 * np.cos(0.5)}", f"{0.8 * np.cos(np.pi - 1e-4)}")
                   .replace(f"{0.5 + 0.8 * np.sin(0.5)}", f"{0.5 + 0.8 * np.sin(np.pi - 1e-4)}"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", hinge.MeshWarning)
        with pytest.raises(hinge.MeshWarning):
            hinge.run_scene(str(scene))


def _system():
    V, F = sheet(3, 3, 40)
    s = hinge.System(V, F).add_bending(energy="tan-bending", k=1e-3).add_gravity(density=0.1)
    return V, s.pin([0, 1])


@pytest.mark.parametrize(
    "call, message",
    [
        # Wrong types and out-of-range whole numbers: ValueError naming the argument, not TypeError or
        # OverflowError from a conversion (and not a silent bool(): barrier="no" was True).
        (lambda V, s: s.add_sphere((0, 0, -1), None, 1.0), "radius must be a number"),
        (lambda V, s: s.add_sphere((0, 0, -1), 0.5, [1.0, 2.0]), "stiffness must be a number"),
        (lambda V, s: s.add_sphere((0, 0), 0.5, 1.0), "center must have 3 components"),
        (lambda V, s: s.add_sphere(None, 0.5, 1.0), "center must have 3 components"),
        (lambda V, s: s.add_sphere((0, 0, -1), 0.5, 1.0, barrier="no"), "barrier must be True or False"),
        (lambda V, s: s.add_plane((0, 0, 0), (0, 0, {}), 1.0), r"normal\[2\] must be a number"),
        (lambda V, s: s.add_membrane(True, 0.3, 1e-3), "young must be a number"),
        (lambda V, s: s.add_membrane(1e5, 0.3, 1e-3, kind=1), "kind must be a string"),
        (lambda V, s: s.add_springs(1.0, compressive="yes"), "compressive must be True or False"),
        (lambda V, s: s.add_gravity(0.1, g=(0, 0)), "g must have 3 components"),
        (lambda V, s: s.add_drag(np.zeros(3), 1.0), "density must be a number"),
        (lambda V, s: s.evaluate(V, hessian="no"), "hessian must be True or False"),
        (lambda V, s: s.set_parameter("gravity.g", {}), "values must be a number"),
        (lambda V, s: s.parameter(3), "name must be a string"),
        (lambda V, s: hinge.solve_static(s, V, max_iterations=-1), "max_iterations must be at least 0"),
        (lambda V, s: hinge.solve_static(s, V, max_iterations=float("inf")), "max_iterations must be a whole"),
        (lambda V, s: hinge.solve_static(s, V, max_iterations=2**70), "below 2"),
        (lambda V, s: hinge.solve_static(s, V, gradient_tolerance=None), "gradient_tolerance must be a number"),
        # Newton's budget is bounded as in scene files (a million iterations per solve).
        (lambda V, s: hinge.solve_static(s, V, max_iterations=0), "max_iterations must be from 1 to 1 000 000, got 0"),
        (lambda V, s: hinge.solve_static(s, V, max_iterations=1_000_001), "from 1 to 1 000 000, got 1000001"),
        (lambda V, s: hinge.ImplicitEuler(s, V, dt=0.01, density=0.1, max_iterations=10**9), "from 1 to 1 000 000"),
        (lambda V, s: hinge.solve_static(s, V, gradient_tolerance=-1e-9), "gradient_tolerance must be finite and ≥ 0"),
        (lambda V, s: hinge.ImplicitEuler(s, V, dt=0.01, density=0.1, gradient_tolerance=float("inf")), "got inf"),
        # The fits' L-BFGS budget too (0 evaluates the start only).
        (lambda V, s: hinge.fit(s, V, V, ["tan-bending.k"], max_iterations=1_000_001), "max_iterations must be from 0 to 1 000 000, got 1000001"),
        (lambda V, s: hinge.fit_scene("beam1", V, "material.young", max_iterations=10**7), "from 0 to 1 000 000"),
        (lambda V, s: hinge.fit_scene("beam1", V, "material.young", smoothness=float("nan")), "smoothness must be non-negative"),
        (lambda V, s: hinge.ImplicitEuler(s, V, dt=[0.01], density=0.1), "dt must be a number"),
        (lambda V, s: hinge.ImplicitEuler(s, V, dt=0.01, density=0.1, max_iterations=-3), "at least 0"),
        (lambda V, s: hinge.adjoint_gradient(s, V, np.zeros_like(V), None), "parameters must be a string"),
        (lambda V, s: hinge.fit(s, V, V, [1]), r"parameters\[0\] must be a string"),
        (lambda V, s: hinge.fit_scene("beam1", {}, "material.young"), "target must be"),
        (lambda V, s: hinge.fit_scene("beam1", "x.obj", 7), "keys must be a string"),
        (lambda V, s: hinge.run_scene("beam1", frames=-5), "frames must be at least 0"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]]), threads=-2**63), "threads must be at least 1"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]]), method=3), "method must be a string"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]]), energy=("tan-bending",)), "energy must be"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]])).set_step(V, None), "dt must be a number"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]])).set_rest_angles({}), "theta_bar must be"),
        # Rest angles are angles in radians, in [-pi, pi]: degrees are refused.
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 4], [4, 1, 5]])).set_rest_angles(np.array([90.0])),
         r"value of hinge 0 is 90 rad, outside \[−π, π\]"),
        (lambda V, s: hinge.BendingModel(V, np.array([[0, 1, 2]])).evaluate_into(V, None), "g_out must be"),
    ],
)
def test_arguments_of_the_wrong_kind_raise_value_error(call, message):
    V, s = _system()
    with pytest.raises(ValueError, match=message):
        call(V, s)


def test_numbers_of_any_numeric_kind_are_accepted():
    V, s = _system()
    s.add_sphere(np.array([0.0, 0.0, -1.0]), np.float64(0.5), np.array(2.0), margin=0)
    s.add_plane([0, 0, -2], (0, 0, 1), 1)
    V2, plain = _system()
    plain.add_sphere((0.0, 0.0, -1.0), 0.5, 2.0, margin=0.0)
    plain.add_plane((0.0, 0.0, -2.0), (0.0, 0.0, 1.0), 1.0)
    X = V + 0.01 * np.sin(7 * V)
    E, g, H = s.evaluate(X)
    E2, g2, H2 = plain.evaluate(X)
    assert E == E2 and np.array_equal(g, g2) and (H != H2).nnz == 0
    # Three iterations cannot reach 1e-30: the same failure, at the same gradient norm, either way.
    with pytest.raises(ValueError, match="no convergence in 3 iterations") as a:
        hinge.solve_static(s, X, max_iterations=np.int64(3), gradient_tolerance=np.float32(1e-30))
    with pytest.raises(ValueError) as b:
        hinge.solve_static(plain, X, max_iterations=3.0, gradient_tolerance=1e-30)
    assert str(a.value) == str(b.value)


def test_non_finite_states_and_targets_raise_value_error_naming_the_entry():
    # Velocities, positions, loss gradients and targets that are not finite: ValueError naming the vertex,
    # not a stepper that takes NaN in, nor a linear solver's "singular".
    V, s = _system()
    bad = V.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"vertex 3: velocity coordinate 1 is not finite \(NaN\)"):
        hinge.ImplicitEuler(s, V, dt=0.01, density=0.1, V0=np.where(np.isnan(bad), np.nan, 0.0))
    with pytest.raises(ValueError, match=r"vertex 3: position coordinate 1 is not finite \(NaN\)"):
        hinge.ImplicitEuler(s, bad, dt=0.01, density=0.1)
    V, F, s = cantilever()
    bending = [n for n, _ in s.parameters() if n.endswith(".k")][0]
    X, _ = hinge.solve_static(s, V, gradient_tolerance=1e-11)
    dloss = np.zeros_like(V)
    dloss[5, 2] = np.inf
    with pytest.raises(ValueError, match=r"entry 17 \(vertex 5, coordinate 2\) is not finite \(inf\)"):
        hinge.adjoint_gradient(s, X, dloss, [bending])
    target = X.copy()
    target[1, 1] = -np.inf
    with pytest.raises(ValueError, match=r"the target positions: entry 4 \(vertex 1, coordinate 1\)"):
        hinge.fit(s, X, target, [bending], max_iterations=2)


def folded_pair_scene(tmp_path, frames, plane_z, stiffness):
    """A scene file: a folded pair of triangles (its vertices at z = 0.5 … 0.88, the first of the four at
    z = 0.5 the lowest) of the drape's material with a contact plane at height ``plane_z``."""
    obj = tmp_path / "pair.obj"
    obj.write_text(
        "v 0.4 -0.9 0.5\nv 1 0 0.5\n"
        f"v 0.5 {0.8 * np.cos(0.5)} {0.5 + 0.8 * np.sin(0.5)}\n"
        "v 2 0 0.5\nv 0 0 0.5\nf 1 5 2\nf 3 2 5\nf 4 2 3\n"
    )
    scene = tmp_path / "pair.toml"
    scene.write_text(
        f'name = "pair"\nframes = {frames}\ndt = 0.0166\ngravity = [0.0, 0.0, -9.81]\n[mesh]\nobj = "pair.obj"\n'
        "[material]\nyoung = 2e5\npoisson = 0.3\nthickness = 5e-4\ndensity = 0.1\n"
        '[bending]\nenergy = "tan-bending"\n'
        f'[[obstacles]]\nkind = "plane"\npoint = [0.0, 0.0, {plane_z}]\nnormal = [0.0, 0.0, 1.0]\n'
        f"stiffness = {stiffness}\n"
    )
    return str(scene)


def test_run_scene_warns_of_a_mesh_that_starts_inside_an_obstacle(tmp_path):
    # The folded pair below a contact plane at z = 1: every vertex starts inside it, the first of the four at
    # z = 0.5 is the deepest.
    with pytest.warns(hinge.MeshWarning) as caught:
        hinge.run_scene(folded_pair_scene(tmp_path, 1, 1.0, 2e3))
    messages = [str(w.message) for w in caught]
    V = np.array(
        [[0.4, -0.9, 0.5], [1, 0, 0.5], [0.5, 0.8 * np.cos(0.5), 0.5 + 0.8 * np.sin(0.5)], [2, 0, 0.5], [0, 0, 0.5]]
    )
    F = [[0, 4, 1], [2, 1, 4], [3, 1, 2]]
    depth = 0.01 * np.mean([np.linalg.norm(V[f[k]] - V[f[(k + 1) % 3]]) for f in F for k in range(3)])
    mantissa, exponent = f"{depth:.3e}".split("e")  # as Rust writes it: 1.066e-2
    assert messages == [
        f"obstacles[0]: 5 vertices start more than {mantissa}e{int(exponent)} m (1 % of the mean edge) inside it, "
        "the deepest (vertex 0) 5.000e-1 m below its surface; the contact pushes them out at once (vertices from 0)"
    ], messages


def test_run_scene_warns_once_of_vertices_a_soft_contact_lets_through(tmp_path):
    # The folded pair falls onto a plane at z = 0.3 whose contact (1e-3 N/m) cannot stop it: one warning, for
    # the first frame that ends with vertices below the plane, and the run goes on to its end.
    with pytest.warns(hinge.MeshWarning) as caught:
        V, F, X, summary = hinge.run_scene(folded_pair_scene(tmp_path, 30, 0.3, 1e-3))
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1, messages
    m = re.fullmatch(
        r"frame (\d+): \d vertices are more than ([0-9.e-]+) m \(1 % of the mean edge\) inside obstacles\[0\], "
        r"the deepest \(vertex \d\) [0-9.e-]+ m below its surface: its penalty contact \(stiffness 1e-3 N/m, margin 0e0 m\) let them through; a stiffer "
        r"contact, a smaller dt or model = \"barrier\" keeps them out \(vertices from 0\)",
        messages[0],
    )
    assert m, messages
    # The depth is 1 % of the mean edge, and the frame it names is the first whose positions have a vertex
    # that much below the plane (X[k - 1] is frame k).
    edges = [np.linalg.norm(V[a] - V[b]) for f in F for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))]
    depth = 0.01 * np.mean(edges)
    assert float(m.group(2)) == pytest.approx(depth, rel=1e-3), (m.group(2), depth)
    assert summary["frames"] == 30 and X.shape == (30, 5, 3), (summary, X.shape)
    below = [k + 1 for k in range(30) if (X[k][:, 2] < 0.3 - depth).any()]
    assert below and below[0] == int(m.group(1)), (below, messages)


def test_run_scene_warns_of_vertices_a_step_carries_through_a_sphere(tmp_path):
    # At dt = 0.5 s the folded pair falls 2.45 m in its first frame, from 0.5 m above a sphere of radius 0.2
    # centred 0.03 m beside vertex 1 to well below it, and ends outside the sphere: one warning, naming the
    # vertices whose straight paths between frames 0 and 1 pass within half the radius of the centre,
    # recomputed here from the positions.
    folded_pair_scene(tmp_path, 3, 0.3, 1e-3)
    scene = tmp_path / "pair.toml"
    text = scene.read_text().replace("dt = 0.0166", "dt = 0.5")
    text = text[: text.index("[[obstacles]]")] + (
        '[[obstacles]]\nkind = "sphere"\ncenter = [1.03, 0.0, 0.0]\nradius = 0.2\nstiffness = 2e3\nmargin = 0.005\n'
    )
    scene.write_text(text)
    with pytest.warns(hinge.MeshWarning) as caught:
        V, F, X, summary = hinge.run_scene(str(scene))
    messages = [str(w.message) for w in caught]
    assert len(messages) == 1, messages
    m = re.fullmatch(
        r"frame 1: 1 vertex went through obstacles\[0\] since frame 0 \(its straight path relative to the sphere "
        r"passes within half its radius of its centre; the closest, vertex (\d), ([0-9.e-]+) m from it\): its "
        r"penalty contact \(stiffness 2e3 N/m, margin 5e-3 m\) acts where a step ends and never held it; a smaller "
        r"dt or model = \"barrier\" keeps it out \(vertices from 0\)",
        messages[0],
    )
    assert m, messages
    centre = np.array([1.03, 0.0, 0.0])
    a, b = V - centre, X[0] - centre
    t = np.clip(-np.einsum("ij,ij->i", a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0.0, 1.0)
    d = np.linalg.norm(a + t[:, None] * (b - a), axis=1)
    assert [int(v) for v in np.flatnonzero(d < 0.1)] == [int(m.group(1))] == [1], (d, messages)
    assert float(m.group(2)) == pytest.approx(d[1], rel=1e-3), (m.group(2), d)
    assert summary["frames"] == 3


def test_a_static_solve_of_gravity_alone_names_the_zero_hessian():
    V, F = sheet(3, 3, 40)
    s = hinge.System(V, F).add_gravity(density=0.1)
    with pytest.raises(ValueError, match="the Hessian is zero on every free dof at iteration 0 while the gradient is not"):
        hinge.solve_static(s, V)



def test_solves_say_where_the_residual_is():
    """``stats["largest_residual"]``: the free vertex with the largest force at the returned positions,
    recomputed from ``System.evaluate``; the pinned vertices' reactions (larger) are not residuals. A solve
    that fails names that vertex (a row of V) in its ValueError."""
    V, F = sheet(6, 3, 41)
    s = hinge.System(V, F).add_bending(energy="tan-bending", k=1e-3).add_membrane(1e5, 0.3, 1e-3)
    s.add_gravity(density=0.1)
    pinned = np.flatnonzero(V[:, 0] <= V[:, 0].min() + 0.05)
    s.pin(pinned)
    free = np.setdiff1d(np.arange(len(V)), pinned)
    # Stopped early (the gradient a thousandth of its start's) and solved: both name the free vertex whose
    # force is largest.
    for kwargs in ({"relative_gradient_tolerance": 1e-3, "gradient_tolerance": 0}, {}):
        X, stats = hinge.solve_static(s, V, membrane_continuation=False, **kwargs)
        assert stats["newton_iterations"] >= 2
        _, g = s.evaluate(X, hessian=False)
        force = np.linalg.norm(g.reshape(-1, 3), axis=1)
        v, f = stats["largest_residual"]
        assert v == free[np.argmax(force[free])]
        assert f == pytest.approx(force[v], rel=1e-13)
        assert f <= stats["final_gradient_norm"]
        assert force[pinned].max() > 10 * f
    with pytest.raises(ValueError, match=r"no convergence in 2 iterations .*; the largest residual force, .* N, "
                                         r"is at vertex \d+$") as e:
        hinge.solve_static(s, V, max_iterations=2, membrane_continuation=False)
    named = int(str(e.value).rsplit(" ", 1)[1])
    assert named in free
    # A time step's stats say it too, at the frame's end (the inertia term included, so not recomputed here:
    # a free vertex, at most the final gradient norm).
    X, stats = hinge.ImplicitEuler(s, V, 0.01, 0.1, gradient_tolerance=1e-9).step()
    v, f = stats["largest_residual"]
    assert v in free and 0 < f <= stats["final_gradient_norm"] <= 1e-9


def test_run_scene_resumes_from_its_checkpoint_bitwise(tmp_path):
    # Straight through 16 frames, and 7 then resumed to 16: the same frames, bit for bit, with the trace
    # counting frames from the checkpoint's and the per-frame counts the straight run's tail.
    V, F, X, s = hinge.run_scene("drape", frames=16, checkpoint=tmp_path / "full.txt")
    _, _, X7, s7 = hinge.run_scene("drape", frames=7, checkpoint=str(tmp_path / "c7.txt"))
    assert s7["resumed_after_frame"] is None
    assert np.array_equal(X7, X[:7])
    _, _, Xr, sr = hinge.run_scene("drape", frames=16, trace=True, resume=tmp_path / "c7.txt",
                                   checkpoint=tmp_path / "resumed.txt")
    assert Xr.shape == (9, len(V), 3)
    assert np.array_equal(Xr, X[7:])
    assert sr["frames"] == 9 and sr["resumed_after_frame"] == 7
    assert sr["frame_newton_iterations"] == s["frame_newton_iterations"][7:]
    assert sr["trace"][0, 0] == 7 and sr["trace"][-1, 0] == 15
    assert (tmp_path / "resumed.txt").read_text() == (tmp_path / "full.txt").read_text()
    # The checkpoint's header and positions: frame 7, the last frame's positions exactly.
    lines = (tmp_path / "c7.txt").read_text().splitlines()
    assert lines[0] == "hinge checkpoint 2" and lines[2] == "frame 7"
    assert lines[6].startswith("warned_obstacles")
    first = [float(t) for t in lines[9].split()]
    assert first[:3] == list(X[6, 0])
    # Checkpoints that do not fit, damaged ones and bad arguments raise ValueError.
    with pytest.raises(ValueError, match="the checkpoint has 961 vertices, the scene's mesh"):
        hinge.run_scene("shell-drop", frames=8, resume=tmp_path / "c7.txt")
    with pytest.raises(ValueError, match="at frame 16 and the scene has 16 frames"):
        hinge.run_scene("drape", frames=16, resume=tmp_path / "full.txt")
    bad = tmp_path / "bad.txt"
    bad.write_text("\n".join(lines[:9] + ["1 2 3"] + lines[10:]))
    with pytest.raises(ValueError, match="line 10 \\(vertex 0\\): expected 6 numbers, found 3"):
        hinge.run_scene("drape", frames=16, resume=bad)
    with pytest.raises(ValueError, match="resume: "):
        hinge.run_scene("drape", frames=16, resume=tmp_path / "missing.txt")
    with pytest.raises(ValueError, match="resume must be a path"):
        hinge.run_scene("drape", frames=16, resume=3)
    # Periodic checkpoints: the file after the run is its end, written every 4 frames on the way.
    _, _, _, s9 = hinge.run_scene("drape", frames=9, checkpoint=tmp_path / "p.txt", checkpoint_every=4)
    assert (tmp_path / "p.txt").read_text().splitlines()[2] == "frame 9"
    with pytest.raises(ValueError, match="checkpoint_every must be at least 1"):
        hinge.run_scene("drape", frames=9, checkpoint=tmp_path / "p.txt", checkpoint_every=0)
    with pytest.raises(ValueError, match="checkpoint_every needs checkpoint"):
        hinge.run_scene("drape", frames=9, checkpoint_every=2)
    with pytest.raises(ValueError, match="cannot be written"):
        hinge.run_scene("drape", frames=9, checkpoint=tmp_path / "no" / "such" / "c.txt")
    with pytest.raises(ValueError, match="cannot be written"):
        hinge.run_scene("drape", frames=9, checkpoint=tmp_path)
