"""Exact ray intersection with a revolved cubic B-spline (docs/method.md, Method 2).

Pure Dr.Jit (float32, any JIT variant of Mitsuba); no plugin code. All
functions work in the lathe's LOCAL frame, whose axis is +z, and are
traceable inside an outer symbolic loop (no ``dr.eval``, no per-ray Python).

Surface of segment ``i`` (eqs. 13-14), ``t`` in [0, 1]::

    x^2 + y^2 = R_i(t)^2,    z = Z_i(t)        (R_i, Z_i cubic in t)

Ray ``o + s d`` (unit ``d``), with ``a = d_x^2 + d_y^2``, ``s*`` the ray's
closest approach to the axis, ``r0`` its distance there and ``z* = o_z +
d_z s*``; the ray's radius obeys ``r(s)^2 = a (s - s*)^2 + r0^2``. Eq. 15
gives ``s = (Z(t) - o_z) / d_z``; substituting into the first equation and
multiplying by ``d_z^2`` keeps a polynomial of degree 6 in ``t`` that is also
valid for ``d_z = 0``::

    F(t) = a (Z(t) - z*)^2 - d_z^2 (R(t)^2 - r0^2) = 0.

(This equals ``|d_z o_xy + (Z - o_z) d_xy|^2 - d_z^2 R^2``: the ray's
projection into the (r, z) half plane is a hyperbola branch and ``F`` is its
implicit equation along the curve.) For a horizontal ray (``d_z = 0``) ``F =
a (Z - o_z)^2``: every root is a double root, at ``Z(t) = o_z`` (a cubic, eq.
14 with ``z = o_z``), and the two ray parameters follow from ``|o_xy + s d_xy| =
R(t)``. Nearly horizontal rays give close root pairs. The solver therefore
reports both sign-change roots and tangent (double) roots of ``F``, and
recovers ``s`` from whichever of the two ray equations is better
conditioned: eq. 15 for steep rays (``d_z^2 >= a``), else ``s = s* -+ h``
from the radius, taking the branch whose z agrees, or both for a pair that
float32 cannot resolve. Since ``F = a W^2`` has lost ``R`` for horizontal
rays, every root must also pass ``R(t) >= r0``. The nearest hit is finally
polished by two guarded Newton steps on the unsquared (s, t) system
``z(s) = Z(t)``, ``|xy(s)|^2 = R(t)^2``.

Squared radius given directly. A segment may give ``R(t)^2`` itself as a
cubic ``P(t)`` instead of ``R(t)`` (the ``sor`` kind, docs/method.md eqs.
19-20; :func:`build_cubic_data` with ``r_squared``): ``F`` then takes ``P``
where it squares ``R`` (degree 3 when ``Z`` is linear), and so do the hull,
the ``R >= r0`` test, the polish and the normal. Every other cubic kind
(Bezier, Catmull-Rom, quadratic; eqs. 17-18) arrives as power coefficients
of ``R`` and ``Z`` and is handled exactly like a B-spline.

Leaves. Every segment is cut, at the interior extrema of ``R`` and ``Z`` and
then evenly into pieces of at most ``_LEAF_T`` in ``t``, into leaves. A leaf
covers ``t = t0 + h u``, ``u`` in [0, 1] (no overlap with its neighbours),
and stores its cubics in that local parameter as Bernstein (Bezier) control
points, plus an exact, padded annular bounding box. Its first and last
control points are its joints: one float32 point per joint, stored bit for
bit alike in the two leaves that meet there (also where segments meet, and
where a closed curve closes). The kernel reads the control points (two
loads of four floats; the power form follows from them in a few
operations), and a crossing carries its leaf and ``u``: the
segment and its ``t`` are read once per ray, for the crossing taken.

Joints: parity first. A ray aimed at a joint may, after float32 rounding,
find a root on both leaves or on neither. Each leaf therefore first fixes
the parity of its crossings from the signs of ``F`` at its two joints (the
end values of its Bernstein form, computed from the shared points by the
same operations in both leaves; a point with ``R < r0`` counts as positive
whatever float32 says, since ``F`` is positive there): odd exactly when they
differ. ``F`` changes sign, strictly (0 counts as positive), on an odd
number of the leaf's monotonic intervals exactly then, and each such
interval reports one crossing; a tangent root reports two (see
:func:`_take_interval`). So the parities of all leaves add up to an even
number of crossings for every line through a closed profile: a ray that
enters leaves. The roots only say where those crossings are.

Walking a ray through its crossings. Restarting a ray past a hit (Mitsuba's
``spawn_ray`` offsets the origin) makes a new line and can skip a second
crossing closer than the offset. :func:`next_crossing_bspline` instead keeps
the ray's origin and asks for the crossing after the one just taken,
ordered by ray parameter, then by a key (leaf and root): each crossing of
the line is found exactly once. Its traversal culls boxes between the last
crossing and the best one so far, and keeps every crossing within its
leaf's box (:func:`_into_box`), so that no crossing in between is culled.
:func:`count_crossings_bspline` counts them all in one traversal.

Culling (the skeleton shared with the polyline kernel, kernels/common.py):
a bounding volume hierarchy over the leaves' annular boxes in the
(r, z) plane, stored four times as a threaded (stackless, pre-order with
miss links) array whose copies differ in child order; each ray takes the
copy that visits the lower / upper and outer / inner child first according
to the signs of ``d_z`` and of its radial velocity, so near leaves come first
and the nearest-hit interval shrinks early. A box is entered where ``z(s)``
is in its slab and ``r(s) <= rmax``; ``r(s)^2`` is convex, so its maximum
over that interval is at an end and decides ``r >= rmin``. A leaf whose box
is met within (lo, best) is then tested with the Bernstein form of ``F`` on
the leaf: the products ``R^2`` and ``(Z - z*)^2`` of Bezier cubics give the 7
Bernstein coefficients of ``F`` directly, and when all exceed the float32
error bound ``tol`` in magnitude with one sign (convex hull property), ``F``
has no root, not even a grazing one, on the leaf. Only the leaves that pass
(usually the few that the ray really crosses) are solved: an inner loop walks
the tree to the next entered leaf, so all lanes of a SIMD packet test and
solve together; the Bernstein test runs there, outside the walk (a walk
step with it is much slower, although a packet without a lane at a leaf
skips it), and a packet with no lane that passes skips the solve.

Root finding on a leaf (after C. Yuksel, "High-Performance Polynomial Root
Finding for Graphics", HPG 2022): the roots of ``F'`` split [0, 1] into
intervals on which ``F`` is monotonic, so each holds at most one root, and it
exists exactly when ``F`` changes sign across it. The critical points come
from the same idea one degree lower, recursively, down to a linear
polynomial. Leaves are short, so the chain can mostly stop early: when the
Bernstein coefficients of ``F'`` (first differences of those of ``F``) share
a sign beyond their error bound, ``F`` is monotonic and one bracketed search
suffices (most candidate leaves); else when those of ``F''`` (second
differences) do, ``F`` is convex or concave: one search where its ends
differ in sign beyond noise, else a single critical point and at most two
roots: three searches. Only the remaining lanes (about 1%) run the full
derivative chain (five levels, twenty searches). The extra work of each case
sits in a symbolic ``if``, which packets without such a lane skip. Each
bracketed root is found by safeguarded Newton steps (bisection when a step
leaves the bracket or converges slowly; the answer is the evaluated point
with the least ``|F|``, or the point after a last Newton step small enough
that the next would be below float32 resolution), so no root with a sign
change can be missed; the iteration count only limits precision; the steps
run in a symbolic loop that ends once all lanes of a packet converged. The
fast cases' searches share one loop; the derivative chain runs its levels
in one loop (each level's polynomial padded to one degree) and then its six
intervals in another. Code size matters more than the work of these rare
lanes: the LLVM code of the whole traversal gets slower with every inlined
search, although most packets never run one. A critical point where
``|F|`` is below ``tol`` is a tangent (double) root: a grazing hit.

Precision: in float32 the coefficients of ``F`` would lose most of their
digits to cancellation for a ray that starts far from the lathe, so the ray
set-up of kernels/common.py first moves the origin to where the ray enters
the lathe's bounding cylinder; all coefficients are built from that nearby
origin (with a unit direction, so ``s`` is a length) and ``s`` is shifted
back at the end. All data and rays are in the unit frame of
kernels/common.py (the profile divided by its size), so the pads and
thresholds below are relative to the profile whatever the user's units.

Modules: :mod:`.bspline_data` (the data and its numpy build),
:mod:`.bspline_roots` (the root finding's polynomial helpers and searches),
:mod:`.bspline_traversal` (ray set-up, box entry, hull culling); here the
per-leaf solve, the traversal loop, the polish, the public kernels and the
geometry. Every name of those modules is importable from here.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from . import common
from .bspline_data import (  # noqa: F401 (importable from here)
    _KEYS_PER_LEAF,
    _LEAF_STRIDE,
    _LEAF_T,
    _PAIR_WIDTH,
    _POLISH_REACH,
    _R0_REL_TOL,
    _STEPS_CRIT,
    _STEPS_POLISH,
    _STEPS_ROOT,
    _STRIDE,
    _T_FINAL,
    _T_PAD,
    _T_RESOLUTION,
    _TANGENT_ULPS,
    LEAF_STRIDE,
    STRIDE,
    BSplineData,
    BSplineGeometry,
    BSplineHit,
    _bezier,
    _cubic_range,
    _curve_hull,
    _leaf_pieces,
    _reparam,
    _shared_joints,
    build_bspline_data,
    build_cubic_data,
)
from .bspline_roots import (  # noqa: F401 (importable from here)
    _bracket_root,
    _bracket_roots,
    _by_form,
    _isolate_critical,
    _newton_step,
    _polyder,
    _polymul,
    _polyval,
    _polyval_d,
    _squared,
)
from .bspline_traversal import (  # noqa: F401 (importable from here)
    _bezier_elevate,
    _bezier_square,
    _bezier_to_power,
    _box_enter,
    _hull,
    _into_box,
    _kept_in_box,
    _one_sign,
    _Ray,
    _visit,
)
from .common import (
    to_unit_frame,
)

__all__ = [
    "BSplineData",
    "BSplineHit",
    "BSplineGeometry",
    "build_bspline_data",
    "build_cubic_data",
    "intersect_bspline",
    "occluded_bspline",
    "count_crossings_bspline",
    "next_crossing_bspline",
    "bspline_geometry",
    "STRIDE",
    "LEAF_STRIDE",
]

# ---------------------------------------------------------------------------
# Per-leaf solve
# ---------------------------------------------------------------------------

class _Best(metaclass=common.VariantStruct):
    """The crossings found so far on a ray: the first one in the ray's order
    (:func:`_offer`), ``s`` (moved frame, ``s_max``: none), its ``leaf`` and
    parameter ``u`` there (the segment and its parameter follow once, at the
    end of the traversal: :func:`_leaf_to_segment`) and crossing key
    ``key``, and ``count``, the number of crossings (counting rays only).
    Keyed rays order crossings by their polished ``s`` (eq. 31): ``raw`` is
    then the root finder's ``s`` that the polish starts from."""

    _FIELDS = {"s": "Float", "u": "Float", "leaf": "UInt32", "key": "UInt32", "count": "UInt32",
               "raw": "Float"}

    def __init__(self, s=None, u=None, leaf=None, key=None, count=None, raw=None) -> None:
        self.s = mi.Float(dr.inf) if s is None else s
        self.u = mi.Float(0.0) if u is None else u
        self.leaf = mi.UInt32(0) if leaf is None else leaf
        self.key = mi.UInt32(0) if key is None else key
        self.count = mi.UInt32(0) if count is None else count
        self.raw = self.s if raw is None else raw


