"""Linearly varying source radiance over visible fragments: the first moment of the form factor.

A source triangle whose radiance is given at its three corners has, per channel, the affine radiance
``L(x) = L0 + g·x`` over its plane (Chen & Arvo, "A closed-form solution for the irradiance due to
linearly-varying luminaires", EGWR 2000; Chen & Arvo, "Closed-form expressions for irradiance from
non-uniform Lambertian luminaires, part I", Caltech CS-TR-00-01). The contribution of a visible
fragment of it to the irradiance at the receiver P is ``∫_frag L dF = L0·F + g·G`` with the form
factor ``F`` (Lambert's contour integral, eq. 4 of the paper) and the *first moment*

    G = ∫_frag x · cosθ_P cosθ_x / (π r²) dA(x)          (a 3-vector, length units of x)

All coordinates are P-local (``x - P``), float64. Units: ``F`` is dimensionless, ``G`` has the units
of the coordinates, ``g`` is radiance per length, so ``g·G`` is a radiance (W sr⁻¹ m⁻²) × F.

Derivation (near field, all fragments not covered by the far-field rule below)
-----------------------------------------------------------------------------
Let the fragment's plane be ``n·x = d`` with ``n`` oriented so that ``d > 0`` (``n`` points away from
P), write ``x = d n + y`` with ``y`` in the plane (origin of ``y`` = foot point of P), ``r² = d² + ρ²``,
``ρ = |y|``. Then ``cosθ_x = d/r``, ``cosθ_P = N·x/r`` and ``G = T N`` with the symmetric tensor
``T = (d/π) ∫ x xᵀ / r⁴ dA`` (a second-order irradiance tensor in the sense of Arvo, "Applications of
irradiance tensors to the simulation of non-Lambertian phenomena", SIGGRAPH 1995, but with area
measure, hence the non-elementary part below, as in Chen & Arvo). With ``V = (d/π) ∫ x / r⁴ dA`` —
the vector irradiance, ``V = (1/2π) Σ_e Γ_e`` by Lambert's formula, ``F = N·V`` —

    T n      = d V                                           (so G·n = d F exactly: a built-in check)
    T_tt     = (d/π) ∫ y yᵀ / r⁴ dA = (d/2π) (J P_t − S)      (in-plane block, divergence theorem)
    G        = d [ (n·N) V + F n − (n·V)(n·N) n ] + T_tt N

using ``y_i y_j / r⁴ = ½ δ_ij / r² − ½ ∂_i (y_j / r²)`` (``P_t = I − n nᵀ``). Per edge ``e`` from
vertex ``a`` to ``b`` (length ``ℓ``, unit direction ``ê``, outward in-plane normal ``ν``, signed
distance ``p = ν·a`` of its line from the foot point, ``c = √(d² + p²)`` its distance from P,
``t = ê·x`` along it):

    S = sym Σ_e ν ⊗ (p A_e ν + B_e ê),   A_e = ∫ dt/(c² + t²) = θ_e / c,   θ_e = atan2(|a×b|, a·b)
                                         B_e = ∫ t dt/(c² + t²) = ½ log1p((b−a)·(b+a) / |a|²)
    J = ∫ dA / r² = Σ_e J_e,              J_e = ½ p ∫ log1p((p² + t²)/d²) / (p² + t²) dt

``J`` (the log-potential of the fragment, polar coordinates about the foot point) is the only
non-elementary part (a Clausen/dilogarithm function, the "well-behaved special function" of Chen &
Arvo). It is integrated numerically after the substitution ``t = c sinh u``, which turns it into

    J_e = ∫_{u_a}^{u_b} f(u) du,   f(u) = ½ p c cosh u · log1p(ρ²/d²) / ρ²,   ρ² = p² + c² sinh² u

``f`` is analytic in the strip ``|Im u| < π/2``; its only singularities are the branch points
``u = ±iπ/2 (+ iπk)`` (where ``r = c cosh u = 0``), all on the imaginary axis, and it decays like
``u e^{-|u|}``. The peaked kernel of a receiver close to the plane (``d ≪`` fragment size), edges
passing close to the foot point (``p → 0``) and huge fragments (long ``u`` ranges) are all absorbed
by this substitution: the singularity is always at distance ``π/2`` from the real axis.

Error bound. ``[u_a, u_b]`` is cut at the fixed break points ``±BREAK0·2^k`` (one central piece
``[−BREAK0, BREAK0]``, then pieces ``[β, 2β]`` further out) and each piece gets an ``n = _J_NODES``-point
Gauss–Legendre rule. By the Bernstein-ellipse bound for Gauss quadrature (Trefethen, *Approximation
Theory and Approximation Practice*, Thm 19.3), ``|E_n| ≤ (64/15) M h ρ^{-2n} / (ρ² − 1)`` on a piece of
half-length ``h`` where ``f`` is analytic and bounded by ``M`` inside the ellipse ``E_ρ`` (``f`` is
analytic in the ellipse through the nearest branch point: the zeros of ``ρ²`` on the imaginary axis are
removable). For the central piece (BREAK0 = 1) the ellipse through ``±i(π/2 − 0.2)`` has
``ρ₀ = a + √(a² + 1) = 3.07``, ``a = π/2 − 0.2``, and on it ``M ≤ 5.3 × mean|f|`` on the piece
(sampled over ``p/d``, ``d`` in 1e-8…1e8 — near ``±iπ/2`` the integrand behaves like
``log(c²v²/d²)/(d² + c²v²)``, ``v = u ∓ iπ/2``, a mild, scale-free peak), so with n = 20 the
relative error (to ``∫|f| = |J_e|``, ``f`` has the sign of ``p``) is ``≤ 2e-19``. Outer pieces
``[β, 2β]`` see the branch points from ``≥ 3β/2`` away: ``ρ ≥ 5.8``, error ``≤ 1e-28``. Rounding
dominates: the development check against 34-digit mpmath integrals of ``J_e`` for 6000 random edges
(``d`` in 1e-8…1e3, ``p/d`` and edge length / ``c`` in 1e-8…1e8, positions along the line to 1e8 ``c``)
gave a max relative error of 6.1e-15 with n = 20 (n = 16 gives the same; n = 12 gives 1.5e-13, n = 8
3e-9 — the convergence predicted by the bound). Short edges far out along their line are integrated on
``[u_a, u_a + Δu]`` with ``Δu = asinh(t_b/c) − asinh(t_a/c)`` evaluated without cancellation from the
edge length.

Direct quadrature (far field, and ill-conditioned edge sums). A fragment — or a sub-triangle — of
diameter ``D`` at distance ``dist ≥ D / FAR_RATIO = 4D`` from P is integrated directly: the integrand
``x (N·x) d / (π r⁴)`` (times ``x − centre`` for the moment about a centre) on each fan triangle from
vertex 0 with a collapsed (Duffy) ``FAR_NODES × FAR_NODES`` = 10 × 10 Gauss–Legendre rule, which is
exact for polynomials of total degree ≤ 2·10 − 2 = 18 on the triangle. The integrand's only
singularity is P (along any line through the triangle's centroid ``x₀`` the complex zeros of ``r²`` lie
at distance ``|x₀| ≥ 4D`` from ``x₀``, and every point of the triangle is within ``2D/3`` of ``x₀``), so
its Taylor series about ``x₀`` converges with ratio ``≤ 1/6`` and the rule's relative error is
``≈ 6^{-19} ≈ 2e-15`` times a modest constant. Measured against the tests' independent reference: no
change from 6 to 16 nodes, at the reference's ~1e-14 floor. Used for

* far-field fragments (``D ≤ FAR_RATIO · max(d, min_k |v_k| − D)``, ``D`` the exact diameter): this
  avoids the cancellation of the edge sums for small fragments (edge terms ``~D``, result ``~D²``) —
  relative accuracy ~1e-15 for fragments of size 1e-6 at distance 1, where the contour formulas
  would lose ~10 digits;
* near-field fragments whose Lambert sum is ill-conditioned beyond what the input's rounding already
  implies (``κ_F = Σ|N·Γ_e| / |F|`` with ``κ_F d / max|x| > KAPPA_MAX``: typically fragments lying in a
  thin sliver ``0 ≤ N·x ≤ δ|x|`` above the horizon, where Lambert's F loses ``~eps/δ³``), provided the
  fan triangles, split 4-way towards P, satisfy the far-field criterion within ``MAX_LEVEL`` = 6
  splits (otherwise the contour result is kept).

Conditioning and measured accuracy. The near-field contour formulas reproduce the reference to ~1e-14
(a few 1e-11 when P is within ~1e-6 of the fragment's plane with the foot point outside the fragment,
where F's edge sum cancels by ``~size/d``: rounding the P-local vertices by ``eps·|x|`` changes the
exact F by the same ``~eps·|x|/d`` there, so the inputs carry that uncertainty anyway). Sliver fragments
near the horizon (δ = 1e-2 … 1e-6): G to ≤ 2e-13 (Lambert's F on the same fragments: 5e-11 … 6e-3).
Rounding the inputs by ``eps·|x|`` changes the exact ``G`` of a fragment of size ``D`` by
``~eps·|x|/D`` relative.

Cost (one core, numpy 2.4, 6-vertex fragments): ~30–50 µs per fragment (near field: ~4 Gauss pieces of
20 nodes per edge; far field: 100 nodes per fan triangle); ~1–5 ms for the rare adaptively split ones.
"""

