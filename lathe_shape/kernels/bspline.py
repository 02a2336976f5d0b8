"""Exact ray intersection with a revolved cubic B-spline (method.md, Method 2).

Pure Dr.Jit (float32, any JIT variant of Mitsuba); no plugin code. All
functions work in the lathe's LOCAL frame, whose axis is +z, and are
traceable inside an outer symbolic loop (no ``dr.eval``, no per-ray Python).

Surface of segment ``i`` (eqs. 13-14), ``t`` in [0, 1]::

    x^2 + y^2 = R_i(t)^2,    z = Z_i(t)        (R_i, Z_i cubic in t)

Ray ``o + s d``. With ``W(t) = Z(t) - o_z``, eq. 15 gives ``s = W(t) / d_z``;
substituting into the first equation and multiplying by ``d_z^2`` keeps a
polynomial of degree 6 in ``t`` that is also valid for ``d_z = 0``::

    F(t) = a W(t)^2 + 2 d_z b W(t) + d_z^2 (c - R(t)^2) = 0,
    a = d_x^2 + d_y^2,  b = o_x d_x + o_y d_y,  c = o_x^2 + o_y^2.

For a horizontal ray (``d_z = 0``) ``F = a W^2``: every root is a double
root, at ``Z(t) = o_z`` (the cubic of method.md), and the two ray
parameters follow from ``|o_xy + s d_xy| = R(t)``. Nearly horizontal rays give
close root pairs. The solver below therefore reports both sign-change roots
and tangent (double) roots of ``F``, and recovers ``s`` from whichever of the
two ray equations is better conditioned: eq. 15 for steep rays
(``d_z^2 >= a``), else ``s = s* -+ h`` from the radius (``s*`` the ray's
closest approach to the axis), taking the branch whose z agrees, or both for a
pair that float32 cannot resolve. Since ``F = a W^2`` has lost ``R`` for
horizontal rays, every root must also pass ``R(t) >= r0`` (the ray's distance
from the axis). The nearest hit is finally polished by two guarded Newton
steps on the unsquared (s, t) system ``z(s) = Z(t)``, ``|xy(s)|^2 = R(t)^2``.

Root finding (after C. Yuksel, "High-Performance Polynomial Root Finding for
Graphics", HPG 2022): the roots of ``F'`` split [0, 1] into intervals on which
``F`` is monotonic, so each holds at most one root, and it exists exactly when
``F`` changes sign across it. The critical points come from the same idea one
degree lower, recursively, down to a linear polynomial. Each bracketed root is
found by safeguarded Newton steps (bisection when a step leaves the bracket
or converges slowly; the answer is the evaluated point with the least |F|),
so no root with a sign change can be missed; the iteration count only limits
precision. A critical point where ``|F|`` is below the float32
evaluation error bound is a tangent (double) root: a grazing hit.

Culling: each segment has a padded bounding annular cylinder ``rmin <= r <=
rmax``, ``zmin <= z <= zmax``. The ray's z gives a linear s-interval and
``r(s)^2 <= rmax^2`` a quadratic one; ``r(s)^2`` is convex, so its maximum over
their intersection is at an endpoint and decides ``r >= rmin``. Only segments
whose box the ray meets before the current nearest hit are solved: a nested
loop skips the others, so the costly solve runs once per candidate segment.

Precision (traps.md, float32 cancellation): the ray origin is first moved to
where the ray enters the lathe's bounding cylinder, all coefficients are
built from that nearby origin, and ``s`` is shifted back at the end. The
root search runs on ``[-eps, 1 + eps]`` (``eps`` = ``_T_PAD``) so that hits on
a joint between two segments are found by both.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..bspline import power_coefficients
from .common import LatheGeometry, LatheHit

__all__ = [
    "BSplineData",
    "BSplineHit",
    "BSplineGeometry",
    "build_bspline_data",
    "intersect_bspline",
    "occluded_bspline",
    "bspline_geometry",
]

#: Floats per segment in ``BSplineData.seg``: R0..R3, Z0..Z3 (ascending
#: powers of t), then the padded bounds rmin, rmax, zmin, zmax.
_STRIDE = 12

#: Parameter overlap: roots are searched on [-_T_PAD, 1 + _T_PAD].
_T_PAD = 1e-3

#: Newton/bisection steps for critical points and for the roots of F.
_STEPS_CRIT = 10
_STEPS_ROOT = 12

#: Relative tolerance of the R(t) >= r0 test of a root (grazing rays).
_R0_REL_TOL = 1e-5

#: Steps below this (about the float32 spacing near t = 1) end a root search.
_T_RESOLUTION = 1e-7

#: Newton steps polishing the nearest hit on the (s, t) system.
_STEPS_POLISH = 2

#: Tangent-root threshold, in units of float32 epsilon times a bound on the
#: magnitude of the terms of F (its evaluation error is below that).
_TANGENT_ULPS = 8.0

#: Width of an unresolved root pair in z, in units of sqrt(tol / a).
_PAIR_WIDTH = 4.0


class BSplineData:
    """Packed, opaque segment buffers of one B-spline lathe (local frame).

    Attributes:
        seg: ``mi.Float`` of ``n_seg * 12`` values (see ``_STRIDE``).
        n_seg: opaque ``mi.UInt32`` (one element): number of segments.
        n_seg_host: the same as a Python int.
        cyl: opaque ``mi.Float`` values (rmax, zmin, zmax) of the padded
            bounding cylinder of the whole curve.
        scale: opaque ``mi.Float``: bounding-box diagonal of the profile.
    """

    def __init__(self, seg, n_seg, n_seg_host, cyl_rmax, cyl_zmin, cyl_zmax, scale):
        self.seg = seg
        self.n_seg = n_seg
        self.n_seg_host = n_seg_host
        self.cyl_rmax = cyl_rmax
        self.cyl_zmin = cyl_zmin
        self.cyl_zmax = cyl_zmax
        self.scale = scale


#: Result types (shared with the polyline kernel).
BSplineHit = LatheHit
BSplineGeometry = LatheGeometry


# ---------------------------------------------------------------------------
# Data
# ---------------------------------------------------------------------------

def _cubic_range(c: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """Exact (min, max) of the cubic ``c`` (ascending) on [lo, hi]."""
    ts = [lo, hi]
    if np.any(c[1:] != 0):
        for root in np.roots([3 * c[3], 2 * c[2], c[1]]):
            if abs(root.imag) < 1e-12 and lo < root.real < hi:
                ts.append(float(root.real))
    v = np.polynomial.polynomial.polyval(np.array(ts), c)
    return float(v.min()), float(v.max())


def build_bspline_data(seg_ctrl: np.ndarray) -> BSplineData:
    """Pack validated per-segment control points (from
    :func:`lathe_shape.bspline.bspline_segments`, oriented clockwise) into
    opaque Dr.Jit buffers, with padded per-segment bounds and the bounding
    cylinder. Call once per shape."""
    seg_ctrl = np.asarray(seg_ctrl, dtype=np.float64)
    coef = power_coefficients(seg_ctrl)  # (n_seg, 2, 4)
    n_seg = len(coef)
    pts = seg_ctrl.reshape(-1, 2)
    scale = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0
    lo, hi = -_T_PAD, 1.0 + _T_PAD
    # Absolute padding: float32 rounding of the data and of the ray.
    pad = 1e-5 * scale
    table = np.zeros((n_seg, _STRIDE))
    for i in range(n_seg):
        rmin, rmax = _cubic_range(coef[i, 0], lo, hi)
        zmin, zmax = _cubic_range(coef[i, 1], lo, hi)
        table[i, 0:4] = coef[i, 0]
        table[i, 4:8] = coef[i, 1]
        table[i, 8:12] = [max(rmin - pad, 0.0), rmax + pad, zmin - pad, zmax + pad]

    def opaque(value, cls=mi.Float):
        v = cls(value)
        dr.make_opaque(v)
        return v

    return BSplineData(
        seg=opaque(table.ravel()),
        n_seg=opaque(n_seg, mi.UInt32),
        n_seg_host=n_seg,
        cyl_rmax=opaque(float(table[:, 9].max())),
        cyl_zmin=opaque(float(table[:, 10].min())),
        cyl_zmax=opaque(float(table[:, 11].max())),
        scale=opaque(scale),
    )


# ---------------------------------------------------------------------------
# Polynomial helpers (unrolled per degree, vectorized over lanes)
# ---------------------------------------------------------------------------

def _polyval(c: list, x):
    """Horner evaluation of ascending coefficients ``c`` at ``x``."""
    v = c[-1]
    for ck in reversed(c[:-1]):
        v = dr.fma(v, x, ck)
    return v


def _polyval_d(c: list, x):
    """Value and first derivative of ascending coefficients ``c`` at ``x``."""
    v, dv = c[-1], mi.Float(0)
    for ck in reversed(c[:-1]):
        dv = dr.fma(dv, x, v)
        v = dr.fma(v, x, ck)
    return v, dv


def _polyder(c: list) -> list:
    return [c[k] * float(k) for k in range(1, len(c))]


def _polymul(p: list, q: list) -> list:
    out = [None] * (len(p) + len(q) - 1)
    for i, pi in enumerate(p):
        for j, qj in enumerate(q):
            out[i + j] = pi * qj if out[i + j] is None else dr.fma(pi, qj, out[i + j])
    return out


def _bracket_root(c: list, dc: list, x0, x1, f0, f1, steps: int):
    """Root of the polynomial ``c`` (derivative ``dc``) on [x0, x1], where it
    is monotonic; ``f0``, ``f1`` are its values at the ends.

    Returns ``(x, found)``. ``found``: ``f0`` and ``f1`` differ in sign (or
    one is 0), so exactly one root lies in the bracket. It is refined by
    safeguarded Newton steps (as ``rtsafe`` in Numerical Recipes): a step
    that would leave the bracket, or that did not halve the previous one,
    is replaced by bisection, so the bracket shrinks at least geometrically;
    the result is the evaluated point with the least ``|f|`` (always inside
    the bracket). Without a sign change ``x`` is ``x1``
    (this keeps the list of critical points sorted for the next level).
    """
    found = ((f0 <= 0) & (f1 >= 0)) | ((f0 >= 0) & (f1 <= 0))
    neg0 = f0 < 0
    a, b = mi.Float(x0), mi.Float(x1)  # bracket; f(a) has the sign of f0
    x = 0.5 * (a + b)                  # current estimate
    dx_old = b - a                     # step before last
    dx = mi.Float(dx_old)              # last step
    done = ~found                      # converged (or nothing to find)
    best_x = mi.Float(x)               # evaluated point with the least |f|
    best_f = mi.Float(dr.inf)
    for _ in range(steps):
        f, df = _polyval_d(c, x)
        # Near the root f is float32 noise, and the steps below may then
        # bisect away from it; the least |f| seen is the answer.
        better = dr.abs(f) < best_f
        best_x = dr.select(better, x, best_x)
        best_f = dr.select(better, dr.abs(f), best_f)
        left = (f < 0) == neg0
        a = dr.select(left, x, a)
        b = dr.select(left, b, x)
        # Converged: an exact zero, or a Newton step below float32
        # resolution of t (checked first: the test below would then pick
        # bisection and jump away from the root).
        done |= (f == 0) | (dr.abs(f) <= _T_RESOLUTION * dr.abs(df))
        # Newton unless it leaves [a, b] or converges slower than bisection.
        xn = x - f / df
        newton = (df != 0) & (xn >= a) & (xn <= b) & (dr.abs(2.0 * f) <= dr.abs(dx_old * df))
        dx_old = dx
        x_new = dr.select(newton, xn, 0.5 * (a + b))
        dx = x_new - x
        x = dr.select(done, x, x_new)
    x = dr.select(f0 == 0, x0, dr.select(f1 == 0, x1, best_x))
    return dr.select(found, x, x1), found


def _isolate_critical(derivs: list, lo, hi) -> list:
    """Sorted critical points of ``derivs[0]`` (degree k) on [lo, hi]: the
    roots of its derivative, found level by level from the linear
    ``derivs[-1]`` up. ``derivs[j]`` is the j-th derivative of ``derivs[0]``.
    Missing points are filled with interval ends (harmless: they only split a
    monotonic interval). Returns k - 1 values."""
    # The root of the linear derivs[-1] is the critical point of derivs[-2].
    lin = derivs[-1]
    x = dr.select(lin[1] != 0, -lin[0] / lin[1], hi)
    x = dr.select(dr.isfinite(x), x, hi)
    crit = [dr.clip(x, lo, hi)]
    # Levels of degree 2 .. k-1: each turns its critical points into its
    # roots, which are the critical points of the level above.
    for level in range(len(derivs) - 2, 0, -1):
        c = derivs[level]
        dc = derivs[level + 1]
        xs = [lo] + crit + [hi]
        fs = [_polyval(c, xk) for xk in xs]
        crit = []
        for j in range(len(xs) - 1):
            r, _ = _bracket_root(c, dc, xs[j], xs[j + 1], fs[j], fs[j + 1], _STEPS_CRIT)
            crit.append(r)
    return crit


# ---------------------------------------------------------------------------
# Ray setup and culling
# ---------------------------------------------------------------------------

class _Ray:
    """Ray quantities in the shifted frame (unit direction, origin near the
    bounding cylinder); ``s`` here is a length along the unit direction."""

    def __init__(self, o, dh, a, b, c, s_star, r0sq, lo, hi):
        self.o, self.dh = o, dh
        self.a, self.b, self.c = a, b, c      # a = d_xy.d_xy, b = o_xy.d_xy, c = o_xy.o_xy
        self.s_star, self.r0sq = s_star, r0sq  # closest approach to the axis (xy)
        self.lo, self.hi = lo, hi              # accepted open s-interval (lo, hi)


def _xy_terms(o, dh):
    a = dr.fma(dh.x, dh.x, dh.y * dh.y)
    b = dr.fma(o.x, dh.x, o.y * dh.y)
    c = dr.fma(o.x, o.x, o.y * o.y)
    horiz = a > 1e-12
    s_star = dr.select(horiz, -b / a, 0.0)
    cross = dr.fma(o.x, dh.y, -o.y * dh.x)
    r0sq = dr.select(horiz, cross * cross / a, c)
    return a, b, c, s_star, r0sq


def _slab(o, dh, a, s_star, r0sq, rmax, zmin, zmax):
    """s-interval where the ray is inside the annular box's outer cylinder
    ``r <= rmax`` and its slab ``zmin <= z <= zmax`` (empty: lo > hi)."""
    # z: linear in s.
    inv_dz = dr.rcp(dh.z)
    s1 = (zmin - o.z) * inv_dz
    s2 = (zmax - o.z) * inv_dz
    flat = dh.z == 0
    inside_z = (o.z >= zmin) & (o.z <= zmax)
    zlo = dr.select(flat, dr.select(inside_z, -dr.inf, dr.inf), dr.minimum(s1, s2))
    zhi = dr.select(flat, dr.select(inside_z, dr.inf, -dr.inf), dr.maximum(s1, s2))
    # r^2(s) = a (s - s*)^2 + r0^2 <= rmax^2: quadratic, symmetric about s*.
    disc = rmax * rmax - r0sq
    vertical = a <= 1e-12
    h = dr.sqrt(dr.maximum(disc, 0.0) / dr.select(vertical, 1.0, a))
    rlo = dr.select(vertical, -dr.inf, s_star - h)
    rhi = dr.select(vertical, dr.inf, s_star + h)
    rlo = dr.select(disc >= 0, rlo, dr.inf)
    rhi = dr.select(disc >= 0, rhi, -dr.inf)
    return dr.maximum(zlo, rlo), dr.minimum(zhi, rhi)


def _setup(data: BSplineData, o, d, tmax, active):
    """Unit direction, bounding-cylinder clip, origin shift."""
    dn = dr.norm(d)
    dh = d / dn
    a, b, c, s_star, r0sq = _xy_terms(o, dh)
    c_lo, c_hi = _slab(o, dh, a, s_star, r0sq, data.cyl_rmax, data.cyl_zmin, data.cyl_zmax)
    s_max = tmax * dn
    active = active & (dn > 0) & (c_lo <= c_hi) & (c_hi > 0) & (c_lo < s_max)
    shift = dr.select(active, dr.maximum(c_lo, 0.0), 0.0)
    o2 = mi.Point3f(dr.fma(dh.x, shift, o.x), dr.fma(dh.y, shift, o.y), dr.fma(dh.z, shift, o.z))
    a, b, c, s_star, r0sq = _xy_terms(o2, dh)
    ray = _Ray(o2, dh, a, b, c, s_star, r0sq, -shift, s_max - shift)
    return ray, active, shift, dn


def _box_pass(data: BSplineData, i, ray: _Ray, best, active):
    """Whether the ray meets segment ``i``'s annular box within (lo, best)."""
    base = i * _STRIDE
    rmin = dr.gather(mi.Float, data.seg, base + 8, active)
    rmax = dr.gather(mi.Float, data.seg, base + 9, active)
    zmin = dr.gather(mi.Float, data.seg, base + 10, active)
    zmax = dr.gather(mi.Float, data.seg, base + 11, active)
    s0, s1 = _slab(ray.o, ray.dh, ray.a, ray.s_star, ray.r0sq, rmax, zmin, zmax)
    s0 = dr.maximum(s0, ray.lo)
    s1 = dr.minimum(s1, best)
    # r(s)^2 is convex: its maximum over [s0, s1] is at an endpoint.
    e0 = s0 - ray.s_star
    e1 = s1 - ray.s_star
    r2max = dr.fma(ray.a, dr.maximum(e0 * e0, e1 * e1), ray.r0sq)
    return active & (s0 <= s1) & (r2max >= rmin * rmin)