def _offer(best: _Best, ray: _Ray, s, u, leaf, key, ok) -> _Best:
    """``best`` with the crossing ``(s, key)`` at parameter ``u`` of leaf
    ``leaf`` (lanes ``ok``) taken into account, as the ray's mode
    says: ``nearest``, the least ``s`` after ``s_lo`` (ties: the first
    offered); ``keyed``, the least ``(s, key)`` after ``ray.after`` (ties in
    ``s`` broken by the key, so that a walk through a ray's crossings finds
    each once); ``count``, every crossing after ``s_lo``."""
    ok = ok & dr.isfinite(s)
    if ray.mode == "count":
        return _Best(best.s, best.u, best.leaf, best.key,
                     best.count + mi.UInt32(ok & (s > ray.s_lo) & (s < ray.s_max)))
    if ray.mode == "keyed":
        # Ordered by the polished s, the place the walk returns (eq. 31: a
        # crossing's t then orders it among the other lathes' too, and a
        # lathe's own order agrees with its t)
        seg, u_seg = _leaf_to_segment(ray.data, _Best(s=s, u=u, leaf=leaf), ok)
        s_polished, _ = _polish(ray.data, ray, s, u_seg, seg, ok)
        after_s, after_key = ray.after
        take = ok & ((s_polished > after_s) | ((s_polished == after_s) & (key > after_key)))
        if ray.t_after is not None:
            # after another lathe's crossing: on this crossing's own t
            take &= (s_polished + ray.s_enter) * ray.t_scale > ray.t_after
        take &= (s_polished < best.s) | ((s_polished == best.s) & (key < best.key))
        return _Best(dr.select(take, s_polished, best.s), dr.select(take, u, best.u),
                     dr.select(take, leaf, best.leaf), dr.select(take, key, best.key), best.count,
                     dr.select(take, s, best.raw))
    take = ok & (s > ray.s_lo) & (s < best.s)
    return _Best(dr.select(take, s, best.s), dr.select(take, u, best.u),
                 dr.select(take, leaf, best.leaf), best.key, best.count)