from __future__ import annotations

import numpy as np

__all__ = ["first_moment", "linear_irradiance"]

#: Gauss–Legendre nodes per piece of the edge integral J_e (see the module docstring for the bound).
_J_NODES = 20
#: Half-width of the central piece in u = asinh(t / c); outer break points are ±BREAK0·2^k.
BREAK0 = 1.0
#: Fragments (and sub-triangles) with diameter ≤ FAR_RATIO × (a lower bound of their distance from P)
#: use the direct (far-field) quadrature.
FAR_RATIO = 0.25
#: Near-field fragments whose contour sum for F cancels by more than this factor beyond the input's own
#: conditioning (κ_F · d / max|x| > KAPPA_MAX; a receiver close to the plane makes F inherently
#: sensitive to rounding of the vertices, by ~max|x|/d) use the adaptive direct quadrature instead.
KAPPA_MAX = 1e3
#: Maximum number of 4-way splits of a fan triangle in the adaptive quadrature.
MAX_LEVEL = 6
#: Gauss–Legendre nodes per direction of the far-field rule on each fan triangle.
FAR_NODES = 10

_BREAKS = np.concatenate([-BREAK0 * 2.0 ** np.arange(11)[::-1], BREAK0 * 2.0 ** np.arange(11)])
_GL_X, _GL_W = np.polynomial.legendre.leggauss(_J_NODES)
_FAR_X, _FAR_W = np.polynomial.legendre.leggauss(FAR_NODES)
_FAR_X = 0.5 * (_FAR_X + 1.0)
_FAR_W = 0.5 * _FAR_W


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _norm(a):
    return np.sqrt(_dot(a, a))


