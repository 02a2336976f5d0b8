"""Uniform cubic B-spline profiles (docs/method.md, Method 2), numpy only.

A profile lives in the (r, z) half plane: ``r >= 0`` is the distance from the
lathe's local +z axis, ``z`` the position along it. The curve is a uniform
cubic B-spline of the control points ``P_0 .. P_(m-1)``; segment ``i`` uses
``P_i .. P_(i+3)`` and, for ``t`` in [0, 1], is (docs/method.md, eq. 12)

    B_i(t) = ((1-t)^3 P_i + (3t^3 - 6t^2 + 4) P_(i+1)
              + (-3t^3 + 3t^2 + 3t + 1) P_(i+2) + t^3 P_(i+3)) / 6.

Two forms, chosen by the points themselves:

* **closed** (first point == last point): a periodic B-spline. The repeated
  point counts once, and the ``n >= 3`` distinct control points give ``n``
  segments that wrap around (``P_(n+k) = P_k``).
* **open** (first point != last point): the end control points are tripled,
  so the curve starts exactly on the first point and ends exactly on the last
  one (``m + 1`` segments for ``m >= 3`` points). Both ends must lie on the
  axis (``r = 0``), so that the curve and the axis bound the solid.

``bspline_segments`` returns the per-segment control points (after closing or
tripling), which is what every other function here (and the Dr.Jit kernel in
:mod:`lathe_shape.kernels.bspline`) takes. Orientation: like polyline
profiles (docs/method.md, "The object"), the kernels expect the curve to run
clockwise in the (r right, z up) plane, interior on the right; use
:func:`orient_clockwise` on the control points first.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .crossings import first_crossing, meeting_parameters, touch_tolerance
from .errors import ProfileError
from .limits import BSPLINE_SAMPLES_PER_SEGMENT, MAX_COORDINATE, check_point_count

__all__ = [
    "BSplineError",
    "BSplineProfile",
    "make_bspline_profile",
    "bspline_segments",
    "validate_curve",
    "control_points",
    "cubic_ranges",
    "adaptive_parameters",
    "curve_functions",
    "flat_intervals",
    "unit_tangents",
    "is_closed",
    "ends_meet",
    "power_coefficients",
    "evaluate",
    "derivative",
    "signed_area",
    "orientation_sign",
    "orient_clockwise",
    "sample_adaptive",
    "to_polyline",
    "resample_curve",
]

#: Power-basis matrix of the uniform cubic B-spline: ``C = M @ P`` gives the
#: coefficients of ``1, t, t^2, t^3`` (rows) from the 4 control points (cols).
_BASIS = np.array([[1.0, 4.0, 1.0, 0.0],
                   [-3.0, 0.0, 3.0, 0.0],
                   [3.0, -6.0, 3.0, 0.0],
                   [-1.0, 3.0, -3.0, 1.0]]) / 6.0

#: ``(b - a) / (a + b)`` (0 for ``a = b = 0``): the signed area of a segment
#: is ``1/2 r^T W z`` for its power coefficients ``r``, ``z`` (:func:`signed_area`).
_AREA_WEIGHTS = np.array([[(b - a) / (a + b) if a + b else 0.0 for b in range(4)] for a in range(4)])

#: Most dense samples of the whole curve for ``to_polyline(method="adaptive")``.
_DENSE_SAMPLES = 1 << 20

#: Points evaluated at a time by :func:`_eval_global` (intervals by
#: :func:`flat_intervals`).
_EVAL_CHUNK = 1 << 16

#: Samples per segment for the self-intersection and regularity checks.
_CHECK_SAMPLES = BSPLINE_SAMPLES_PER_SEGMENT


class BSplineError(ProfileError):
    """An invalid B-spline profile; the message names the source and the problem."""


# ---------------------------------------------------------------------------
# Construction and validation
# ---------------------------------------------------------------------------

def is_closed(points: np.ndarray) -> bool:
    """True when the control points describe a closed (periodic) B-spline,
    i.e. when the first point equals the last one."""
    p = np.asarray(points, dtype=np.float64)
    return len(p) >= 2 and bool(np.array_equal(p[0], p[-1]))


def bspline_segments(points: np.ndarray, source: str = "profile") -> np.ndarray:
    """Per-segment control points of a validated cubic B-spline profile.

    Parameter ``points`` (array of shape (m, 2)):
        Control points ``(r, z)``. Closed when ``points[0] == points[-1]``
        (needs >= 3 distinct points, i.e. >= 4 rows with the repeat), open
        otherwise (needs >= 3 points, the first and last on the axis).

    Parameter ``source`` (str):
        Name of the file or scene parameter, used in error messages.

    Returns an array of shape (n_seg, 4, 2): the control points of every
    segment after closing (closed form) or tripling the ends (open form).

    Raises :class:`BSplineError` when the points are not finite, too few, the
    open ends are not on the axis, the curve crosses or touches the axis
    (r < 0 anywhere, r = 0 other than at the open ends), has a cusp (zero
    tangent), encloses no area, or intersects itself.
    """
    p = control_points(points, source, "B-spline")
    seg, closed = _segment_controls(p, source)
    validate_curve(seg, closed, source)
    return seg


def control_points(points: np.ndarray, source: str, what: str) -> np.ndarray:
    """The control points of a ``what`` curve (``B-spline``, ``bezier``,
    ...) as a finite (m, 2) float64 array, each coordinate below
    :data:`.limits.MAX_COORDINATE`; raises :class:`BSplineError`."""
    try:
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise BSplineError(f"{source}: {what} control points are not numbers ({e})") from None
    if p.ndim != 2 or p.shape[1] != 2:
        raise BSplineError(f"{source}: {what} control points must be (r, z) pairs, "
                           f"got an array of shape {p.shape}")
    check_point_count(len(p), source, "control points", _CHECK_SAMPLES, BSplineError)
    if not np.all(np.isfinite(p)):
        bad = int(np.argwhere(~np.all(np.isfinite(p), axis=1))[0, 0])
        raise BSplineError(f"{source}: {what} control point {bad + 1} is not finite: "
                           f"{p[bad].tolist()}")
    if np.any(np.abs(p) >= MAX_COORDINATE):
        bad = int(np.argwhere(np.any(np.abs(p) >= MAX_COORDINATE, axis=1))[0, 0])
        raise BSplineError(f"{source}: {what} control point {bad + 1} is too large: {p[bad].tolist()} "
                           f"(|r| and |z| must be below {MAX_COORDINATE:g}: their squares must fit "
                           f"in float32)")
    return p


def _segment_controls(p: np.ndarray, source: str) -> tuple[np.ndarray, bool]:
    """Per-segment control points (closing or tripling the ends) of finite
    (m, 2) control points, and whether the form is closed; checks the point
    count and, for the open form, that the ends lie on the axis. No
    geometric validation (:func:`validate_curve` does that)."""
    closed = is_closed(p)
    if closed:
        q = p[:-1]
        n_distinct = len(np.unique(q, axis=0))
        if n_distinct < 3:
            raise BSplineError(f"{source}: a closed B-spline needs at least 3 distinct control "
                               f"points (plus the repeated first one), got {n_distinct}")
        idx = (np.arange(len(q))[:, None] + np.arange(4)[None, :]) % len(q)
        seg = q[idx]
    else:
        if len(p) < 3:
            raise BSplineError(f"{source}: an open B-spline needs at least 3 control points "
                               f"(both ends on the axis), got {len(p)}")
        scale = _scale(p)
        for name, k in (("first", 0), ("last", len(p) - 1)):
            if abs(p[k, 0]) > 1e-12 * scale:
                raise BSplineError(
                    f"{source}: an open B-spline must start and end on the axis (r = 0); its "
                    f"{name} control point is {p[k].tolist()} (close it by repeating the first "
                    f"point at the end, or move the end to r = 0)")
        p = p.copy()
        p[0, 0] = p[-1, 0] = 0.0
        q = np.concatenate([p[:1], p[:1], p, p[-1:], p[-1:]])
        idx = np.arange(len(q) - 3)[:, None] + np.arange(4)[None, :]
        seg = q[idx]
    return seg, closed


def _scale(p: np.ndarray) -> float:
    """Size of a point set (bounding-box diagonal, 1 when degenerate)."""
    ext = float(np.linalg.norm(p.reshape(-1, 2).max(axis=0) - p.reshape(-1, 2).min(axis=0)))
    return ext if ext > 0 else 1.0


def _segments_closed(seg_ctrl: np.ndarray) -> bool:
    """Whether the curve's end equals its start (closed form)."""
    end = seg_ctrl[-1].T @ _BASIS.sum(axis=0)
    start = seg_ctrl[0].T @ _BASIS[0]
    return ends_meet(start, end, _scale(seg_ctrl))