# ---------------------------------------------------------------------------
# Per-segment solve
# ---------------------------------------------------------------------------

def _solve_segment(data: BSplineData, i, ray: _Ray, best_s, best_u, best_seg, m):
    """Intersect segment ``i`` (lanes ``m``); return the updated nearest hit."""
    base = i * _STRIDE
    R = [dr.gather(mi.Float, data.seg, base + k, m) for k in range(4)]
    Z = [dr.gather(mi.Float, data.seg, base + 4 + k, m) for k in range(4)]
    o, dh = ray.o, ray.dh
    dz = dh.z
    W = [Z[0] - o.z] + Z[1:]
    # F(t) = a W^2 + 2 d_z b W + d_z^2 (c - R^2)      (eqs. 14-15, times d_z^2)
    W2 = _polymul(W, W)
    R2 = _polymul(R, R)
    k1 = 2.0 * dz * ray.b
    k2 = dz * dz
    F = [ray.a * W2[k] - k2 * R2[k] for k in range(7)]
    for k in range(4):
        F[k] = dr.fma(k1, W[k], F[k])
    F[0] = dr.fma(k2, ray.c, F[0])
    # Bound on the size of F's terms on [0, 1]: float32 error scale.
    sw = dr.abs(W[0]) + dr.abs(W[1]) + dr.abs(W[2]) + dr.abs(W[3])
    sr = dr.abs(R[0]) + dr.abs(R[1]) + dr.abs(R[2]) + dr.abs(R[3])
    bound = ray.a * sw * sw + dr.abs(k1) * sw + k2 * (ray.c + sr * sr)
    tol = _TANGENT_ULPS * dr.epsilon(mi.Float) * bound

    lo, hi = mi.Float(-_T_PAD), mi.Float(1.0 + _T_PAD)
    derivs = [F]
    for _ in range(5):
        derivs.append(_polyder(derivs[-1]))
    crit = _isolate_critical(derivs, lo, hi)
    xs = [lo] + crit + [hi]
    fs = [_polyval(F, xk) for xk in xs]
    steep = k2 >= ray.a
    inv_dz = dr.rcp(dz)
    inv_a = dr.rcp(dr.maximum(ray.a, 1e-30))
    # |F| <= tol near a root pair allows |W1 - W2| up to ~2 sqrt(tol / a).
    z_tol = _PAIR_WIDTH * dr.sqrt(tol * inv_a)
    for j in range(len(xs) - 1):
        t, found = _bracket_root(F, derivs[1], xs[j], xs[j + 1], fs[j], fs[j + 1], _STEPS_ROOT)
        # No sign change: a tangent (double) root at the endpoint with the
        # smaller |F|, if that is within float32 noise of 0.
        near0 = dr.abs(fs[j]) <= dr.abs(fs[j + 1])
        t_tan = dr.select(near0, xs[j], xs[j + 1])
        tangent = ~found & (dr.minimum(dr.abs(fs[j]), dr.abs(fs[j + 1])) <= tol)
        t = dr.select(found, t, t_tan)
        Rt = _polyval(R, t)
        Zt = _polyval(Z, t)
        # A real hit has R(t) >= the ray's distance r0 from the axis. For
        # (nearly) horizontal rays F ~ a W^2 has lost R altogether, and its
        # tangent roots at Z(t) = o_z must be checked against it.
        ok = m & (found | tangent) & (Rt * Rt >= ray.r0sq * (1.0 - _R0_REL_TOL))
        # s from eq. 15 for steep rays; else from |o_xy + s d_xy| = R(t),
        # s = s* -+ h, choosing the branch(es) consistent with z.
        s_z = (Zt - o.z) * inv_dz
        h = dr.sqrt(dr.maximum(dr.fma(Rt, Rt, -ray.r0sq), 0.0) * inv_a)
        s1 = ray.s_star - h
        s2 = ray.s_star + h
        e1 = dr.abs(dr.fma(s1, dz, o.z) - Zt)
        e2 = dr.abs(dr.fma(s2, dz, o.z) - Zt)
        # A root pair of a nearly horizontal ray that float32 cannot resolve
        # (a tangent root, or a root next to a critical point where |F| is
        # within noise) stands for both branches: keep both when both z
        # errors are within the pair width allowed by the noise of F.
        near_pair = tangent | (found & (dr.minimum(dr.abs(fs[j]), dr.abs(fs[j + 1])) <= tol))
        both = near_pair & (dr.maximum(e1, e2) <= z_tol)
        cand_a = dr.select(steep, s_z, s1)
        ok_a = ok & (steep | (e1 <= e2) | both)
        ok_b = ok & ~steep & ((e2 < e1) | both)
        for s, oks in ((cand_a, ok_a), (s2, ok_b)):
            take = oks & (s > ray.lo) & (s < best_s) & dr.isfinite(s)
            best_s = dr.select(take, s, best_s)
            best_u = dr.select(take, t, best_u)
            best_seg = dr.select(take, i, best_seg)
    return best_s, best_u, best_seg