def _safe_unit(a):
    n = _norm(a)
    ok = n > 0
    return a / np.where(ok, n, 1.0)[..., None], n, ok


def _edges(verts, counts):
    """Edge endpoint arrays (F, K, 3) a, b and a validity mask (F, K) from padded vertices."""
    F, K, _ = verts.shape
    k = np.arange(K)
    counts = np.asarray(counts, dtype=np.int64).reshape(F)
    valid = k[None, :] < counts[:, None]
    nxt = np.where(k[None, :] + 1 < counts[:, None], k[None, :] + 1, 0)
    a = verts
    b = np.take_along_axis(verts, nxt[:, :, None], axis=1)
    valid &= _norm(b - a) > 0
    return a, b, valid


def _area_vector(verts, counts):
    """Twice the vector area (F, 3) of padded polygons, from differences to vertex 0 (no cancellation
    for small polygons far from P)."""
    a, b, valid = _edges(verts, counts)
    v0 = verts[:, :1]
    return np.sum(np.where(valid[..., None], np.cross(a - v0, b - v0), 0.0), axis=1)


def _orient(verts, counts, plane_normal):
    """Unit plane normal n pointing away from P (d > 0), offset d (F,), orientation s (F,) of the
    vertex order about n (+1 counter-clockwise, -1 clockwise, 0 degenerate)."""
    F, K, _ = verts.shape
    n, _, _ = _safe_unit(np.broadcast_to(np.asarray(plane_normal, dtype=np.float64), (F, 3)))
    counts = np.asarray(counts, dtype=np.int64).reshape(F)
    k = np.arange(K)
    valid = k[None, :] < counts[:, None]
    d = np.sum(np.where(valid, _dot(verts, n[:, None, :]), 0.0), axis=1) / np.maximum(counts, 1)
    flip = d < 0
    n = np.where(flip[:, None], -n, n)
    d = np.abs(d)
    s = np.sign(_dot(_area_vector(verts, counts), n))
    return n, d, s


