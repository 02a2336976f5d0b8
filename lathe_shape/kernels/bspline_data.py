"""The B-spline kernel's data (kernels/bspline.py, which re-exports these
names): the layout constants, :class:`BSplineData` and its numpy build from a
profile's cubic segments (:func:`build_bspline_data`,
:func:`build_cubic_data`): power-form segments, short leaves with their
Bezier control values, and the threaded BVH over them."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

from ..profiles.bspline import power_coefficients
from .common import (
    LatheData,
    LatheGeometry,
    LatheHit,
    box_rmin2,
    opaque,
    threaded_bvh,
    unit_frame,
)

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