@dr.syntax
def _trace(data: BSplineData, o, d, tmax, active, shadow: bool):
    ray, active, shift, dn = _setup(data, o, d, tmax, mi.Bool(active))
    n = data.n_seg
    best_s = mi.Float(ray.hi)   # nearest accepted s so far (shifted frame)
    best_u = mi.Float(0.0)      # its curve parameter
    best_seg = mi.UInt32(0)     # its segment
    hit = mi.Bool(False)        # a hit was found (ends shadow rays)
    i = mi.UInt32(0)            # next segment to consider
    while active & (i < n) & ~(hit & shadow):
        # Skip segments whose annular box the ray misses before best_s.
        while active & (i < n) & ~_box_pass(data, i, ray, best_s, active & (i < n)):
            i += 1
        m = active & (i < n)
        prev = mi.Float(best_s)
        best_s, best_u, best_seg = _solve_segment(data, i, ray, best_s, best_u, best_seg, m)
        hit |= best_s < prev
        i += 1
    valid = hit & (best_s < ray.hi)
    if not shadow:
        best_s, best_u = _polish(data, ray, best_s, best_u, best_seg, valid)
    t = dr.select(valid, (best_s + shift) / dn, dr.inf)
    return BSplineHit(t=t, seg=best_seg, u=dr.clip(best_u, 0.0, 1.0), valid=valid)