def _vector_irradiance(a, b, valid, s, N=None):
    """V = (1/2π) Σ_e unit(a×b) θ_e (sign-corrected), the vector whose N-component is Lambert's
    form factor (paper eq. 4). a, b (F, K, 3); returns V (F, 3), and with N (F, 3) also
    Σ_e |N·Γ_e| / 2π (F,), so that κ_F = that / |F| is the condition number of the edge sum.
    ``a × (b − a)`` (= a × b) is used for the direction of Γ_e: accurate for short edges, where a × b
    loses ``|a| / |b − a|`` digits (for a polygon of size 1e-6 at distance 1 that is the difference
    between ~1e-8 and ~1e-3 relative error in F, measured)."""
    cr = np.cross(a, b - a)
    u, crn, ok = _safe_unit(cr)
    theta = np.arctan2(crn, _dot(a, b))
    ok &= valid
    gam = np.where(ok[..., None], u * theta[..., None], 0.0)
    V = np.sum(gam, axis=1) * (s / (2.0 * np.pi))[:, None]
    if N is None:
        return V
    return V, np.sum(np.abs(_dot(gam, N[:, None, :])), axis=1) / (2.0 * np.pi)


def _polygon_form_factor(verts, counts, normal):
    """Lambert's contour integral (paper eq. 4): F (F,) of convex planar fragments (F, K, 3),
    P-local, seen from a receiver with unit normal ``normal`` (F, 3) or (3,). Orientation is taken
    from the fragment's own area vector (the fragment faces P)."""
    verts = np.asarray(verts, dtype=np.float64)
    F = verts.shape[0]
    N = np.broadcast_to(np.asarray(normal, dtype=np.float64), (F, 3))
    a, b, valid = _edges(verts, counts)
    # the side of the fragment facing P: area vector pointing away from P ⇔ area·x > 0
    s = np.sign(_dot(_area_vector(verts, counts), verts[:, 0]))
    return _dot(N, _vector_irradiance(a, b, valid, s))


def _asinh_difference(x, y, diff):
    """asinh(x) − asinh(y) for x ≥ y, given diff = x − y accurately, without cancellation (arrays)."""
    same = (x > 0) & (y > 0) | (x < 0) & (y < 0)
    neg = x < 0
    xs = np.where(neg, -y, x)  # reflect so that both are positive: asinh(x)−asinh(y) = asinh(−y)−asinh(−x)
    ys = np.where(neg, -x, y)
    sx = np.sqrt(1.0 + xs * xs)
    sy = np.sqrt(1.0 + ys * ys)
    close = np.log1p(diff * (1.0 + (xs + ys) / (sx + sy)) / np.where(same, ys + sy, 1.0))
    return np.where(same, close, np.arcsinh(x) - np.arcsinh(y))


