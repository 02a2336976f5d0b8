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
"""

from __future__ import annotations

import math
from collections.abc import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

from ..profiles.bspline import power_coefficients
from . import common
from .common import (
    LatheData,
    LatheGeometry,
    LatheHit,
    LatheRay,
    box_rmin2,
    opaque,
    threaded_bvh,
    to_unit_frame,
    unit_frame,
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

#: Floats per segment in ``BSplineData.seg``: R0..R3, Z0..Z3 (ascending
#: powers of t).
STRIDE = 8

#: Floats per leaf in ``BSplineData.leaf`` (three Vector4f): Bezier control
#: values R_b0..3 and Z_b0..3 (in the leaf's parameter u; the kernel derives
#: the power form from them, :func:`_bezier_to_power`), then (t0, h,
#: segment, r_squared): the last is 1 where the R slots hold R^2 (the sor
#: kind; the kernel reads the flag from ``BSplineData``, see :func:`_squared`).
LEAF_STRIDE = 12

# (the former private names, for older importers)
_STRIDE = STRIDE
_LEAF_STRIDE = LEAF_STRIDE

#: Longest leaf, in segment parameter t (before padding).
_LEAF_T = 0.25

#: How far, in segment parameter t, the polish may move a hit past the
#: segment's ends.
_T_PAD = 1e-3

#: Newton/bisection steps for critical points and for the roots of F.
_STEPS_CRIT = 10
_STEPS_ROOT = 12

#: Relative tolerance of the R(t) >= r0 test of a root (grazing rays).
_R0_REL_TOL = 1e-5

#: Steps below this (about the float32 spacing near u = 1) end a root search.
_T_RESOLUTION = 1e-7

#: A Newton step below this ends a root search after it is taken.
_T_FINAL = 1e-4

#: Newton steps polishing the nearest hit on the (s, t) system.
_STEPS_POLISH = 2

#: Farthest the polish moves a root's s (unit frame): measured on 10^6 hits
#: of five profiles, 99.99% move less than 2e-4 and all but a tangent's
#: less than 2.2e-3. A walk visits the boxes that far before its last
#: crossing (next_crossing_bspline), as a crossing is ordered by its
#: polished s but found in the box of its root.
_POLISH_REACH = 4e-3

#: Tangent-root threshold, in units of float32 epsilon times a bound on the
#: magnitude of the terms of F (its evaluation error is below that).
_TANGENT_ULPS = 8.0

#: Width of an unresolved root pair in z, in units of sqrt(tol / a).
_PAIR_WIDTH = 4.0

#: Crossing keys per leaf (next_crossing_bspline): two per monotonic
#: interval of F, at most six intervals.
_KEYS_PER_LEAF = 16


class BSplineData(LatheData):
    """Packed, opaque buffers of one B-spline lathe (local frame).

    Attributes (besides those of :class:`~lathe_shape.kernels.common.LatheData`):
        seg: ``mi.Float`` of ``n_seg * 8`` values (see ``STRIDE``).
        leaf: ``mi.Float`` of ``n_leaf * 12`` values (see ``LEAF_STRIDE``).
        nodes: ``mi.Float``, 4 values per node of the four threaded BVH
            copies: the annular box ``(rmax, rmin^2, zmin, zmax)``.
        links: ``mi.UInt32`` per node: an inner node's miss link, or
            ``LEAF | leaf index``.
        n_nodes: opaque ``mi.UInt32``: nodes per copy.
        n_seg: opaque ``mi.UInt32`` (one element): number of segments.
        n_seg_host, n_leaf_host: the segment and leaf counts as Python ints.
        r_squared: Python bool, True when the ``R`` slots hold ``R^2`` (the
            ``sor`` kind, :func:`build_cubic_data`); chosen when tracing.
        r_squared_flag: the same as an opaque ``mi.UInt32`` (0 or 1): a view
            of several profiles' data (kernels/top_level.py) gathers it per
            lane, so that one kernel serves profiles of both forms.
        bound_r, bound_z_lo, bound_z_hi: opaque ``mi.Float`` padded bounding
            cylinder of the whole curve (the union of the leaf boxes).
        scale, inv_scale, z_shift: the unit frame (kernels/common.py), in
            which ``seg``, ``leaf``, ``nodes`` and the cylinder are given.
    """


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


def _leaf_pieces(coef: np.ndarray) -> list[tuple[float, float]]:
    """Pieces [ta, tb] of one segment: cut at the interior extrema of R and
    Z (monotone pieces have corner-tight boxes), then evenly into pieces of
    at most ``_LEAF_T``."""
    cuts = {0.0, 1.0}
    for c in coef:
        if np.any(c[1:] != 0):
            for root in np.roots([3 * c[3], 2 * c[2], c[1]]):
                if abs(root.imag) < 1e-12 and 0.02 < root.real < 0.98:
                    cuts.add(float(root.real))
    cuts = sorted(cuts)
    pieces = []
    for ta, tb in zip(cuts[:-1], cuts[1:], strict=True):
        n = max(1, math.ceil((tb - ta) / _LEAF_T - 1e-9))
        edges = np.linspace(ta, tb, n + 1)
        pieces += list(zip(edges[:-1], edges[1:], strict=True))
    return pieces


def _reparam(c: np.ndarray, t0: float, h: float) -> np.ndarray:
    """Power coefficients in u of the cubic ``c`` at ``t = t0 + h u``."""
    p = np.polynomial.Polynomial(c)(np.polynomial.Polynomial([t0, h])).coef
    return np.pad(p, (0, 4 - len(p)))


def _bezier(p: np.ndarray) -> np.ndarray:
    """Bernstein (Bezier) coefficients on [0, 1] of the power-form cubic ``p``."""
    return np.array([p[0], p[0] + p[1] / 3, p[0] + (2 * p[1] + p[2]) / 3, p.sum()])


def _shared_joints(coef: np.ndarray, pieces: list) -> list:
    """Per leaf ``(i, ta, tb)`` of ``pieces`` (in profile order), its start and
    end point ``((R, Z), (R, Z))`` as float32 values (``R^2`` for the sor
    kind), one value per joint: where a leaf ends where the next one (or, for
    a closed curve, the first one) starts (within float64 rounding of the
    segment cubics), both get the same point."""
    P = np.polynomial.polynomial
    ends = [[P.polyval(t, coef[i].T) for t in (ta, tb)] for i, ta, tb in pieces]
    n = len(ends)
    for k in range(n):
        nxt = (k + 1) % n
        if np.max(np.abs(ends[k][1] - ends[nxt][0])) <= 1e-9:
            ends[k][1] = ends[nxt][0]
    return [[tuple(np.float32(p)) for p in pair] for pair in ends]


def build_bspline_data(seg_ctrl: np.ndarray, free_ends: bool = False) -> BSplineData:
    """Pack validated per-segment control points (from
    :func:`lathe_shape.profiles.bspline.bspline_segments`, oriented clockwise) into
    opaque Dr.Jit buffers: segment cubics, leaves with padded boxes, the
    threaded BVH and the bounding cylinder. Call once per shape.
    ``free_ends``: see :func:`build_cubic_data`."""
    seg_ctrl = np.asarray(seg_ctrl, dtype=np.float64)
    # The curve lies in the control points' hull: their bounds size the frame
    return build_cubic_data(power_coefficients(seg_ctrl), seg_ctrl.reshape(-1, 2),
                            free_ends=free_ends)


def _curve_hull(coef: np.ndarray, r_squared: bool) -> np.ndarray:
    """Two corners ``(rmin, zmin), (rmax, zmax)`` of the exact bounding box
    of the curve (``coef`` in the user's units)."""
    r = np.array([_cubic_range(c, 0.0, 1.0) for c in coef[:, 0]])
    z = np.array([_cubic_range(c, 0.0, 1.0) for c in coef[:, 1]])
    if r_squared:
        r = np.sqrt(np.maximum(r, 0.0))
    return np.array([[r[:, 0].min(), z[:, 0].min()], [r[:, 1].max(), z[:, 1].max()]])


def build_cubic_data(coef: np.ndarray, hull: np.ndarray | None = None,
                     r_squared: bool = False, free_ends: bool = False) -> BSplineData:
    """Pack the power coefficients ``coef`` (n_seg, 2, 4) of validated
    clockwise segment cubics ``R(t)``, ``Z(t)`` (any cubic kind, eq. 18) into
    opaque Dr.Jit buffers, as :func:`build_bspline_data`. ``hull``: points
    whose bounding box holds the curve (default: its exact box).

    ``r_squared``: ``coef[:, 0]`` holds ``R(t)^2`` itself (the ``sor`` kind,
    eq. 20), not ``R(t)``: the kernel then uses that cubic where it would
    square ``R`` (``F`` of eqs. 13-15 drops to degree 3 when ``Z`` is linear),
    and the segments' ``R`` slots hold ``R^2`` in the unit frame.

    ``free_ends``: the curve is an open sheet (accepted for the callers;
    leaves are not padded in ``t``, so a free end needs nothing else)."""
    coef = np.array(coef, dtype=np.float64)
    pts = _curve_hull(coef, r_squared) if hull is None else np.asarray(hull, dtype=np.float64)
    size, z_c, frame = unit_frame("build_bspline_data()", float(np.abs(pts[:, 0]).max()),
                                  float(pts[:, 1].min()), float(pts[:, 1].max()))
    coef[:, 1, 0] -= z_c
    coef[:, 1] /= size
    coef[:, 0] /= size * size if r_squared else size
    n_seg = len(coef)
    # Padding (unit frame): float32 rounding of the data and of the ray.
    pad = 1e-5 * float(np.linalg.norm(np.ptp(pts, axis=0))) / size
    pieces = [(i, ta, tb) for i in range(n_seg) for ta, tb in _leaf_pieces(coef[i])]
    ends = _shared_joints(coef, pieces)
    leaves, boxes = [], []
    for (i, ta, tb), (start, end) in zip(pieces, ends, strict=True):
        rp = _reparam(coef[i, 0], ta, tb - ta)
        zp = _reparam(coef[i, 1], ta, tb - ta)
        rmin, rmax = _cubic_range(rp, 0.0, 1.0)
        if r_squared:
            rmin, rmax = math.sqrt(max(rmin, 0.0)), math.sqrt(max(rmax, 0.0))
        zmin, zmax = _cubic_range(zp, 0.0, 1.0)
        rb, zb = _bezier(rp), _bezier(zp)
        # The end control points are the leaf's joints, shared bit for bit
        # with the neighbouring leaf (the parity rule of _take_interval)
        (rb[0], zb[0]), (rb[3], zb[3]) = start, end
        leaves.append(np.concatenate([rb, zb, [ta, tb - ta, i, float(r_squared)]]))
        boxes.append([max(min(rmin, rb[0], rb[3]) - pad, 0.0), max(rmax, rb[0], rb[3]) + pad,
                      min(zmin, zb[0], zb[3]) - pad, max(zmax, zb[0], zb[3]) + pad])
    boxes = np.array(boxes)
    # Inner nodes and leaves alike store (rmax, rmin^2, zmin, zmax).
    def record(b):
        return [b[1], box_rmin2(b[0]), b[2], b[3]]

    recs, links, n_nodes = threaded_bvh(boxes, record, lambda k, b: record(b))

    return BSplineData(
        seg=opaque(coef.reshape(n_seg, STRIDE).ravel()),
        leaf=opaque(np.asarray(leaves).ravel()),
        nodes=opaque(np.asarray(recs).ravel()),
        links=opaque(np.asarray(links, dtype=np.uint32), mi.UInt32),
        n_nodes=opaque(n_nodes, mi.UInt32),
        n_seg=opaque(n_seg, mi.UInt32),
        n_seg_host=n_seg,
        n_leaf_host=len(leaves),
        r_squared=r_squared,
        r_squared_flag=opaque(int(r_squared), mi.UInt32),
        bound_r=opaque(float(boxes[:, 1].max())),
        bound_z_lo=opaque(float(boxes[:, 2].min())),
        bound_z_hi=opaque(float(boxes[:, 3].max())),
        **frame,
    )


# ---------------------------------------------------------------------------
# Polynomial helpers (unrolled per degree, vectorized over lanes)
# ---------------------------------------------------------------------------

def _squared(data: LatheData):
    """Whether the ``R`` slots of ``data`` hold ``R^2`` (the sor kind, eq.
    20): the Python bool of one lathe's own :class:`BSplineData`, so that
    its kernel is specialised to one form; else (a view of several profiles'
    data, kernels/top_level.py, which has no such bool) a per-lane mask
    from the profile's ``r_squared_flag``."""
    flag = getattr(data, "r_squared", None)
    return flag if isinstance(flag, bool) else data.r_squared_flag != 0


def _by_form(squared, of_square: Callable, of_radius: Callable, *args):
    """``of_square(*args)`` where ``squared`` (see :func:`_squared`), else
    ``of_radius(*args)``: only the one needed for a Python bool, both
    selected per lane for a mask. The callables return a value or a
    tuple/list."""
    if isinstance(squared, bool):
        return of_square(*args) if squared else of_radius(*args)
    a, b = of_square(*args), of_radius(*args)
    if isinstance(a, (list, tuple)):
        return type(a)(dr.select(squared, x, y) for x, y in zip(a, b, strict=True))
    return dr.select(squared, a, b)


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
    safeguarded Newton steps (as ``rtsafe`` in Numerical Recipes), starting
    from the false-position point: a step that would leave the bracket, or
    that did not halve the previous one, is replaced by bisection, so the
    bracket shrinks at least geometrically; the result is the evaluated
    point with the least ``|f|`` (always inside the bracket). A symbolic
    loop of at most ``steps`` iterations ends when every lane of a packet
    has converged (usually after 2-4 steps on a leaf). Without a sign change
    ``x`` is ``x1`` (this keeps the list of critical points sorted for the
    next level).
    """
    return _bracket_roots(c, dc, [(x0, x1, f0, f1, None)], steps)[0]


def _bracket_roots(c: list, dc: list, brackets: list, steps: int, strict: bool = False) -> list:
    """:func:`_bracket_root` on several brackets ``(x0, x1, f0, f1, mask)``
    of one polynomial at once (``mask``: lanes that search it, ``None``:
    all), in one symbolic loop: every bracket takes the same steps as on its
    own (a converged bracket's point stays put), so the results are the
    same, and a kernel holds one loop instead of one per bracket (fewer
    loops make faster LLVM code, even where they seldom run).

    ``strict``: a root is found exactly where ``f0 < 0`` and ``f1 < 0``
    differ (0 counts as positive), so that along a chain of brackets the
    found roots change the sign as often as the ends do (the parity rule of
    :func:`_take_interval`); else also where ``f0`` or ``f1`` is 0."""
    state, starts = [], []
    for x0, x1, f0, f1, mask in brackets:
        if strict:
            found = (f0 < 0) != (f1 < 0)
        else:
            found = ((f0 <= 0) & (f1 >= 0)) | ((f0 >= 0) & (f1 <= 0))
        if mask is not None:
            found &= mask
        a, b = mi.Float(x0), mi.Float(x1)  # bracket [a, b]; f(a) has the sign of f0
        x = dr.clip(x0 - f0 * (x1 - x0) / (f1 - f0), a, b)  # current estimate
        x = dr.select(dr.isfinite(x), x, 0.5 * (a + b))
        # (a, b, x, step before last, last step, converged or nothing to
        # find, evaluated point with the least |f|, its |f|)
        state.append((a, b, x, b - a, b - a, ~found, mi.Float(x), mi.Float(dr.inf)))
        starts.append((found, f0 < 0))

    def pending(k, state):
        todo = ~state[0][5]
        for bracket in state[1:]:
            todo |= ~bracket[5]
        return todo & (k < steps)

    def step(k, state):
        return k + 1, [_newton_step(c, dc, bracket, neg0)
                       for bracket, (_, neg0) in zip(state, starts, strict=True)]

    _, state = dr.while_loop((mi.UInt32(0), state), pending, step)
    out = []
    for (x0, x1, f0, f1, _), (found, _), bracket in zip(brackets, starts, state, strict=True):
        x = dr.select(f0 == 0, x0, dr.select(f1 == 0, x1, bracket[6]))
        out.append((dr.select(found, x, x1), found))
    return out


def _newton_step(c: list, dc: list, bracket: tuple, neg0) -> tuple:
    """One safeguarded Newton step of :func:`_bracket_roots` on one bracket
    state (the order of its fields is documented there)."""
    a, b, x, dx_old, dx, done, best_x, best_f = bracket
    f, df = _polyval_d(c, x)
    # Near the root f is float32 noise, and the steps below may then
    # bisect away from it; the least |f| seen is the answer.
    better = dr.abs(f) < best_f
    best_x = dr.select(better, x, best_x)
    best_f = dr.select(better, dr.abs(f), best_f)
    left = (f < 0) == neg0
    a = dr.select(left, x, a)
    b = dr.select(left, b, x)
    # Converged: an exact zero, or a Newton step below float32 resolution of
    # t (checked first: the test below would then pick bisection and jump
    # away from the root).
    done = done | (f == 0) | (dr.abs(f) <= _T_RESOLUTION * dr.abs(df))
    # Newton unless it leaves [a, b] or converges slower than bisection.
    xn = x - f / df
    newton = (df != 0) & (xn >= a) & (xn <= b) & (dr.abs(2.0 * f) <= dr.abs(dx_old * df))
    x_new = dr.select(newton, xn, 0.5 * (a + b))
    # A Newton step below _T_FINAL is the last one: the next would be of
    # its square's order, below float32 resolution (saves an evaluation).
    last = ~done & newton & (dr.abs(f) <= _T_FINAL * dr.abs(df))
    best_x = dr.select(last, xn, best_x)
    return a, b, dr.select(done, x, x_new), dx, x_new - x, done | last, best_x, best_f


def _isolate_critical(derivs: list, lo, hi) -> list:
    """Sorted critical points of ``derivs[0]`` (degree k) on [lo, hi]: the
    roots of its derivative, found level by level from the linear
    ``derivs[-1]`` up. ``derivs[j]`` is the j-th derivative of ``derivs[0]``.
    Missing points are filled with interval ends (harmless: they only split a
    monotonic interval). Returns k - 1 values.

    One symbolic loop runs the levels: each level's polynomial is padded
    with zero coefficients to the degree of the last (which changes no
    value), its brackets likewise with empty ones at ``hi``, so that one
    search of k - 1 brackets serves all levels: a much shorter kernel than
    a search per level (this runs seldom, but its code slows the rest)."""
    # The root of the linear derivs[-1] is the critical point of derivs[-2].
    lin = derivs[-1]
    x = dr.select(lin[1] != 0, -lin[0] / lin[1], hi)
    x = dr.select(dr.isfinite(x), x, hi)
    width = len(derivs[1])  # coefficients of the last level's polynomial

    def padded(c: list) -> list:
        return list(c) + [mi.Float(0.0)] * (width - len(c))

    levels = {j: (padded(derivs[j]), padded(derivs[j + 1])) for j in range(1, len(derivs) - 1)}

    def level_poly(j):
        """The polynomial of level ``j`` and its derivative (padded)."""
        c, dc = levels[len(derivs) - 2]
        for level in range(len(derivs) - 3, 0, -1):
            c = [dr.select(j == level, p, q) for p, q in zip(levels[level][0], c, strict=True)]
            dc = [dr.select(j == level, p, q) for p, q in zip(levels[level][1], dc, strict=True)]
        return c, dc

    def step(j, crit):
        # Level j turns its critical points into its roots, the critical
        # points of level j - 1.
        c, dc = level_poly(j)
        xs = [lo] + crit[:width - 2] + [hi]
        fs = [_polyval(c, xk) for xk in xs]
        brackets = [(xs[k], xs[k + 1], fs[k], fs[k + 1], None) for k in range(len(xs) - 1)]
        return j - 1, [r for r, _ in _bracket_roots(c, dc, brackets, _STEPS_CRIT)]

    crit = [dr.clip(x, lo, hi)] + [mi.Float(hi) for _ in range(width - 2)]
    _, crit = dr.while_loop((mi.UInt32(len(derivs) - 2), crit), lambda j, crit: j > 0, step)
    return crit


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