def ends_meet(start: np.ndarray, end: np.ndarray, scale: float) -> bool:
    """Whether a curve of size ``scale`` ends where it starts: its end
    points ``(r, z)`` lie within ``1e-12 * scale`` of each other, or within
    the rounding of their coordinates (16 units in the last place of the
    largest, as :func:`.crossings.touch_tolerance`). The second is what
    evaluating the curve (eq. 12) after a kind's conversion (eq. 18) leaves
    in the ends of a loop that closes exactly: far from the origin it
    exceeds the first (a curve of size 2 at z = 1e7: 1e-9 against 2e-12)."""
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    rounding = 16.0 * np.finfo(np.float64).eps * float(max(np.abs(start).max(), np.abs(end).max()))
    return bool(np.all(np.abs(end - start) <= 1e-12 * scale + rounding))


def validate_curve(seg: np.ndarray, closed: bool, source: str, what: str = "B-spline curve",
                   solid: bool = True) -> None:
    """Geometric checks of :func:`bspline_segments` (see there) of any
    curve given by per-segment B-spline control points ``seg`` (every cubic
    kind converts to them, :mod:`.spline_kinds`); ``what`` names the curve in
    messages. ``solid=False`` (an open sheet) skips the enclosed-area test.
    Every tolerance is relative to the curve's size, so a scaled copy of a
    curve is accepted or refused alike."""
    scale = _scale(seg)
    _check_axis(power_coefficients(seg), closed, 1e-9 * scale, source, what)
    _check_regular(seg, closed, 1e-9 * scale, source, what)
    # A curve that crosses itself can enclose no (net) area: the crossing
    # test comes first to name it.
    _check_self_intersection(seg, closed, source, what)
    if solid and abs(signed_area(seg)) <= 1e-12 * scale * scale:
        raise BSplineError(f"{source}: {what} encloses no area")