def _edge_log_potential(p, c, d, ta, tb, length=None):
    """J_e = ½ p ∫_{ta}^{tb} log1p((p² + t²)/d²) / (p² + t²) dt for arrays (E,) (length², i.e. the
    signed ∫ dA / r² over the fan triangle foot–a–b); ``length`` = tb − ta if known more accurately than
    the difference (the edge length). Gauss–Legendre in u = asinh(t / c) on the fixed
    pieces of ``_BREAKS`` (see the module docstring for the error bound)."""
    E = p.shape[0]
    if E == 0:
        return np.zeros(0)
    ua = np.arcsinh(ta / c)
    ub = np.arcsinh(tb / c)
    lo = np.minimum(ua, ub)
    hi = np.maximum(ua, ub)
    sign = np.where(ub >= ua, 1.0, -1.0)
    span = np.abs(tb - ta if length is None else length) / c
    width = _asinh_difference(np.maximum(ta, tb) / c, np.minimum(ta, tb) / c, span)
    npieces = _BREAKS.size + 1  # including the two unbounded end pieces (never reached in practice)
    brk = np.concatenate([[-np.inf], _BREAKS, [np.inf]])
    jlo = np.clip(np.searchsorted(brk, lo, side="right") - 1, 0, npieces - 1)
    jhi = np.clip(np.searchsorted(brk, hi, side="left") - 1, 0, npieces - 1)
    cnt = np.maximum(jhi - jlo + 1, 0)
    edge = np.repeat(np.arange(E), cnt)
    start = np.cumsum(cnt) - cnt
    j = jlo[edge] + (np.arange(edge.size) - np.repeat(start, cnt))
    # pieces as offsets from lo (break point − lo is exact when close), the last one ending at the
    # accurately computed width: short edges far out keep full relative precision
    lo_e = lo[edge]
    o0 = np.maximum(brk[j] - lo_e, 0.0)
    o1 = np.minimum(brk[j + 1] - lo_e, width[edge])
    half = 0.5 * (o1 - o0)
    u = (lo_e + 0.5 * (o0 + o1))[:, None] + half[:, None] * _GL_X[None, :]
    pe, ce, de = p[edge][:, None], c[edge][:, None], d[edge][:, None]
    sh = np.sinh(u)
    ch = np.cosh(u)
    cs = ce * sh
    rho2 = pe * pe + cs * cs
    pos = rho2 > 0
    sr = np.sqrt(rho2) / de  # ρ / d
    small = sr <= 1.0
    srs = np.where(small, sr, 0.0)
    srl = np.where(small, 1.0, sr)
    lg = np.where(small, np.log1p(srs * srs), 2.0 * np.log(np.hypot(1.0, srl)))  # log(r²/d²)
    f = np.where(pos, 0.5 * pe * (ce * ch) * lg / np.where(pos, rho2, 1.0), 0.0)
    piece = half * (f @ _GL_W)
    return sign * np.bincount(edge, weights=piece, minlength=E)


def _near_moment(verts, counts, N, n, d, s):
    """Contour-integral G (F, 3) and Lambert F (F,) for fragments with d > 0 (module docstring)."""
    F, K, _ = verts.shape
    a, b, valid = _edges(verts, counts)
    V, Vabs = _vector_irradiance(a, b, valid, s, N)
    Ff = _dot(N, V)
    ab = b - a
    ell = _norm(ab)
    e = ab / np.where(valid, ell, 1.0)[..., None]
    nu = np.cross(e, n[:, None, :]) * s[:, None, None]
    p = 0.5 * (_dot(nu, a) + _dot(nu, b))
    dd = np.broadcast_to(d[:, None], (F, K))
    c = np.hypot(dd, p)
    theta = np.arctan2(_norm(np.cross(a, ab)), _dot(a, b))
    A = theta / np.where(valid, c, 1.0)
    a2 = _dot(a, a)
    B = 0.5 * np.log1p(np.where(valid, _dot(ab, a + b) / np.where(valid, a2, 1.0), 0.0))
    vec = (p * A)[..., None] * nu + B[..., None] * e
    S = np.einsum("fki,fkj->fij", np.where(valid[..., None], nu, 0.0), vec)
    S = 0.5 * (S + np.swapaxes(S, 1, 2))
    # the non-elementary log-potential J = ∫ dA / r², summed over the edges with p ≠ 0
    use = valid & (p != 0)
    Je = np.zeros((F, K))
    Je[use] = _edge_log_potential(p[use], c[use], dd[use], _dot(e, a)[use], _dot(e, b)[use], ell[use])
    J = np.sum(Je, axis=1) * np.abs(s)
    Pt = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
    Ttt = (d / (2.0 * np.pi))[:, None, None] * (J[:, None, None] * Pt - S)
    nN = _dot(n, N)
    G = d[:, None] * (nN[:, None] * V + Ff[:, None] * n - (_dot(n, V) * nN)[:, None] * n)
    G = G + np.einsum("fij,fj->fi", Ttt, N)
    kappa = Vabs / np.maximum(np.abs(Ff), np.finfo(float).tiny)
    return G, Ff, kappa


