"""POV-Ray's cubic lathe curves as per-segment cubics (numpy only).

Besides uniform cubic B-splines (:mod:`.bspline`), three kinds of control
points describe a profile made of cubic (or quadratic) segments, with POV-Ray
3.7's ``lathe`` semantics:

* ``bezier`` (``bezier_spline``): four points per segment, ``P_4i ..
  P_4i+3``; segment ``i`` runs from ``P_4i`` to ``P_4i+3``, and the next one
  must start where it ends;
* ``catmull_rom`` (``cubic_spline``): segment ``i`` runs from ``P_i+1`` to
  ``P_i+2`` with the tangents ``(P_i+2 - P_i) / 2`` and ``(P_i+3 - P_i+1) /
  2``; the first and the last point only set the end tangents (``n - 3``
  segments);
* ``quadratic`` (``quadratic_spline``): segment ``i`` runs from ``P_i+1`` to
  ``P_i+2`` with the start tangent ``(P_i+2 - P_i) / 2``; the first point only
  sets a tangent (``n - 2`` segments).

Each segment is the cubic ``C = M W`` in the power basis (docs/method.md,
eq. 17) of its window ``W`` of control points, with a fixed matrix ``M`` per
kind; a basis change turns it into the four uniform B-spline control points
of the same cubic (eq. 18), so that every B-spline routine (validation,
evaluation, sampling, the exact kernel) serves all kinds unchanged.

Closed or open. A curve whose end is its start (a loop), or whose two ends
lie on the axis, bounds a solid: it is validated as strictly as a B-spline
profile and oriented clockwise. Any other curve is refused unless
``open_sheet`` is set: it is then a single sheet (no inside, no area
check), still free of self-intersections and of points with ``r < 0``,
oriented so that its normal points away from the axis (it runs downwards on
the whole, like a solid's outer wall).
"""

from __future__ import annotations

import numpy as np

from . import bspline as bs
from .bspline import BSplineError, BSplineProfile
from .limits import BSPLINE_SAMPLES_PER_SEGMENT

__all__ = ["CUBIC_KINDS", "control_weights", "kind_coefficients", "make_cubic_profile", "to_bspline_controls",
           "curve_form", "bezier_points", "catmull_rom_through", "quadratic_through"]

#: Power-basis matrices (rows: 1, t, t^2, t^3) of each kind's window of
#: control points (columns), and how far the window moves per segment.
_MATRICES = {
    "bezier": (np.array([[1.0, 0.0, 0.0, 0.0],
                         [-3.0, 3.0, 0.0, 0.0],
                         [3.0, -6.0, 3.0, 0.0],
                         [-1.0, 3.0, -3.0, 1.0]]), 4),
    "catmull_rom": (np.array([[0.0, 1.0, 0.0, 0.0],
                              [-0.5, 0.0, 0.5, 0.0],
                              [1.0, -2.5, 2.0, -0.5],
                              [-0.5, 1.5, -1.5, 0.5]]), 1),
    "quadratic": (np.array([[0.0, 1.0, 0.0],
                            [-0.5, 0.0, 0.5],
                            [0.5, -1.0, 0.5],
                            [0.0, 0.0, 0.0]]), 1),
}

#: The kinds of this module, with POV-Ray's name and least point count.
CUBIC_KINDS = {"bezier": ("bezier_spline", 4), "catmull_rom": ("cubic_spline", 4),
               "quadratic": ("quadratic_spline", 3)}

#: Uniform B-spline control points of a cubic from its power coefficients
#: (the inverse of :data:`lathe_shape.profiles.bspline._BASIS`).
_TO_BSPLINE = np.linalg.inv(bs._BASIS)


def kind_coefficients(kind: str, points: np.ndarray, source: str = "profile") -> np.ndarray:
    """Power coefficients ``(n_seg, 2, 4)`` (as
    :func:`lathe_shape.profiles.bspline.power_coefficients`) of the curve of
    control points ``points`` (m, 2) of ``kind``. Raises
    :class:`~lathe_shape.profiles.bspline.BSplineError` for a wrong point
    count or, for ``bezier``, segments that do not join."""
    matrix, step = _MATRICES[kind]
    pov_name, least = CUBIC_KINDS[kind]
    p = bs.control_points(points, source, kind)
    width = matrix.shape[1]
    if len(p) < least:
        raise BSplineError(f"{source}: a {kind} profile ({pov_name}) needs at least {least} "
                           f"control points, got {len(p)}")
    if kind == "bezier":
        if len(p) % 4:
            raise BSplineError(f"{source}: a bezier profile needs 4 control points per segment "
                               f"(a multiple of 4), got {len(p)}")
        ends, starts = p[3:-1:4], p[4::4]
        gap = np.any(ends != starts, axis=1)
        if np.any(gap):
            k = int(np.argmax(gap)) + 1
            raise BSplineError(f"{source}: bezier segment {k + 1} starts at {starts[k - 1].tolist()} "
                               f"(control point {4 * k + 1}) but segment {k} ends at "
                               f"{ends[k - 1].tolist()} (control point {4 * k}): the curve must be "
                               f"connected (control points are numbered from 1)")
    count = (len(p) - width) // step + 1
    index = np.arange(count)[:, None] * step + np.arange(width)[None, :]
    return np.einsum("kj,ijc->ick", matrix, p[index])