def _check_axis(coef: np.ndarray, closed: bool, tol: float, source: str,
                what: str = "B-spline curve") -> None:
    """The curve stays off the axis (r > tol), but for the ends of an open
    curve: the exact minimum of R(t) per segment, at t = 0, 1 or a root of
    R'(t). The ends of an open curve are left out (with a small margin for
    the roots of R'(t): near the ends R(t) grows like t^3)."""
    n_seg = len(coef)
    for i in range(n_seg):
        c = coef[i, 0]
        first_open = not closed and i == 0
        last_open = not closed and i == n_seg - 1
        ts = ([] if first_open else [0.0]) + ([] if last_open else [1.0])
        if np.any(c[1:] != 0):
            for root in np.roots([3 * c[3], 2 * c[2], c[1]]):
                lo = 1e-6 if first_open else 0.0
                hi = 1.0 - 1e-6 if last_open else 1.0
                if abs(root.imag) < 1e-12 and lo < root.real < hi:
                    ts.append(float(root.real))
        if not ts:
            continue
        ts = np.array(ts)
        r = np.polynomial.polynomial.polyval(ts, c)
        k = int(np.argmin(r))
        if r[k] < -tol:
            raise BSplineError(f"{source}: {what} crosses the axis (r < 0) near "
                               f"t={i + ts[k]:.4g} (segment {i}, r = {r[k]:.4g})")
        if r[k] <= tol:
            raise BSplineError(f"{source}: {what} touches the axis (r = 0) near "
                               f"t={i + ts[k]:.4g} (segment {i}); only the ends of an open "
                               f"curve may lie on the axis")