def _triangle_rule():
    uu, ww = np.meshgrid(_FAR_X, _FAR_X, indexing="ij")
    wt = (_FAR_W[:, None] * _FAR_W[None, :] * uu).ravel()  # collapsed (Duffy) Jacobian u
    return (uu * (1.0 - ww)).ravel(), (uu * ww).ravel(), wt


def _quadrature_moment(verts, counts, N, d, centre, max_level):
    """Direct quadrature of F and ∫ (x − centre) dF over fragments (F, K, 3): the fan triangles from
    vertex 0, split into four (edge midpoints) until each satisfies the far-field criterion
    ``diam ≤ FAR_RATIO · max(d, r_min − diam)``, at most ``max_level`` times.

    Returns (F_quad (F,), M (F, 3), resolved (F,) bool); where ``resolved`` is False some triangle still
    failed the criterion after ``max_level`` splits (the values are then not to be used)."""
    Fn, K, _ = verts.shape
    xi, eta, wt = _triangle_rule()
    kk = np.arange(1, K - 1)
    fi, ki = np.nonzero(kk[None, :] + 1 < counts[:, None])
    ki = ki + 1
    tri = np.stack([verts[fi, 0], verts[fi, ki], verts[fi, ki + 1]], axis=1)  # (T, 3, 3)
    owner = fi
    Fq = np.zeros(Fn)
    M = np.zeros((Fn, 3))
    resolved = np.ones(Fn, dtype=bool)
    for level in range(max_level + 1):
        if tri.shape[0] == 0:
            break
        e1 = tri[:, 1] - tri[:, 0]
        e2 = tri[:, 2] - tri[:, 0]
        jac = _norm(np.cross(e1, e2))
        diam = np.maximum(np.maximum(_norm(e1), _norm(e2)), _norm(tri[:, 2] - tri[:, 1]))
        rmin = np.min(_norm(tri), axis=1)
        ok = (diam <= FAR_RATIO * np.maximum(d[owner], rmin - diam)) | (jac == 0)
        if level == max_level:
            resolved[owner[~ok]] = False
        t, o, j = tri[ok], owner[ok], jac[ok]
        if t.shape[0]:
            x = t[:, :1, :] + xi[None, :, None] * (t[:, 1] - t[:, 0])[:, None, :]
            x = x + eta[None, :, None] * (t[:, 2] - t[:, 0])[:, None, :]  # (T, Q, 3)
            r2 = _dot(x, x)
            w = _dot(x, N[o][:, None, :]) / (r2 * r2) * (wt[None, :] * j[:, None])  # (T, Q)
            Fq += np.bincount(o, weights=w.sum(axis=1), minlength=Fn)
            mom = np.einsum("tq,tqi->ti", w, x - centre[o][:, None, :])
            for i in range(3):
                M[:, i] += np.bincount(o, weights=mom[:, i], minlength=Fn)
        bad = ~ok
        if level == max_level or not np.any(bad):
            break
        a, b, c = tri[bad, 0], tri[bad, 1], tri[bad, 2]
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        tri = np.concatenate(
            [np.stack(v, axis=1) for v in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))], axis=0
        )
        owner = np.tile(owner[bad], 4)
    scale = d / np.pi
    return Fq * scale, M * scale[:, None], resolved


