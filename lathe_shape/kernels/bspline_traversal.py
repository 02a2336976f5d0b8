"""Ray set-up and culling for the B-spline kernel (kernels/bspline.py):
the kernel's ray, entering the BVH's annular boxes, and the Bernstein hull
tests that cull leaves."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from . import common
from .bspline_data import (
    _TANGENT_ULPS,
    BSplineData,
)
from .bspline_roots import (
    _by_form,
)
from .common import (
    LatheRay,
)

# ---------------------------------------------------------------------------
# Ray setup and culling
# ---------------------------------------------------------------------------

class _Ray(LatheRay):
    """The common ray set-up (kernels/common.py) for a unit direction, so that
    ``s`` is a length, plus the ray's closest approach to the axis."""

    def __init__(self, data: BSplineData, o, d, tmax, active, mode: str = "nearest"):
        super().__init__(data, o, d, tmax, active)
        self.mode = mode  # how crossings are taken (_offer)
        self.after = None  # keyed: the crossing (s, key) to find the next one after
        self.s_positive = self.s_lo  # hits need s > this (t > 0), whatever s_lo a walk sets
        self.t_after = None  # ... or, after another lathe's crossing, its t
        self.data = data  # (keyed: _offer polishes each crossing)
        self.slack = 0.0  # keyed: how far past the best boxes are visited
        a, b, c = self.a, self.b, self.c      # a = d_xy.d_xy, b = o_xy.d_xy, c = o_xy.o_xy
        horiz = a > 1e-12
        # Closest approach to the axis (xy): s*, at distance sqrt(r0sq)
        self.s_star = dr.select(horiz, -b / a, 0.0)
        self.r0sq = dr.select(horiz, self.cross * self.cross / a, c)
        self.zc = dr.fma(self.d.z, self.s_star, self.o.z)  # z* = z at the closest approach
        self.inv_a = dr.rcp(dr.maximum(a, 1e-30))

    def reaches(self, lo, hi, r2):
        """Whether ``r(s)^2 = a (s - s*)^2 + r0^2`` reaches ``r2`` on ``[lo,
        hi]``: its largest value there is at the end farther from ``s*``."""
        e0 = lo - self.s_star
        e1 = hi - self.s_star
        return dr.fma(self.a, dr.maximum(e0 * e0, e1 * e1), self.r0sq) >= r2


def _box_enter(ray: _Ray, box, best, active):
    """Whether the ray meets the annular box ``(rmax, rmin^2, zmin, zmax)``
    within (s_lo, best): on the part [lo, hi] of that interval within the
    box's z slab, ``r(s)^2`` (continuous and convex) takes every value
    between its least, at ``s*`` clipped to [lo, hi], and its largest, at an
    end; the box is met iff the first is at most ``rmax^2`` and the second at
    least ``rmin^2`` (no square root, unlike the interval where ``r <=
    rmax``)."""
    zl = (box.z - ray.o.z) * ray.inv_dz
    zh = (box.w - ray.o.z) * ray.inv_dz
    lo = dr.maximum(dr.minimum(zl, zh), ray.s_lo)
    hi = dr.minimum(dr.maximum(zl, zh), best)
    e = dr.clip(ray.s_star, lo, hi) - ray.s_star
    inner = dr.fma(ray.a, e * e, ray.r0sq) <= box.x * box.x
    return active & (lo <= hi) & inner & ray.reaches(lo, hi, box.y)


def _into_box(ray: _Ray, box, s):
    """``s`` moved (where needed) to the nearest point at which the ray is
    within the annular box ``(rmax, rmin^2, zmin, zmax)`` as
    :func:`_box_enter` computes it: in the box's z slab, with ``r(s)^2 =
    a (s - s*)^2 + r0^2`` between ``rmin^2`` and ``rmax^2`` (a few ulps
    inside), on either side of ``s*``. :func:`_box_enter` is monotonic in
    the box and in its interval of ``s``, so a leaf's crossing moved into
    its box is never culled, by its own box or by an inner node's, while it
    lies between the walk's last crossing and the best one so far (the
    keyed walk, :func:`_offer`). Only a crossing that the root finder
    places outside its leaf's box (an ill-conditioned root) moves."""
    zl = (box.z - ray.o.z) * ray.inv_dz
    zh = (box.w - ray.o.z) * ray.inv_dz
    lo, hi = dr.minimum(zl, zh), dr.maximum(zl, zh)
    ulps = 4.0 * dr.epsilon(mi.Float)
    # The ray is within [rmin, rmax] where g <= |s - s*| <= g_max
    g = dr.sqrt(dr.maximum(box.y - ray.r0sq, 0.0) * ray.inv_a) * (1.0 + ulps)
    g_max = dr.sqrt(dr.maximum(box.x * box.x - ray.r0sq, 0.0) * ray.inv_a) * (1.0 - ulps)
    far = box.x * box.x < ray.r0sq
    best_s, best_d = mi.Float(s), mi.Float(dr.inf)
    for a, b in ((ray.s_star - g_max, ray.s_star - g), (ray.s_star + g, ray.s_star + g_max)):
        a, b = dr.maximum(a, lo), dr.minimum(b, hi)
        near = dr.clip(s, a, b)
        take = (a <= b) & ~far & (dr.abs(near - s) < best_d)
        best_s = dr.select(take, near, best_s)
        best_d = dr.select(take, dr.abs(near - s), best_d)
    return best_s