def control_weights(kind: str, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The linear map from the ``n_points`` control points of a ``kind``
    curve to its segments' uniform B-spline control points (eqs. 17-18):
    ``(windows, weights)``, ``windows`` (n_seg, w) the indices of each
    segment's window of points and ``weights`` (4, w) the fixed weights, so
    that B-spline control ``k`` of segment ``i`` is ``sum_j weights[k, j]
    points[windows[i, j]]`` (before :func:`make_cubic_profile` may reverse
    the curve). The same for r and z."""
    matrix, step = _MATRICES[kind]
    width = matrix.shape[1]
    count = (n_points - width) // step + 1
    windows = np.arange(count)[:, None] * step + np.arange(width)[None, :]
    return windows, _TO_BSPLINE @ matrix


def to_bspline_controls(coef: np.ndarray) -> np.ndarray:
    """Per-segment uniform B-spline control points ``(n_seg, 4, 2)`` of the
    cubics with power coefficients ``coef`` (n_seg, 2, 4) (eq. 18)."""
    return np.einsum("kj,icj->ikc", _TO_BSPLINE, np.asarray(coef, dtype=np.float64))


def bezier_points(coef: np.ndarray) -> np.ndarray:
    """The ``bezier`` control points (4 per segment) of the cubics with
    power coefficients ``coef`` (n_seg, 2, 4): the same curve, each
    segment's first point set to the previous one's last (bit-equal joints,
    as the ``bezier`` kind requires)."""
    c = np.transpose(np.asarray(coef, dtype=np.float64), (0, 2, 1))  # (n, 4 powers, 2)
    b = np.stack([c[:, 0], c[:, 0] + c[:, 1] / 3, c[:, 0] + (2 * c[:, 1] + c[:, 2]) / 3,
                  c.sum(axis=1)], axis=1)
    b[1:, 0] = b[:-1, 3]
    return b.reshape(-1, 2)


def catmull_rom_through(points: np.ndarray) -> np.ndarray:
    """``catmull_rom`` control points of the curve through ``points``: the
    points plus end tangent controls mirrored through the ends."""
    p = np.asarray(points, dtype=np.float64)
    return np.concatenate([2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]])


def quadratic_through(points: np.ndarray) -> np.ndarray:
    """``quadratic`` control points of the curve through ``points``: the
    points plus a start tangent control mirrored through the first."""
    p = np.asarray(points, dtype=np.float64)
    return np.concatenate([2 * p[:1] - p[1:2], p])


def curve_form(start: np.ndarray, end: np.ndarray, scale: float) -> tuple[bool, bool]:
    """``(loop, on_axis)``: whether the curve's end is its start (within
    ``1e-12 * scale`` or the rounding of their coordinates,
    :func:`.bspline.ends_meet`), and whether both its ends lie on the axis
    (within ``1e-12 * scale``)."""
    loop = bs.ends_meet(start, end, scale)
    on_axis = bool(abs(start[0]) <= 1e-12 * scale and abs(end[0]) <= 1e-12 * scale)
    return loop, on_axis


def make_cubic_profile(kind: str, points: np.ndarray, source: str,
                       open_sheet: bool = False) -> BSplineProfile:
    """Validate the control points of a ``bezier``, ``catmull_rom`` or
    ``quadratic`` profile (module docstring) and build its profile: a solid
    (clockwise) unless ``open_sheet``."""
    seg = to_bspline_controls(kind_coefficients(kind, points, source))
    # Snap ends within rounding of the axis (or of each other) onto it.
    scale = bs._scale(seg)
    start, end = (np.array(bs.evaluate(seg, i, t), dtype=np.float64) for i, t in ((0, 0.0),
                                                                                 (len(seg) - 1, 1.0)))
    loop, on_axis = curve_form(start, end, scale)
    what = f"{kind} curve"
    for name, p in (("starts", start), ("ends", end)):
        if p[0] < -1e-12 * scale:
            raise BSplineError(f"{source}: {what} {name} at r = {p[0]:.6g} < 0 (r must be >= 0)")
    if not (loop or on_axis or open_sheet):
        raise BSplineError(
            f"{source}: {what} is not closed: it starts at {start.round(9).tolist()} and ends at "
            f"{end.round(9).tolist()}; a solid's curve must end where it starts, or start and end "
            f"on the axis (r = 0); set open = true for a single open sheet")
    bs.validate_curve(seg, loop, source, what, solid=not open_sheet)
    if _reversed_for_outward(seg, open_sheet):
        seg = seg[::-1, ::-1].copy()  # a reversed uniform B-spline segment is the same cubic
    return BSplineProfile(points=np.array(points, dtype=np.float64), segment_controls=seg,
                          closed_loop=loop, source=source, kind=kind, open_sheet=open_sheet)


def _reversed_for_outward(seg: np.ndarray, open_sheet: bool) -> bool:
    """Whether the curve must be reversed so that its left-hand normal
    points outward: a solid's curve runs clockwise; an open sheet runs
    downwards on the whole (the integral of ``R dZ`` is negative), so that
    its normal points away from the axis like a solid's outer wall (a flat
    sheet, with a zero integral, keeps its direction)."""
    if not open_sheet:
        return bs.orientation_sign(seg) < 0
    t = (np.arange(BSPLINE_SAMPLES_PER_SEGMENT) + 0.5) / BSPLINE_SAMPLES_PER_SEGMENT
    r, _ = bs._grid_values(seg, t)
    _, dz = bs._grid_values(seg, t, derivative=True)
    return float(np.sum(r * dz)) > 1e-12 * bs._scale(seg) ** 2 * BSPLINE_SAMPLES_PER_SEGMENT