def _distance_from_p(verts, counts, n, d, s):
    """Distance (F,) from P (the origin) to each convex planar fragment (oriented by n, d, s)."""
    a, b, valid = _edges(verts, counts)
    ab = b - a
    nu = np.cross(ab, n[:, None, :]) * s[:, None, None]  # outward in-plane edge normals (unnormalised)
    foot = d[:, None] * n
    inside = np.all(~valid | (_dot(nu, foot[:, None, :] - a) <= 0.0), axis=1)
    L2 = _dot(ab, ab)
    t = np.clip(-_dot(a, ab) / np.where(valid, L2, 1.0), 0.0, 1.0)
    dseg = np.where(valid, _norm(a + t[..., None] * ab), np.inf)
    return np.where(inside, d, np.min(dseg, axis=1))


def _moments(verts, counts, normal, plane_normal, centre=None):
    """(F_lambert (F,), M (F, 3)) with M = ∫ (x − centre) dF; centre (F, 3) or None (= P).

    Routing: far-field fragments → direct quadrature; others → the contour formulas, unless their edge
    sums are ill-conditioned (``κ_F = Σ|N·Γ_e| / |Σ N·Γ_e|``, ``κ_F d / max|x| > KAPPA_MAX``) and the
    subdivision stays shallow, then → adaptive quadrature."""
    verts = np.asarray(verts, dtype=np.float64)
    if verts.ndim != 3 or verts.shape[2] != 3:
        raise ValueError(f"verts must have shape (F, K, 3), got {verts.shape}")
    Fn, K, _ = verts.shape
    counts = np.asarray(counts, dtype=np.int64).reshape(Fn)
    N = np.broadcast_to(np.asarray(normal, dtype=np.float64), (Fn, 3))
    cen = np.zeros((Fn, 3)) if centre is None else np.broadcast_to(np.asarray(centre, np.float64), (Fn, 3))
    n, d, s = _orient(verts, counts, plane_normal)
    good = (d > 0) & (s != 0) & np.all(np.isfinite(verts.reshape(Fn, K * 3)), axis=1)
    Ff = np.zeros(Fn)
    M = np.zeros((Fn, 3))
    if not np.any(good):
        return Ff, M
    # far-field test: exact diameter against a lower bound of the distance from P
    kk = np.arange(K)[None, :]
    vmask = kk < counts[:, None]
    diam = np.zeros(Fn)
    for k in range(K):
        dk = _norm(verts - verts[:, k : k + 1])
        diam = np.maximum(diam, np.max(np.where(vmask & vmask[:, k : k + 1], dk, 0.0), axis=1))
    rmin = np.min(np.where(vmask, _norm(verts), np.inf), axis=1)
    far = good & (diam <= FAR_RATIO * np.maximum(d, rmin - diam))
    near = good & ~far
    if np.any(near):
        G, Fl, kappa = _near_moment(verts[near], counts[near], N[near], n[near], d[near], s[near])
        Ff[near] = Fl
        M[near] = G - cen[near] * Fl[:, None]
        # ill-conditioned edge sums (fragments thin in the direction of N): direct quadrature
        rmax = np.max(np.where(vmask, _norm(verts), 0.0), axis=1)
        ill = np.flatnonzero(near)[kappa * d[near] > KAPPA_MAX * rmax[near]]
        if ill.size:  # ... where the subdivision towards the point nearest to P stays shallow
            dist = _distance_from_p(verts[ill], counts[ill], n[ill], d[ill], s[ill])
            ill = ill[diam[ill] <= FAR_RATIO * dist * 2.0**MAX_LEVEL]
        if ill.size:
            _, Mq, ok = _quadrature_moment(verts[ill], counts[ill], N[ill], d[ill], cen[ill], MAX_LEVEL)
            M[ill[ok]] = Mq[ok]
    if np.any(far):
        a, b, valid = _edges(verts[far], counts[far])
        Ff[far] = _dot(N[far], _vector_irradiance(a, b, valid, s[far]))
        M[far] = _quadrature_moment(verts[far], counts[far], N[far], d[far], cen[far], 0)[1]
    return Ff, M


