"""Galois group of Hess(theta)'s characteristic polynomial (evidence for core/src/bending/projection.rs).

monodromy.py shows that the hinge Hessian's eigenvalues have no closed form in psi''/psi'. This script
asks the narrower question whether at least Hess(theta) itself -- the whole Hessian of any psi linear in
theta, and the part a rank-one (secular-equation) update of a closed form would start from -- has
eigenvalues in closed form. It does not:

For stencils with rational coordinates and the hinge edge along the z axis with rational length, every
entry of Hess(theta) is rational (the formula below has |e|, |N1|^2 and |N2|^2 only), so its
characteristic polynomial is lam^4 * p(lam) with p of degree 8 in Q[lam]. The script computes p exactly
and checks
  1. p is irreducible over Q, and over Q(sqrt|N1|^2, sqrt|N2|^2) (the square roots the unit normals
     bring in): no factor of lower degree;
  2. the factorization patterns of p modulo primes (Dedekind: each is the cycle type of a Frobenius
     element of the Galois group): a pattern (7, 1) gives a 7-cycle, so the transitive group is
     primitive (7 > 8/2), and a pattern with one 2 and otherwise odd parts gives a transposition (its
     odd power); a primitive group with a transposition is the full symmetric group S_8 (Jordan).
S_8 is not solvable, so p's roots -- the eight non-zero eigenvalues of Hess(theta) at that stencil --
are not expressible in radicals of the coordinates. Needs sympy; about a minute.
Run: python3 docs/projection/galois.py > docs/projection/galois.txt
"""
import random

import sympy as sp


def cross(a, b):
    return sp.Matrix([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def grad_theta(x1, x2, x3, x4):
    """grad theta (Bridson et al. 2003; wings x1, x2, hinge edge x3 -> x4), up to the sign convention."""
    e = x4 - x3
    n1 = cross(x1 - x3, x1 - x4)
    n2 = cross(x2 - x4, x2 - x3)
    le = sp.sqrt(e.dot(e))
    a1 = n1 / n1.dot(n1)
    a2 = n2 / n2.dot(n2)
    u3 = (x1 - x4).dot(e) / le * a1 + (x2 - x4).dot(e) / le * a2
    u4 = -(x1 - x3).dot(e) / le * a1 - (x2 - x3).dot(e) / le * a2
    return sp.Matrix.vstack(le * a1, le * a2, u3, u4), n1.dot(n1), n2.dot(n2)


def transposition_pattern(degrees):
    return degrees.count(2) == 1 and all(d % 2 == 1 for d in degrees if d != 2)


def analyse(rng):
    y = sp.symbols("y0:12")
    pts = [sp.Matrix(y[3 * i : 3 * i + 3]) for i in range(4)]
    g, _, _ = grad_theta(*pts)
    r = lambda: sp.Rational(rng.randint(-9, 9), rng.randint(1, 5))
    values = [r() for _ in range(6)] + [0, 0, 0, 0, 0, sp.Rational(rng.randint(1, 9), rng.randint(1, 3))]
    at = dict(zip(y, values))
    h = g.jacobian(y).subs(at).applyfunc(sp.nsimplify)
    assert h == h.T, "Hess theta must be symmetric"
    lam = sp.symbols("lam")
    full = sp.Poly(h.charpoly(lam).as_expr(), lam)
    p = sp.Poly(sp.cancel(full.as_expr() / lam**4), lam)
    assert p.degree() == 8 and p.eval(0) != 0, "four zero eigenvalues exactly"
    _, d1, d2 = grad_theta(*[sp.Matrix(values[3 * i : 3 * i + 3]) for i in range(4)])
    over_q = [sp.degree(f, lam) for f, _ in sp.factor_list(p.as_expr(), lam)[1]]
    ext = [sp.sqrt(d1), sp.sqrt(d2)]
    over_ext = [sp.degree(f, lam) for f, _ in sp.factor_list(p.as_expr(), lam, extension=ext)[1]]
    # integer coefficients, then patterns modulo primes not dividing the lead or the discriminant
    pz = sp.Poly(p.as_expr() * sp.lcm([c.q for c in p.all_coeffs()]), lam, domain="ZZ")
    disc = sp.discriminant(pz)
    seven = two = None
    for ell in sp.primerange(3, 2000):
        if pz.LC() % ell == 0 or disc % ell == 0:
            continue
        degrees = sorted((f.degree() for f, _ in sp.Poly(pz.as_expr(), lam, modulus=ell).factor_list()[1]), reverse=True)
        if seven is None and degrees == [7, 1]:
            seven = ell
        if two is None and transposition_pattern(degrees):
            two = (ell, degrees)
        if seven and two:
            break
    s8 = over_q == [8] and seven is not None and two is not None
    return values, over_q, over_ext, ext, seven, two, s8


rng = random.Random(7)
all_s8 = True
for k in range(5):
    values, over_q, over_ext, ext, seven, two, s8 = analyse(rng)
    all_s8 &= s8
    print(f"stencil {k}: {[str(v) for v in values]}")
    print(f"  factor degrees over Q: {over_q}; over Q({', '.join(map(str, ext))}): {over_ext}")
    print(f"  7-cycle mod {seven}; transposition from pattern {two[1] if two else None} mod {two[0] if two else None}")
    print(f"  Galois group S_8: {s8}")
print("every stencil: Galois group S_8" if all_s8 else "NOT every stencil showed S_8")