def _polish(data: BSplineData, ray: _Ray, s, t, seg, active):
    """Newton steps on the geometric system of the hit (eqs. 13-15)::

        g1 = o_z + s d_z - Z(t) = 0,   g2 = |o_xy + s d_xy|^2 - R(t)^2 = 0.

    The roots of F are limited by float32 cancellation among its terms (an
    error in t of up to ~1e-3 on steep rays along near-vertical walls);
    these residuals are not. A step is kept only when the Jacobian is well
    conditioned and it stays small and on the segment (grazing hits keep the
    root-finder's answer)."""
    base = seg * _STRIDE
    R = [dr.gather(mi.Float, data.seg, base + k, active) for k in range(4)]
    Z = [dr.gather(mi.Float, data.seg, base + 4 + k, active) for k in range(4)]
    o, dh = ray.o, ray.dh
    for _ in range(_STEPS_POLISH):
        Rt, dR = _polyval_d(R, t)
        Zt, dZ = _polyval_d(Z, t)
        qx = dr.fma(dh.x, s, o.x)
        qy = dr.fma(dh.y, s, o.y)
        g1 = dr.fma(dh.z, s, o.z) - Zt
        g2 = dr.fma(qx, qx, dr.fma(qy, qy, -Rt * Rt))
        qd = dr.fma(qx, dh.x, qy * dh.y)
        # Jacobian [[d_z, -Z'], [2 q.d, -2 R R']].
        j22 = -2.0 * Rt * dR
        j21 = 2.0 * qd
        det = dr.fma(dh.z, j22, dZ * j21)
        scale_j = (dr.abs(dh.z) + dr.abs(j21)) * (dr.abs(dZ) + dr.abs(j22))
        ds = -(j22 * g1 + dZ * g2) / det
        dt = -(dh.z * g2 - j21 * g1) / det
        ok = active & (dr.abs(det) > 1e-4 * scale_j) & (dr.abs(dt) < 0.01)
        ok &= (t + dt >= -_T_PAD) & (t + dt <= 1.0 + _T_PAD) & (s + ds > ray.lo)
        s = dr.select(ok, s + ds, s)
        t = dr.select(ok, t + dt, t)
    return s, t