def _check_regular(seg: np.ndarray, closed: bool, tol: float, source: str,
                   what: str = "B-spline curve") -> None:
    """The tangent may vanish only at the ends of an open curve (tripled
    control points); elsewhere a tangent shorter than ``tol`` is a cusp."""
    t = np.linspace(0.0, 1.0, _CHECK_SAMPLES + 1)
    dr, dz = _grid_values(seg, t, derivative=True)
    speed = np.hypot(dr, dz)
    ends = np.zeros_like(speed, dtype=bool)
    if not closed:
        ends[0, :2] = True
        ends[-1, -2:] = True
    slow = (speed <= tol) & ~ends
    if np.any(slow):
        i, j = np.argwhere(slow)[0]
        raise BSplineError(f"{source}: {what} has a cusp (zero tangent) near "
                           f"t={i + t[j]:.4g}; avoid tripled interior control points")


def _grid_values(seg: np.ndarray, t: np.ndarray, derivative: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``(R, Z)`` (or their derivatives), each of shape (n_seg, len(t)), of
    every segment at the same parameters ``t``: one matrix product of the
    power coefficients, no per-sample copies of them."""
    k = np.arange(4)[:, None]
    if derivative:
        powers = k * t[None, :] ** np.maximum(k - 1, 0)
    else:
        powers = t[None, :] ** k
    values = power_coefficients(seg) @ powers  # (n_seg, 2, len(t))
    return values[:, 0], values[:, 1]


def _check_self_intersection(seg: np.ndarray, closed: bool, source: str,
                             what: str = "B-spline curve") -> None:
    """Self-intersection test of the curve flattened to ``_CHECK_SAMPLES``
    chords per segment, with the polyline profiles' crossing routine
    (:func:`.crossings.first_crossing`, ``n log n`` in the chord count)."""
    r, z = _grid_values(seg, np.arange(_CHECK_SAMPLES) / _CHECK_SAMPLES)
    pts = np.stack([r.ravel(), z.ravel()], axis=1)
    if not closed:  # the curve's end point
        pts = np.concatenate([pts, np.stack(evaluate(seg, len(seg) - 1, 1.0))[None, :]])
    pair = first_crossing(pts, closed, touch_tolerance(pts))
    if pair is None:
        return
    i, j = pair
    m = len(pts)
    u, v = meeting_parameters(pts[i], pts[(i + 1) % m], pts[j], pts[(j + 1) % m])
    point = pts[i] + u * (pts[(i + 1) % m] - pts[i])
    t1, t2 = (i + u) / _CHECK_SAMPLES, (j + v) / _CHECK_SAMPLES
    raise BSplineError(f"{source}: {what} intersects itself near t={t1:.4g} "
                       f"and t={t2:.4g} (point {point.round(6).tolist()})")


# ---------------------------------------------------------------------------
# Evaluation
# ---------------------------------------------------------------------------

def power_coefficients(seg_ctrl: np.ndarray) -> np.ndarray:
    """Power-basis coefficients of every segment.

    Returns an array of shape (n_seg, 2, 4): ``[i, 0, k]`` is the coefficient
    of ``t^k`` in ``R_i(t)`` and ``[i, 1, k]`` the one in ``Z_i(t)``
    (ascending powers, ``k = 0..3``), so that
    ``R_i(t) = c[i,0,0] + c[i,0,1] t + c[i,0,2] t^2 + c[i,0,3] t^3``.
    """
    seg = np.asarray(seg_ctrl, dtype=np.float64)
    return np.einsum("kj,ijc->ick", _BASIS, seg)


def evaluate(seg_ctrl: np.ndarray, seg_index, t) -> tuple[np.ndarray, np.ndarray]:
    """Curve point ``(R(t), Z(t))`` of segment(s) ``seg_index`` at ``t``
    (both broadcast; eq. 12)."""
    return _point_of(power_coefficients(seg_ctrl)[np.asarray(seg_index)], t)


def derivative(seg_ctrl: np.ndarray, seg_index, t) -> tuple[np.ndarray, np.ndarray]:
    """Tangent ``(dR/dt, dZ/dt)`` of segment(s) ``seg_index`` at ``t``."""
    return _tangent_of(power_coefficients(seg_ctrl)[np.asarray(seg_index)], t)


def _point_of(c: np.ndarray, t) -> tuple[np.ndarray, np.ndarray]:
    """:func:`evaluate` from the segments' power coefficients ``c``."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    powers = np.concatenate([np.ones_like(t), t, t * t, t * t * t], axis=-1)
    r = np.sum(c[..., 0, :] * powers, axis=-1)
    z = np.sum(c[..., 1, :] * powers, axis=-1)
    return r, z


def _tangent_of(c: np.ndarray, t) -> tuple[np.ndarray, np.ndarray]:
    """:func:`derivative` from the segments' power coefficients ``c``."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    powers = np.concatenate([np.zeros_like(t), np.ones_like(t), 2 * t, 3 * t * t], axis=-1)
    return np.sum(c[..., 0, :] * powers, axis=-1), np.sum(c[..., 1, :] * powers, axis=-1)


def signed_area(seg_ctrl: np.ndarray) -> float:
    """Exact signed area enclosed by the curve (closed along the axis for an
    open curve), positive when counter-clockwise in the (r right, z up) plane.

    Green's theorem: ``A = 1/2 sum_i int_0^1 (R Z' - Z R') dt``; the closing
    piece along the axis has ``R = R' = 0`` and adds nothing. With
    ``R = sum_a r_a t^a`` and ``Z = sum_b z_b t^b`` the integral is
    ``sum_(a,b) r_a z_b (b - a) / (a + b)`` (the ``a = b = 0`` term is 0).
    """
    c = power_coefficients(seg_ctrl)
    return 0.5 * float(np.einsum("ia,ab,ib->", c[:, 0], _AREA_WEIGHTS, c[:, 1]))


def orientation_sign(seg_ctrl: np.ndarray) -> int:
    """+1 when the curve runs clockwise in the (r right, z up) plane (solid
    interior on the right when walking forward, as the kernels expect),
    -1 otherwise."""
    return 1 if signed_area(seg_ctrl) < 0 else -1


def orient_clockwise(points: np.ndarray, source: str = "profile") -> np.ndarray:
    """Control points, reversed when needed so that the curve is clockwise.

    Reversing the control points of a uniform B-spline reverses the curve
    (the basis is symmetric under ``t -> 1 - t``), for both forms.
    """
    return _validated_clockwise(points, source)[0]


def _validated_clockwise(points: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Validate the curve once (:func:`bspline_segments`) and orient it
    clockwise: (control points, per-segment control points). The reversed
    curve is the same curve, so it is rebuilt without validating again."""
    p = np.array(points, dtype=np.float64)
    seg = bspline_segments(p, source)
    if orientation_sign(seg) > 0:
        return p, seg
    p = p[::-1].copy()
    return p, _segment_controls(p, source)[0]


# ---------------------------------------------------------------------------
# The validated profile
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class BSplineProfile:
    """A validated, clockwise uniform cubic B-spline profile, or a profile
    of another cubic kind (:mod:`.spline_kinds`) in the same per-segment
    form."""

    #: (m, 2) control points (B-splines: clockwise, closed form without the
    #: repeat; other kinds: as given).
    points: np.ndarray
    #: (n_seg, 4, 2) uniform B-spline control points of each curve segment
    #: (clockwise for a solid).
    segment_controls: np.ndarray
    #: True when the curve's end is its start (closed loop).
    closed_loop: bool
    source: str
    #: The profile kind (``bspline``, ``bezier``, ``catmull_rom``, ``quadratic``).
    kind: str = "bspline"
    #: True for a single open sheet (no inside), False for a solid.
    open_sheet: bool = False

    @property
    def segment_count(self) -> int:
        return len(self.segment_controls)

    def bounds(self) -> tuple[float, float, float]:
        """(r_max, z_min, z_max) of the control polygon (bounds the curve);
        for the other kinds, whose B-spline control points may lie far from
        the curve, of the curve itself."""
        if self.kind != "bspline":
            coef = power_coefficients(self.segment_controls)
            r, z = cubic_ranges(coef[:, 0]), cubic_ranges(coef[:, 1])
            return float(r[:, 1].max()), float(z[:, 0].min()), float(z[:, 1].max())
        c = self.segment_controls.reshape(-1, 2)
        return float(c[:, 0].max()), float(c[:, 1].min()), float(c[:, 1].max())


def cubic_ranges(c: np.ndarray) -> np.ndarray:
    """(n, 2) exact (min, max) on [0, 1] of the cubics with ascending
    coefficients ``c`` (n, 4): at the ends or a root of the derivative."""
    out = []
    for ck in c:
        ts = [0.0, 1.0]
        if np.any(ck[1:] != 0):
            ts += [float(x.real) for x in np.roots([3 * ck[3], 2 * ck[2], ck[1]])
                   if abs(x.imag) < 1e-12 and 0.0 < x.real < 1.0]
        v = np.polynomial.polynomial.polyval(np.array(ts), ck)
        out.append((v.min(), v.max()))
    return np.array(out)


def make_bspline_profile(points: np.ndarray, source: str) -> BSplineProfile:
    """Validate B-spline control points (see the module docstring) and
    orient them clockwise."""
    points, controls = _validated_clockwise(points, source)
    return BSplineProfile(points=points, segment_controls=controls, closed_loop=is_closed(points),
                          source=source)


# ---------------------------------------------------------------------------
# Sampling
# ---------------------------------------------------------------------------

def unit_tangents(tangent: np.ndarray, chord: np.ndarray, tiny: float) -> np.ndarray:
    """Unit tangents from the (n, 2) tangent vectors ``tangent``; where the
    speed is at most ``tiny`` (the zero-speed ends of an open curve, a
    disc's centre) the limit direction, the segment's ``chord`` (n, 2), is
    used instead. A zero vector stays zero."""
    speed = np.linalg.norm(tangent, axis=1)
    slow = speed <= tiny
    direction = np.where(slow[:, None], chord, tangent)
    length = np.where(slow, np.linalg.norm(chord, axis=1), speed)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(length[:, None] > 0, direction / length[:, None], direction)


def sample_adaptive(seg_ctrl: np.ndarray, max_angle_deg: float = 2.0,
                    max_error: float | None = None,
                    max_depth: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Adaptive parameter samples for a reference tessellation.

    Every segment's interval [0, 1] is bisected until, on each piece, the
    tangent turns by at most ``max_angle_deg`` and the curve strays from
    the chord by at most ``max_error`` (default: 1e-4 of the profile's
    bounding-box diagonal; checked at the quarter points), or ``max_depth``
    bisections are reached (:func:`adaptive_parameters`).

    Returns ``(segment, t)``, two arrays in curve order, always holding
    every segment's ``t = 0`` and the curve's end ``(n_seg - 1, 1.0)`` (for
    a closed curve that end is the start point again).
    """
    seg_ctrl = np.asarray(seg_ctrl, dtype=np.float64)
    # Once for the curve (not per sample: that made sampling quadratic)
    coeffs = power_coefficients(seg_ctrl)
    size = _scale(seg_ctrl)
    if max_error is None:
        max_error = 1e-4 * size

    points, tangents = curve_functions(lambda index, t: _point_of(coeffs[index], t),  # eq. 12
                                       lambda index, t: _tangent_of(coeffs[index], t), 1e-9 * size)
    return adaptive_parameters(len(seg_ctrl), points, tangents, max_angle_deg, max_error, max_depth)


#: ``(index, t) -> (n, 2)``: points or unit tangents of a curve at the
#: parameters ``t`` of its segments ``index`` (arrays of one length).
CurveFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]


def curve_functions(point_of: Callable, tangent_of: Callable,
                    tiny: float) -> tuple[CurveFunction, CurveFunction]:
    """The ``points`` and unit ``tangents`` of a curve for
    :func:`adaptive_parameters`, from ``point_of(index, t)`` and
    ``tangent_of(index, t)`` (each a pair of arrays ``(r, z)``): a tangent
    of speed at most ``tiny`` falls back on its segment's chord
    (:func:`unit_tangents`)."""
    def points(index: np.ndarray, t: np.ndarray) -> np.ndarray:
        return np.stack(point_of(index, t), axis=1)

    def tangents(index: np.ndarray, t: np.ndarray) -> np.ndarray:
        chord = points(index, np.ones_like(t)) - points(index, np.zeros_like(t))
        return unit_tangents(np.stack(tangent_of(index, t), axis=1), chord, tiny)

    return points, tangents


def adaptive_parameters(n_seg: int, points: CurveFunction, tangents: CurveFunction, max_angle_deg: float,
                        max_error: float, max_depth: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """The bisection of :func:`sample_adaptive` for any curve of ``n_seg``
    segments: ``points(index, t)`` its (r, z) points, ``tangents(index,
    t)`` its unit tangents (the ``sor`` kind's radius is a square root).

    Breadth first: each round tests every open interval of every segment at
    once (:func:`flat_intervals`), keeps the flat ones (and all of them at
    ``max_depth``) and halves the others; sorting the kept intervals by
    (segment, start) gives the curve order. The intervals, their test and
    so the samples are those of a depth-first bisection per segment.
    """
    cos_max = math.cos(math.radians(max_angle_deg))
    index = np.arange(n_seg)
    t0, t1 = np.zeros(n_seg), np.ones(n_seg)
    kept_index, kept_t = [], []
    for depth in range(max_depth + 1):
        if depth == max_depth:
            flat = np.ones(len(index), dtype=bool)
        else:
            flat = flat_intervals(points, tangents, index, t0, t1, cos_max, max_error)
        kept_index.append(index[flat])
        kept_t.append(t0[flat])
        index, t0, t1 = _halves(index[~flat], t0[~flat], t1[~flat])
        if len(index) == 0:
            break
    index, t = np.concatenate(kept_index), np.concatenate(kept_t)
    order = np.lexsort((t, index))
    return np.append(index[order], n_seg - 1), np.append(t[order], 1.0)


def _halves(index: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Both halves of each interval ``[t0, t1]`` of segment ``index``."""
    middle = 0.5 * (t0 + t1)
    return np.repeat(index, 2), np.stack([t0, middle], axis=1).ravel(), np.stack([middle, t1], axis=1).ravel()


def flat_intervals(points: CurveFunction, tangents: CurveFunction, index: np.ndarray, t0: np.ndarray,
                   t1: np.ndarray, cos_max: float, max_error: float) -> np.ndarray:
    """Whether the curve is flat on each interval ``[t0, t1]`` of segment
    ``index``: its unit tangents at both ends make a cosine of at least
    ``cos_max``, and its points at the quarters lie within ``max_error`` of
    the chord (of the start point where the chord has no length).
    Evaluated :data:`_EVAL_CHUNK` intervals at a time (bounded memory)."""
    flat = np.empty(len(index), dtype=bool)
    for start in range(0, len(index), _EVAL_CHUNK):
        part = slice(start, start + _EVAL_CHUNK)
        flat[part] = _flat(points, tangents, index[part], t0[part], t1[part], cos_max, max_error)
    return flat


def _flat(points: CurveFunction, tangents: CurveFunction, index: np.ndarray, t0: np.ndarray,
          t1: np.ndarray, cos_max: float, max_error: float) -> np.ndarray:
    """:func:`flat_intervals` of one chunk of intervals. (The comparisons
    are written so that a NaN passes each test, as the scalar test did.)"""
    turns = np.sum(tangents(index, t0) * tangents(index, t1), axis=1) < cos_max
    a = points(index, t0)
    chord = points(index, t1) - a
    length = np.linalg.norm(chord, axis=1)
    strays = np.zeros(len(index), dtype=bool)
    for f in (0.25, 0.5, 0.75):
        m = points(index, t0 + f * (t1 - t0)) - a
        cross = np.abs(chord[:, 0] * m[:, 1] - chord[:, 1] * m[:, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            distance = np.where(length > 0, cross / length, np.linalg.norm(m, axis=1))
        strays |= distance > max_error
    return ~turns & ~strays


def to_polyline(seg_ctrl: np.ndarray, n_points: int, method: str = "uniform") -> np.ndarray:
    """Polyline approximation of the curve with ``n_points`` points.

    Parameter ``method``:
        ``"uniform"``: uniform in the global parameter ``T = seg + t``.
        ``"adaptive"``: points placed at equal steps of the turning angle
        (docs/method.md section 2.3: keep the angle between successive segments
        small and nearly constant), blended with 10% arc length so straight
        stretches still get points.

    Returns an (n_points, 2) array of ``(r, z)`` points on the curve (fewer
    where points would lie within 1e-9 of the curve's size of the one
    before: where the curve's speed vanishes, at an open B-spline's tripled
    end control points). A closed curve gives a closed polyline (last point
    == first point); an end on the axis stays exactly on it (r = 0).
    """
    seg_ctrl = np.asarray(seg_ctrl, dtype=np.float64)
    return resample_curve(lambda T: _eval_global(seg_ctrl, T), len(seg_ctrl),
                          _segments_closed(seg_ctrl), _scale(seg_ctrl), n_points, method)


def resample_curve(eval_global, n_seg: int, closed: bool, scale: float, n_points: int,
                   method: str = "uniform") -> np.ndarray:
    """:func:`to_polyline` of any curve of ``n_seg`` segments:
    ``eval_global(T)`` gives its (len(T), 2) points at global parameters
    ``T = segment + t``; ``scale`` is its size (ends within ``1e-12 scale``
    of the axis are put on it)."""
    n_min = 4 if closed else 3
    if n_points < n_min:
        raise BSplineError(f"to_polyline: need at least {n_min} points, got {n_points}")
    check_point_count(n_points, "to_polyline", error=BSplineError)
    if method == "uniform":
        T = np.linspace(0.0, n_seg, n_points)
    elif method == "adaptive":
        # Dense sampling, cumulative turning angle + arc length, inverted;
        # 256 samples per segment, fewer for very many segments (bounded memory).
        per_segment = max(16, min(256, _DENSE_SAMPLES // n_seg))
        dense = np.linspace(0.0, n_seg, per_segment * n_seg + 1)
        pts = eval_global(dense)
        chord = np.diff(pts, axis=0)
        length = np.hypot(chord[:, 0], chord[:, 1])
        ang = np.arctan2(chord[:, 1], chord[:, 0])
        turn = np.abs(np.angle(np.exp(1j * np.diff(ang))))
        turn = np.concatenate([[0.0], turn])  # turn at the start of each chord
        total_turn, total_len = turn.sum(), length.sum()
        w = 0.1 * total_turn / total_len if total_turn > 0 else 1.0
        measure = np.concatenate([[0.0], np.cumsum(0.5 * (turn + np.append(turn[1:], 0.0))
                                                   + w * length)])
        target = np.linspace(0.0, measure[-1], n_points)
        T = np.interp(target, measure, dense)
    else:
        raise BSplineError(f"to_polyline: unknown method {method!r} (use 'uniform' or 'adaptive')")
    T[0], T[-1] = 0.0, float(n_seg)
    pts = eval_global(T)
    if closed:
        pts[-1] = pts[0]
    else:  # ends on the axis stay exactly there (an open sheet's need not be)
        near_axis = np.abs(pts[[0, -1], 0]) <= 1e-12 * scale
        pts[[0, -1], 0] = np.where(near_axis, 0.0, pts[[0, -1], 0])
    return _without_tiny_steps(pts, 1e-9 * scale)


def _without_tiny_steps(pts: np.ndarray, tol: float) -> np.ndarray:
    """``pts`` less the points within ``tol`` of the point kept before them
    (the ends stay): where the curve's speed vanishes (an open B-spline's
    tripled end control points), a fine uniform sampling puts points
    closer than a polyline's touch tolerance, which the polyline refused
    as too short a segment."""
    step = np.hypot(*np.diff(pts, axis=0).T)
    if np.all(step > tol):
        return pts
    keep = [0]
    for k in range(1, len(pts)):
        if np.hypot(*(pts[k] - pts[keep[-1]])) > tol:
            keep.append(k)
    if keep[-1] != len(pts) - 1:
        keep[-1] = len(pts) - 1  # (the end replaces the point kept within tol of it)
    return pts[keep]


def _eval_global(seg_ctrl: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Points at global parameters ``T = seg + t`` in [0, n_seg], evaluated
    in chunks (bounded memory for any number of points)."""
    n_seg = len(seg_ctrl)
    out = np.empty((len(T), 2))
    for start in range(0, len(T), _EVAL_CHUNK):
        chunk = T[start:start + _EVAL_CHUNK]
        i = np.minimum(np.floor(chunk).astype(np.int64), n_seg - 1)
        r, z = evaluate(seg_ctrl, i, chunk - i)
        out[start:start + len(chunk), 0], out[start:start + len(chunk), 1] = r, z
    return out