@dr.syntax
def _kept_in_box(ray: _Ray, box, s):
    """:func:`_into_box` where ``s`` is not already a point at which
    :func:`_box_enter` meets the box (the interval ``[s, s]``; every
    interval of ``s`` holding it meets it then too, as that test is
    monotonic): a packet whose crossings all lie in their boxes (nearly
    always) skips it."""
    zl = (box.z - ray.o.z) * ray.inv_dz
    zh = (box.w - ray.o.z) * ray.inv_dz
    e = s - ray.s_star
    r2 = dr.fma(ray.a, e * e, ray.r0sq)
    inside = (s >= dr.minimum(zl, zh)) & (s <= dr.maximum(zl, zh)) & (r2 <= box.x * box.x) & (r2 >= box.y)
    if ~inside:
        s = _into_box(ray, box, s)
    return s


def _bezier_square(p: list) -> list:
    """Bernstein coefficients (degree 6) of the square of a Bezier cubic:
    ``sum_{i+j=k} C(3,i) C(3,j) / C(6,k) p_i p_j``."""
    return [p[0] * p[0], p[0] * p[1],
            dr.fma(2.0 * p[0], p[2], 3.0 * p[1] * p[1]) * 0.2,
            dr.fma(p[0], p[3], 9.0 * p[1] * p[2]) * 0.1,
            dr.fma(2.0 * p[1], p[3], 3.0 * p[2] * p[2]) * 0.2,
            p[2] * p[3], p[3] * p[3]]


def _bezier_elevate(p: list) -> list:
    """Bernstein coefficients (degree 6) of a Bezier cubic: its product with
    the constant 1 (``sum_{i+j=k} C(3,i) C(3,j) / C(6,k) p_i``)."""
    return [p[0], (p[0] + p[1]) * 0.5, (p[0] + 3.0 * p[1] + p[2]) * 0.2,
            (p[0] + 9.0 * (p[1] + p[2]) + p[3]) * 0.05, (p[1] + 3.0 * p[2] + p[3]) * 0.2,
            (p[2] + p[3]) * 0.5, p[3]]


def _hull(Rb, Zb, ray: _Ray, squared=False):
    """Bernstein coefficients of ``F`` (eqs. 13-15, in the form of the module
    docstring) on a leaf from its Bezier cubics, and ``tol``: a bound on the
    float32 error of ``F`` and of these coefficients there. ``squared`` (a
    bool or a mask, :func:`_squared`): ``Rb`` holds ``R^2`` itself (eq. 20),
    not ``R``."""
    W = [Zb.x - ray.zc, Zb.y - ray.zc, Zb.z - ray.zc, Zb.w - ray.zc]
    R = [Rb.x, Rb.y, Rb.z, Rb.w]
    W2 = _bezier_square(W)
    R2 = _by_form(squared, lambda: _bezier_elevate(R), lambda: _bezier_square(R))
    k2 = ray.d.z * ray.d.z
    G = [dr.fma(ray.a, W2[k], -k2 * (R2[k] - ray.r0sq)) for k in range(7)]
    # |W(u)| <= max |W_b|, |R(u)| <= max |R_b| (convex hull); the bound on R^2.
    mw = dr.maximum(dr.maximum(dr.abs(W[0]), dr.abs(W[1])), dr.maximum(dr.abs(W[2]), dr.abs(W[3])))

    def largest(v):
        return dr.maximum(dr.maximum(v[0], v[1]), dr.maximum(v[2], v[3]))

    mr = _by_form(squared, lambda: largest([dr.abs(x) for x in R]), lambda: largest(R))
    bound = dr.fma(ray.a, mw * mw, k2 * (_by_form(squared, lambda: mr, lambda: mr * mr) + ray.r0sq))
    return G, _TANGENT_ULPS * dr.epsilon(mi.Float) * bound


def _one_sign(c: list, tol):
    """Whether all values of ``c`` exceed ``tol`` in magnitude with one sign."""
    lo, hi = c[0], c[0]
    for ck in c[1:]:
        lo = dr.minimum(lo, ck)
        hi = dr.maximum(hi, ck)
    return (lo > tol) | (hi < -tol)


def _bezier_to_power(b) -> list:
    """Ascending power coefficients of the Bezier cubic with control values
    ``b`` (a Vector4f)."""
    d1, d2, d3 = b.y - b.x, b.z - b.y, b.w - b.z
    return [b.x, 3.0 * d1, 3.0 * (d2 - d1), (d3 - d2) - (d2 - d1)]


def _visit(data: BSplineData, ray: _Ray, node, best, active):
    """One traversal step: ``(candidate, next node)``. A candidate is a leaf
    whose box the ray enters before ``best`` (:func:`_solve_leaf` tests its
    Bernstein hull)."""
    box = dr.gather(mi.Vector4f, data.nodes, node, active)
    link, is_leaf, leaf = common.bvh_link(data.links, node, active)
    enter = _box_enter(ray, box, best, active)
    cand = enter & is_leaf
    # Pre-order: descend into an entered inner node, else take its miss
    # link; stay on a candidate (it is solved next).
    nxt = dr.select(cand, node, common.bvh_next(node, link, is_leaf, enter))
    return cand, nxt