class _Leaf:
    """A candidate leaf's cubics (local parameter u), F in power form and
    its error bound, and the first crossing key of the leaf
    (:func:`_offer`). Only the Bezier control points are read: the power
    form follows from them in a few operations (fewer loads)."""

    def __init__(self, data: BSplineData, node, leaf, ray: _Ray, m):
        base = leaf * (LEAF_STRIDE // 4)
        Rb = dr.gather(mi.Vector4f, data.leaf, base, m)
        Zb = dr.gather(mi.Vector4f, data.leaf, base + 1, m)
        self.leaf = leaf
        self.key = leaf * _KEYS_PER_LEAF
        if ray.mode == "keyed":
            # Crossings stay within the leaf's box (_into_box)
            self.box = dr.gather(mi.Vector4f, data.nodes, node, m)
        self.R = _bezier_to_power(Rb)
        self.Z = _bezier_to_power(Zb)
        self.squared = _squared(data)  # R holds R^2 (eq. 20)
        self.Gb, self.tol = _hull(Rb, Zb, ray, self.squared)
        # F at the leaf's ends, from the joints it shares with its
        # neighbours: their signs fix the parity of its crossings
        self.f0 = _side(self.Gb[0], _by_form(self.squared, lambda: Rb.x, lambda: Rb.x * Rb.x), ray)
        self.f1 = _side(self.Gb[6], _by_form(self.squared, lambda: Rb.w, lambda: Rb.w * Rb.w), ray)
        # F = a (Z - z*)^2 - d_z^2 (R^2 - r0^2)      (eqs. 13-15, times d_z^2)
        W = [self.Z[0] - ray.zc] + self.Z[1:]
        W2 = _polymul(W, W)
        R2 = _by_form(self.squared, lambda: self.R + [mi.Float(0.0)] * 3,
                      lambda: _polymul(self.R, self.R))
        R2[0] = R2[0] - ray.r0sq
        k2 = ray.d.z * ray.d.z
        self.F = [dr.fma(ray.a, W2[k], -k2 * R2[k]) for k in range(7)]
        self.dF = _polyder(self.F)


def _side(f, R2, ray: _Ray):
    """The value ``f`` of ``F`` at a curve point with ``R^2 = R2``, made
    non-negative where ``R < r0``: there ``F = a W^2 + d_z^2 (r0^2 - R^2)``
    is positive (the point lies inside the ray's surface of revolution),
    whatever float32 makes of it (for a nearly horizontal ray ``F`` is then
    ``a W^2`` up to noise, and a noisy sign would pair two phantom
    crossings). Only the sign is used: the parity of the crossings, strictly
    ``f < 0`` or not."""
    return dr.select(R2 < ray.r0sq * (1.0 - _R0_REL_TOL), dr.maximum(f, 0.0), f)


def _value(lf: _Leaf, ray: _Ray, x):
    """``F(x)`` on the leaf, for its sign (:func:`_side`)."""
    Rx = _polyval(lf.R, x)
    return _side(_polyval(lf.F, x), _by_form(lf.squared, lambda: Rx, lambda: Rx * Rx), ray)


def _interval_roots(lf: _Leaf, intervals: list) -> list:
    """The roots ``(u, found)`` of ``F`` on the intervals ``(x0, x1, f0, f1,
    mask)`` where it is monotonic (values ``f0``, ``f1`` at the ends), for
    :func:`_take_interval`: one loop for all (:func:`_bracket_roots`), a
    root where the signs of the ends differ (strictly)."""
    return _bracket_roots(lf.F, lf.dF, intervals, _STEPS_ROOT, strict=True)


def _take_interval(lf: _Leaf, ray: _Ray, x0, x1, f0, f1, root, best: _Best, m, key,
                   crit0=False, crit1=False) -> _Best:
    """The crossings of the ray on [x0, x1], where ``F`` is monotonic
    (values ``f0``, ``f1`` at the ends; ``root``: from
    :func:`_interval_roots`), offered to ``best`` (:func:`_offer`) with the
    keys ``key`` and ``key + 1``. ``crit0``, ``crit1``: whether the lower,
    upper end may be a critical point of ``F`` inside the leaf (False where
    it is known not to be one).

    Parity first: along the leaf's intervals ``f1`` of one is ``f0`` of the
    next, and the leaf's first and last values are ``F`` at its joints,
    evaluated bit for bit alike by both leaves that share one. An interval
    where ``f0 < 0`` and ``f1 < 0`` differ reports exactly one crossing, so
    every leaf reports as many crossings, modulo 2, as its joints' signs
    differ, and the leaves of a closed profile add up to an even number for
    every line. A tangent (double) root reports two crossings (both branches
    of a pair that float32 cannot resolve, else the same point twice): at
    the interval's upper end ``x1``, when ``|f1|`` is within float32 noise
    of 0 without a sign change (the lower end belongs to the interval
    before), where ``x1`` is a critical point inside the leaf (``crit1``).
    (At a joint ``F`` within noise of 0 is mostly a crossing that float32
    cannot place on either leaf, which one of them reports; a tangent there
    counts as none.) See the module docstring for the choice of ``s``."""
    o, dz = ray.o, ray.d.z
    tol = lf.tol
    u, found = root
    tangent = ~found & (dr.abs(f1) <= tol) & (x1 > x0) & (x1 < 1.0) & crit1
    u = dr.select(found, u, x1)
    Rt = _polyval(lf.R, u)
    R2t = _by_form(lf.squared, lambda: Rt, lambda: Rt * Rt)  # R(t)^2
    Zt, dZ = _polyval_d(lf.Z, u)
    # A real tangent has R(t) >= the ray's distance r0 from the axis. For
    # (nearly) horizontal rays F ~ a W^2 has lost R altogether, and its
    # tangent roots at Z(t) = o_z must be checked against it. (A sign
    # change is a crossing whatever float32 says of R.)
    touching = m & tangent & (R2t >= ray.r0sq * (1.0 - _R0_REL_TOL))
    # s from eq. 15 for steep rays; else from |o_xy + s d_xy| = R(t),
    # s = s* -+ h, choosing the branch consistent with z.
    steep = dz * dz >= ray.a
    inv_a = ray.inv_a
    s_z = (Zt - o.z) * dr.rcp(dz)
    hh = dr.sqrt(dr.maximum(R2t - ray.r0sq, 0.0) * inv_a)
    s1 = ray.s_star - hh
    s2 = ray.s_star + hh
    e1 = dr.abs(dr.fma(s1, dz, o.z) - Zt)
    e2 = dr.abs(dr.fma(s2, dz, o.z) - Zt)
    # A root pair of a nearly horizontal ray that float32 cannot resolve
    # (a tangent root, or a root next to a critical point where |F| is
    # within noise) stands for both branches when both z errors are within
    # the pair width allowed by the noise of F (|F| <= tol near a root pair
    # allows |W1 - W2| up to ~2 sqrt(tol / a)): a tangent takes both. A
    # root with a sign change is one crossing, on the branch whose z fits
    # better; in an unresolved pair around an interior critical point c of
    # F, where that cannot tell, the root lies above z* (W > 0, the branch
    # s > s* when d_z >= 0) when it is on the side of c where Z rises, so
    # the two roots take the two branches.
    z_tol = _PAIR_WIDTH * dr.sqrt(tol * inv_a)
    unresolved = dr.maximum(e1, e2) <= z_tol
    both = tangent & unresolved
    near0 = dr.abs(f0) <= dr.abs(f1)  # the end nearer a root pair's centre
    centre = dr.select(near0, x0, x1)
    pair = found & unresolved & (dr.minimum(dr.abs(f0), dr.abs(f1)) <= tol) & (centre > 0) & (centre < 1)
    pair &= dr.select(near0, crit0, crit1)
    above = (dZ > 0) == near0
    take1 = dr.select(pair, above != (dz >= 0), (e1 <= e2) | both)
    first = dr.select(steep, s_z, dr.select(take1, s1, s2))
    second = dr.select(steep, s_z, dr.select(both, s2, first))
    if ray.mode == "keyed":
        first, second = _kept_in_box(ray, lf.box, first), _kept_in_box(ray, lf.box, second)
    best = _offer(best, ray, first, u, lf.leaf, key, m & (found | touching))
    return _offer(best, ray, second, u, lf.leaf, key + 1, touching)


@dr.syntax
def _solve_leaf(data: BSplineData, node, leaf, ray: _Ray, best: _Best, m) -> _Best:
    """Intersect leaf ``leaf`` (BVH node ``node``, lanes ``m``); return the
    updated crossings.
    Lanes where the Bernstein hull of ``F`` excludes a root (or a grazing
    contact) on the leaf skip the solve."""
    lf = _Leaf(data, node, leaf, ray, m)
    m = m & ~_one_sign(lf.Gb, lf.tol)
    if m:
        best = _solve_body(lf, ray, best, m)
    return best


def _solve_chain(lf: _Leaf, ray: _Ray, best: _Best, m) -> _Best:
    """General leaf: all critical points of F by the derivative chain, then
    its six monotonic intervals (the leaf's ends valued at its joints)."""
    lo, hi = mi.Float(0.0), mi.Float(1.0)
    derivs = [lf.F, lf.dF]
    for _ in range(4):
        derivs.append(_polyder(derivs[-1]))
    xs = [lo] + _isolate_critical(derivs, lo, hi) + [hi]
    fs = [lf.f0] + [_value(lf, ray, x) for x in xs[1:-1]] + [lf.f1]

    def pick(values: list, j):
        """``values[j]`` (j the same on all lanes)."""
        out = values[0]
        for k in range(1, len(values)):
            out = dr.select(j == k, values[k], out)
        return out

    def step(j, best):
        # Interval j: one root search and its crossings (a loop over the
        # intervals: a shorter kernel than six of each)
        x0, x1, f0, f1 = pick(xs[:-1], j), pick(xs[1:], j), pick(fs[:-1], j), pick(fs[1:], j)
        root = _interval_roots(lf, [(x0, x1, f0, f1, m)])[0]
        return j + 1, _take_interval(lf, ray, x0, x1, f0, f1, root, best, m, lf.key + 2 * j, True, True)

    return dr.while_loop((mi.UInt32(0), best), lambda j, best: j < len(xs) - 1, step)[1]


@dr.syntax
def _solve_body(lf: _Leaf, ray: _Ray, best: _Best, m) -> _Best:
    """:func:`_solve_leaf` on the lanes ``m`` that its hull test passed."""
    # Bernstein coefficients of F' and F'' (up to the factors 6 and 30):
    # first and second differences of those of F, with errors below 2 tol
    # and 4 tol.
    Gb, tol = lf.Gb, lf.tol
    db = [Gb[k + 1] - Gb[k] for k in range(6)]
    mono = _one_sign(db, 2.0 * tol)
    simple = mono | _one_sign([db[k + 1] - db[k] for k in range(5)], 4.0 * tol)
    # F' keeps its sign: F is monotonic on [0, 1] (most leaves), one
    # interval, and no tangent. Else F'' keeps its sign: F is convex or
    # concave. Where its ends differ in sign (as F has them, beyond its
    # error: _side may have made one end positive, and an end within noise
    # of 0 may be a root of either sign with another one inside) it has one
    # root: one interval again. Else it has at most one critical point c
    # (none: c = 1) and zero or two roots (or a tangent), on [0, c] and
    # [c, 1]; packets without such a lane skip that work.
    fast = m & simple
    across = (lf.f0 < 0) != (lf.f1 < 0)
    across &= ((Gb[0] < -tol) & (Gb[6] > tol)) | ((Gb[0] > tol) & (Gb[6] < -tol))
    split = fast & ~mono & ~across
    c = mi.Float(1.0)            # the critical point (1: none)
    f_c = mi.Float(lf.f1)        # F(c)
    if split:
        c, _ = _bracket_root(lf.dF, _polyder(lf.dF), mi.Float(0.0), mi.Float(1.0), lf.dF[0],
                             sum(lf.dF[1:], lf.dF[0]), _STEPS_CRIT)
        f_c = _value(lf, ray, c)
    first, second = _interval_roots(lf, [(mi.Float(0.0), c, lf.f0, f_c, fast),
                                         (c, mi.Float(1.0), f_c, lf.f1, split)])
    best = _take_interval(lf, ray, mi.Float(0.0), c, lf.f0, f_c, first, best, fast, lf.key, False, split)
    if split:
        best = _take_interval(lf, ray, c, mi.Float(1.0), f_c, lf.f1, second, best, split, lf.key + 2,
                              True, True)
    slow = m & ~simple
    if slow:
        best = _solve_chain(lf, ray, best, slow)
    return best


@dr.syntax
def _trace(data: BSplineData, ray: _Ray, shadow: bool = False):
    """The crossings of ``ray`` in its mode (:func:`_offer`): ``(hit,
    best)``, ``hit`` the first one, polished unless ``shadow``; a shadow
    ray's walk ends at the first crossing found (a counting ray never takes
    one: it walks on, unpolished)."""
    active = ray.active
    node = mi.UInt32(ray.first) # current node of this ray's BVH copy
    end = ray.end               # one past this copy's last node
    best = _Best(s=mi.Float(ray.s_max))  # crossings so far (moved frame)
    hit = mi.Bool(False)        # a hit was found (ends shadow rays)
    cand = mi.Bool(False)       # node is a leaf to solve
    while active & (node < end) & ~(hit & shadow):
        # Walk the tree to the next candidate leaf (keyed: boxes a little
        # past the best, whose polished s may lie below its root's)
        cand = mi.Bool(False)
        while active & (node < end) & ~cand:
            cand, node = _visit(data, ray, node, best.s + ray.slack, active & (node < end))
        leaf = common.bvh_link(data.links, node, cand)[2]
        best = _solve_leaf(data, node, leaf, ray, best, cand)
        hit |= best.s < ray.s_max
        node = dr.select(cand, node + 1, node)
    valid = best.s < ray.s_max
    s = best.raw if ray.mode == "keyed" else best.s  # (keyed: polished again to best.s)
    seg, u = _leaf_to_segment(data, best, valid)
    if not shadow:
        if valid:  # (a packet without a hit skips it)
            s, u = _polish(data, ray, s, u, seg, valid)
    t = dr.select(valid, (s + ray.s_enter) * ray.t_scale, dr.inf)
    return BSplineHit(t=t, seg=seg, u=dr.clip(u, 0.0, 1.0), valid=valid), best


def _leaf_to_segment(data: BSplineData, best: _Best, active):
    """The segment of the crossing ``best`` and its parameter there, ``t =
    t0 + h u`` (the leaf's placement in its segment)."""
    meta = dr.gather(mi.Vector4f, data.leaf, best.leaf * (LEAF_STRIDE // 4) + 2, active)
    return mi.UInt32(meta.z), dr.fma(meta.y, best.u, meta.x)


def _segment_cubics(data: BSplineData, seg, active) -> tuple[list, list]:
    """Power coefficients of ``R`` (or ``R^2``) and ``Z`` of segment
    ``seg``: two loads of four adjacent floats."""
    R = dr.gather(mi.Vector4f, data.seg, seg * (STRIDE // 4), active)
    Z = dr.gather(mi.Vector4f, data.seg, seg * (STRIDE // 4) + 1, active)
    return [R.x, R.y, R.z, R.w], [Z.x, Z.y, Z.z, Z.w]


def _polish(data: BSplineData, ray: _Ray, s, t, seg, active):
    """Newton steps on the geometric system of the hit (eqs. 13-15)::

        g1 = o_z + s d_z - Z(t) = 0,   g2 = |o_xy + s d_xy|^2 - R(t)^2 = 0.

    The roots of F are limited by float32 cancellation among its terms (an
    error in t of up to ~1e-3 on steep rays along near-vertical walls);
    these residuals are not. A step is kept only when the Jacobian is well
    conditioned and it stays small and on the segment (grazing hits keep the
    root-finder's answer)."""
    R, Z = _segment_cubics(data, seg, active)
    o, dh = ray.o, ray.d
    squared = _squared(data)
    s_root = s
    for _ in range(_STEPS_POLISH):
        Rt, dR = _polyval_d(R, t)
        Zt, dZ = _polyval_d(Z, t)
        # R(t)^2 and its derivative 2 R R' (the sor kind stores R^2 itself)
        R2t, dR2 = _by_form(squared, lambda r, dr_: (r, dr_), lambda r, dr_: (r * r, 2.0 * r * dr_), Rt, dR)
        qx = dr.fma(dh.x, s, o.x)
        qy = dr.fma(dh.y, s, o.y)
        g1 = dr.fma(dh.z, s, o.z) - Zt
        g2 = dr.fma(qx, qx, dr.fma(qy, qy, -R2t))
        qd = dr.fma(qx, dh.x, qy * dh.y)
        # Jacobian [[d_z, -Z'], [2 q.d, -2 R R']].
        j22 = -dR2
        j21 = 2.0 * qd
        det = dr.fma(dh.z, j22, dZ * j21)
        scale_j = (dr.abs(dh.z) + dr.abs(j21)) * (dr.abs(dZ) + dr.abs(j22))
        ds = -(j22 * g1 + dZ * g2) / det
        dt = -(dh.z * g2 - j21 * g1) / det
        ok = active & (dr.abs(det) > 1e-4 * scale_j) & (dr.abs(dt) < 0.01)
        # (bounded by t > 0, not by a walk's s_lo: a crossing's s must not
        # depend on where the query starts, eq. 31)
        ok &= (t + dt >= -_T_PAD) & (t + dt <= 1.0 + _T_PAD) & (s + ds > ray.s_positive)
        ok &= dr.abs(s + ds - s_root) <= _POLISH_REACH
        s = dr.select(ok, s + ds, s)
        t = dr.select(ok, t + dt, t)
    return s, t


def intersect_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f,
                      tmax: mi.Float, active: mi.Bool) -> BSplineHit:
    """Nearest hit of the rays ``o + s d`` (local frame, ``d`` not
    necessarily unit) with ``0 < s < tmax`` on the revolved B-spline."""
    return _trace(data, _Ray(data, o, d, mi.Float(tmax), active))[0]


def occluded_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f,
                     tmax: mi.Float, active: mi.Bool) -> mi.Bool:
    """Whether the rays hit the surface at some ``0 < s < tmax`` (stops at
    the first hit found, not necessarily the nearest)."""
    return _trace(data, _Ray(data, o, d, mi.Float(tmax), active), True)[0].valid


def count_crossings_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f,
                            active: mi.Bool) -> mi.UInt32:
    """Number of crossings of the ray ``o + t d`` (``t > 0``) with the lathe,
    every one that :func:`next_crossing_bspline` reports (a tangent counts
    twice). For a ray that starts outside a closed lathe (a profile from
    the axis to the axis, or a closed loop) the number is even for every
    line (the parity rule of :func:`_take_interval`)."""
    ray = _Ray(data, o, d, dr.full(mi.Float, dr.inf, dr.width(o)), active, "count")
    return _trace(data, ray, shadow=True)[1].count


def next_crossing_bspline(data: BSplineData, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float,
                          active: mi.Bool, after_s: mi.Float | None = None,
                          after_key: mi.UInt32 | None = None, after_t: mi.Float | None = None
                          ) -> tuple[BSplineHit, mi.Float, mi.UInt32]:
    """The next crossing of the ray ``o + t d`` (``0 < t < tmax``) after the
    one that a previous call with the same ``o``, ``d`` returned as
    ``(after_s, after_key)``: ``(hit, s, key)``, ``hit`` as
    :func:`intersect_bspline` gives it and ``(s, key)`` this crossing's
    place to pass to the next call (``s`` the kernel's ray parameter,
    ``key`` unique per crossing, ordering crossings at equal ``s``).

    ``None``: the first crossing with ``t > 0``. ``after_t`` (units of
    ``d``; ``None``: 0): lanes whose ``after_key`` is ``0xFFFFFFFF`` (or all,
    without ``after_key``) look for the first crossing with ``t > after_t``
    instead (one of another shape on the same line). Walking a ray through
    its crossings this way, from its first origin and without offsets,
    finds each crossing exactly once, also where two of them are closer
    than any offset or rounded to the same ``t``: with the parity rule of
    :func:`_take_interval` a ray from outside a closed lathe then crosses
    it an even number of times."""
    ray = _Ray(data, o, d, mi.Float(tmax), active, "keyed")
    s_from = mi.Float(ray.s_lo)
    key_from = mi.UInt32(0xFFFFFFFF)
    if after_s is not None:
        later = after_s > ray.s_lo
        s_from = dr.select(later, after_s, s_from)
        key_from = dr.select(later, after_key, key_from)
    if after_t is not None:
        # The first crossing with t > after_t, compared on the t returned
        # (eq. 31); s_from only prunes, lowered past the rounding of t -> s
        by_t = mi.Bool(True) if after_key is None else after_key == 0xFFFFFFFF
        s_t = after_t * dr.rcp(ray.t_scale)
        s_t = dr.maximum(s_t - ray.s_enter - 1e-5 * (dr.abs(s_t) + dr.abs(ray.s_enter)), ray.s_lo)
        s_from = dr.select(by_t, s_t, s_from)
        key_from = dr.select(by_t, 0xFFFFFFFF, key_from)
        ray.t_after = dr.select(by_t, after_t, -dr.inf)
    ray.after = (s_from, key_from)
    # Boxes before it need no visit; crossings are ordered by their polished
    # s (_offer), which lies within _POLISH_REACH of their root's: boxes
    # that far around the interval are visited too
    ray.slack = _POLISH_REACH * 1.25 + 1e-5 * (dr.abs(s_from) + dr.abs(ray.s_enter))
    ray.s_lo = dr.maximum(s_from - ray.slack, ray.s_positive)
    hit, best = _trace(data, ray)
    return hit, best.s, best.key


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
    (the tripled end points of an open profile, a sor disc's centre) the
    segment's chord gives its limit direction. ``uv = (azimuth / 2 pi, (seg +
    u) / n_seg)``.
    """
    R, Z = _segment_cubics(data, seg, True)
    Rt, dR = _polyval_d(R, u)  # unit frame (kernels/common.py)
    _, dZ = _polyval_d(Z, u)
    tan_r, tan_z = dR, dZ
    squared = _squared(data)
    if squared is not False:
        # R holds R^2 (eq. 20): the tangent (R', Z') = ((R^2)' / 2R, Z') is
        # parallel to ((R^2)', 2 R Z'), finite on the axis too.
        radius = dr.sqrt(dr.maximum(Rt, 0.0))
        tan_z, dR, Rt = _by_form(squared, lambda: (2.0 * radius * dZ,
                                                   dR * dr.rcp(2.0 * dr.maximum(radius, 1e-6)), radius),
                                 lambda: (tan_z, dR, Rt))
    chord_r = R[1] + R[2] + R[3]
    chord_z = Z[1] + Z[2] + Z[3]
    speed2 = dr.fma(tan_r, tan_r, tan_z * tan_z)
    degenerate = speed2 <= 1e-24 * dr.fma(chord_r, chord_r, chord_z * chord_z)
    tr = dr.select(degenerate, chord_r, tan_r)
    tz = dr.select(degenerate, chord_z, tan_z)
    inv = dr.rsqrt(dr.fma(tr, tr, tz * tz))
    nr, nz = -tz * inv, tr * inv

    q = to_unit_frame(data, p)
    rho = dr.sqrt(dr.fma(q.x, q.x, q.y * q.y))
    on_axis = rho <= 1e-7
    cos_p = dr.select(on_axis, 1.0, q.x / rho)
    sin_p = dr.select(on_axis, 0.0, q.y / rho)
    n = mi.Vector3f(nr * cos_p, nr * sin_p, nz)

    phi = dr.atan2(sin_p, cos_p)
    phi = dr.select(phi < 0, phi + 2 * math.pi, phi)
    n_seg = mi.Float(data.n_seg)
    uv = mi.Point2f(phi * (0.5 / math.pi), (mi.Float(seg) + u) / n_seg)
    dp_du = mi.Vector3f(-Rt * sin_p, Rt * cos_p, 0.0) * (2 * math.pi * data.scale)
    dp_dv = mi.Vector3f(dR * cos_p, dR * sin_p, dZ) * (n_seg * data.scale)
    return BSplineGeometry(n=n, sh_n=mi.Vector3f(n), uv=uv, dp_du=dp_du, dp_dv=dp_dv)