def intersect_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f,
                      tmax: mi.Float, active: mi.Bool) -> BSplineHit:
    """Nearest hit of the rays ``o + s d`` (local frame, ``d`` not
    necessarily unit) with ``0 < s < tmax`` on the revolved B-spline."""
    return _trace(data, o, d, mi.Float(tmax), active, False)


def occluded_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f,
                     tmax: mi.Float, active: mi.Bool) -> mi.Bool:
    """Whether the rays hit the surface at some ``0 < s < tmax`` (stops at
    the first hit found, not necessarily the nearest)."""
    return _trace(data, o, d, mi.Float(tmax), active, True).valid


# ---------------------------------------------------------------------------
# Geometry
# ---------------------------------------------------------------------------

def bspline_geometry(data: BSplineData, p: mi.Point3f, seg: mi.UInt32,
                     u: mi.Float) -> BSplineGeometry:
    """Outward normal and parametrisation at a local hit point ``p`` on
    segment ``seg``, curve parameter ``u``.

    Normal (eq. 16): the left-hand normal ``(-Z', R')`` of the tangent
    ``(R', Z')``, outward for a clockwise profile, rotated to the hit's
    azimuth (``cos = 1, sin = 0`` on the axis). Where the tangent vanishes
    (the tripled end points of an open profile) the segment's chord gives its
    limit direction. ``uv = (azimuth / 2 pi, (seg + u) / n_seg)``.
    """
    base = seg * _STRIDE
    R = [dr.gather(mi.Float, data.seg, base + k) for k in range(4)]
    Z = [dr.gather(mi.Float, data.seg, base + 4 + k) for k in range(4)]
    Rt, dR = _polyval_d(R, u)
    _, dZ = _polyval_d(Z, u)
    chord_r = R[1] + R[2] + R[3]
    chord_z = Z[1] + Z[2] + Z[3]
    speed2 = dr.fma(dR, dR, dZ * dZ)
    degenerate = speed2 <= 1e-24 * dr.fma(chord_r, chord_r, chord_z * chord_z)
    tr = dr.select(degenerate, chord_r, dR)
    tz = dr.select(degenerate, chord_z, dZ)
    inv = dr.rsqrt(dr.fma(tr, tr, tz * tz))
    nr, nz = -tz * inv, tr * inv

    rho = dr.sqrt(dr.fma(p.x, p.x, p.y * p.y))
    on_axis = rho <= 1e-7 * data.scale
    cos_p = dr.select(on_axis, 1.0, p.x / rho)
    sin_p = dr.select(on_axis, 0.0, p.y / rho)
    n = mi.Vector3f(nr * cos_p, nr * sin_p, nz)

    phi = dr.atan2(sin_p, cos_p)
    phi = dr.select(phi < 0, phi + 2 * math.pi, phi)
    n_seg = mi.Float(data.n_seg)
    uv = mi.Point2f(phi * (0.5 / math.pi), (mi.Float(seg) + u) / n_seg)
    dp_du = mi.Vector3f(-Rt * sin_p, Rt * cos_p, 0.0) * (2 * math.pi)
    dp_dv = mi.Vector3f(dR * cos_p, dR * sin_p, dZ) * n_seg
    return BSplineGeometry(n=n, sh_n=mi.Vector3f(n), uv=uv, dp_du=dp_du, dp_dv=dp_dv)