def first_moment(verts, counts, normal, plane_normal):
    """First moment of the form factor of each fragment about the receiver point P.

    verts (F, K, 3) float: P-local fragment vertices (convex, planar, in the upper half-space
    ``N·x ≥ 0``, plane not through P), padded past ``counts`` (F,) int (≥ 3) by repeating the last
    vertex; normal (F, 3) or (3,): receiver unit normal N; plane_normal (F, 3): unit normal of each
    fragment's plane (either orientation).

    Returns G (F, 3) float64 = ∫_frag x cosθ_P cosθ_x / (π r²) dA(x), in the units of ``verts``.
    Identity: ``G·n = (n·x on the plane) × F``. Fragments whose plane contains P, or degenerate
    (zero-area) fragments, give 0. Method and error bound: see the module docstring.
    """
    return _moments(verts, counts, normal, plane_normal)[1]


def linear_irradiance(verts, counts, normal, plane_normal, tri_vertices, tri_values, form_factor=None):
    """Contribution ``∫_frag L dF`` (F, C) of fragments of triangles with linearly varying radiance.

    verts (F, K, 3), counts (F,), normal (F, 3) or (3,), plane_normal (F, 3): as in
    :func:`first_moment`. tri_vertices (F, 3, 3): P-local corners of the source triangle each fragment
    lies in; tri_values (F, 3, C): values at those corners (C channels, e.g. linear RGB radiance in
    W sr⁻¹ m⁻²). The affine interpolant ``L(x)`` (barycentric) is evaluated at the fragment's vertex
    centroid ``x_c`` and the result is ``L(x_c)·F + g·∫(x − x_c) dF`` (the same as ``L0·F + g·G``,
    but without the cancellation of ``L0 = L(P)`` for small triangles far from P). form_factor (F,):
    the fragments' form factors if already known (else Lambert's contour integral is used).

    Returns (F, C) float64 in the units of the values: the fragment's term ``L_i F_i`` of the paper's
    irradiance sum (eq. 2/3, ``H_P = Σ_i L_i F_i``) with ``L_i`` varying over the fragment. With equal
    corner values ``v`` it is exactly ``v × F`` (the gradient is then exactly zero).
    """
    verts = np.asarray(verts, dtype=np.float64)
    Fn, K, _ = verts.shape
    counts = np.asarray(counts, dtype=np.int64).reshape(Fn)
    tv = np.asarray(tri_vertices, dtype=np.float64).reshape(Fn, 3, 3)
    vals = np.asarray(tri_values, dtype=np.float64)
    if vals.ndim != 3 or vals.shape[:2] != (Fn, 3):
        raise ValueError(f"tri_values must have shape (F, 3, C), got {vals.shape}")
    vmask = np.arange(K)[None, :] < counts[:, None]
    xc = np.sum(np.where(vmask[..., None], verts, 0.0), axis=1) / np.maximum(counts, 1)[:, None]
    Fl, M = _moments(verts, counts, normal, plane_normal, centre=xc)
    Ff = Fl if form_factor is None else np.asarray(form_factor, dtype=np.float64).reshape(Fn)
    # affine interpolant: gradient (F, 3, C) from barycentric gradients
    e1 = tv[:, 1] - tv[:, 0]
    e2 = tv[:, 2] - tv[:, 0]
    nt = np.cross(e1, e2)
    a2 = _dot(nt, nt)
    okt = a2 > 0
    inv = np.where(okt, 1.0 / np.where(okt, a2, 1.0), 0.0)
    gl1 = np.cross(e2, nt) * inv[:, None]
    gl2 = np.cross(nt, e1) * inv[:, None]
    dv1 = vals[:, 1] - vals[:, 0]
    dv2 = vals[:, 2] - vals[:, 0]
    g = gl1[:, :, None] * dv1[:, None, :] + gl2[:, :, None] * dv2[:, None, :]
    vc = vals[:, 0] + np.einsum("fic,fi->fc", g, xc - tv[:, 0])
    return vc * Ff[:, None] + np.einsum("fic,fi->fc", g, M)
