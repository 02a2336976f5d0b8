"""POV-Ray's surface of revolution (``sor``) as a profile (numpy only).

The points ``P_0 .. P_(n-1)`` (``n >= 4``) are ``(r, h)`` pairs. Between
``P_k+1`` and ``P_k+2`` (``k = 0 .. n-4``) the squared radius is the cubic in
the height (docs/method.md, eq. 19)

    r^2(h) = A h^3 + B h^2 + C h + D

through ``r_k+1^2`` and ``r_k+2^2``, with the slopes ``d(r^2)/dh = 2 r_j (r_j+1
- r_j-1) / (h_j+1 - h_j-1)`` at ``j = k+1, k+2`` (Hermite interpolation, as
POV-Ray 3.7 does): the first and the last point only set the end slopes.
The heights of ``P_1 .. P_(n-2)`` must increase strictly, and every ``r``
must be ``>= 0`` (POV-Ray's "incorrect point" errors); here ``r^2`` must
also stay positive between the points, so that the radius is real.

A segment is stored with ``h`` linear in its parameter ``u`` in [0, 1] and
``r^2`` a cubic in ``u`` (eq. 20): the exact kernel solves a cubic, not a
sextic, per leaf (:func:`lathe_shape.kernels.bspline.build_cubic_data` with
``r_squared``). Unless ``open``, POV-Ray closes the sor with flat discs at
the lowest and the highest height of the curve; they are segments too
(``r^2 = r_end^2 u^2``, constant ``h``). A closed sor is a solid, stored
clockwise (interior on the right: top disc, wall downwards, bottom disc); an
open one is the wall alone, a single sheet, outward away from the axis.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from .bspline import BSplineError, adaptive_parameters, cubic_ranges, curve_functions, resample_curve
from .limits import BSPLINE_SAMPLES_PER_SEGMENT, MAX_COORDINATE, check_point_count

__all__ = ["SorError", "SorProfile", "make_sor_profile", "sor_coefficients"]


class SorError(BSplineError):
    """An invalid ``sor`` profile; the message names the source and the point."""


@dataclass(frozen=True)
class SorProfile:
    """A validated ``sor``: per-segment power coefficients of ``r^2`` and
    ``z`` in the segment parameter."""

    #: (n, 2) points (r, h) as given.
    points: np.ndarray
    #: (n_seg, 2, 4): ``[i, 0]`` the coefficients of ``r^2``, ``[i, 1]`` those
    #: of ``z`` (ascending powers of u), clockwise for a closed sor.
    coefficients: np.ndarray
    source: str
    #: True: the wall alone (POV-Ray's ``open``), a single sheet.
    open_sheet: bool = False
    kind: str = "sor"
    closed_loop: bool = False

    @property
    def segment_count(self) -> int:
        return len(self.coefficients)

    def bounds(self) -> tuple[float, float, float]:
        """(r_max, z_min, z_max) of the curve (exact: the extrema of r^2)."""
        r2 = cubic_ranges(self.coefficients[:, 0])
        z = cubic_ranges(self.coefficients[:, 1])
        return float(np.sqrt(max(r2[:, 1].max(), 0.0))), float(z[:, 0].min()), float(z[:, 1].max())

    def evaluate(self, index, t) -> tuple[np.ndarray, np.ndarray]:
        """Curve point ``(r, z)`` of segment(s) ``index`` at ``t``."""
        c = self.coefficients[np.asarray(index)]
        r2 = _polyval(c[..., 0, :], t)
        return np.sqrt(np.maximum(r2, 0.0)), _polyval(c[..., 1, :], t)

    def derivative(self, index, t) -> tuple[np.ndarray, np.ndarray]:
        """Tangent ``(dr/du, dz/du)``, ``dr = (r^2)' / (2 r)``; on the axis
        (where that is 0 / 0 or infinite) a one-sided difference quotient
        over ``1e-6`` in ``u`` stands for it, giving the limit direction."""
        index = np.asarray(index)
        t = np.asarray(t, dtype=np.float64)
        c = self.coefficients[index]
        r = self.evaluate(index, t)[0]
        dr2 = _polyval(c[..., 0, 1:] * [1.0, 2.0, 3.0], t)
        dz = _polyval(c[..., 1, 1:] * [1.0, 2.0, 3.0], t)
        on_axis = r <= 1e-6 * self.scale()
        with np.errstate(divide="ignore", invalid="ignore"):
            dr = np.where(on_axis, 0.0, dr2 / (2.0 * r))
        if np.any(on_axis):
            step = np.where(t < 0.5, 1e-6, -1e-6)
            r_near = self.evaluate(index, t + step)[0]
            dr = np.where(on_axis, (r_near - r) / step, dr)
        return dr, dz

    def scale(self) -> float:
        """The curve's size (the diagonal of its (r, z) box, 1 if none)."""
        return self._size

    @functools.cached_property
    def _size(self) -> float:
        # Computed once: derivative() asks for it at every sample
        r_max, z_min, z_max = self.bounds()
        return float(np.hypot(r_max, z_max - z_min)) or 1.0

    def to_polyline(self, n_points: int, method: str = "uniform") -> np.ndarray:
        """(n_points, 2) points of the curve, as
        :func:`lathe_shape.profiles.bspline.to_polyline`."""
        def eval_global(T):
            i = np.minimum(np.floor(T).astype(np.int64), self.segment_count - 1)
            return np.stack(self.evaluate(i, T - i), axis=1)

        return resample_curve(eval_global, self.segment_count, False, self.scale(), n_points, method)

    def sample_parameters(self, max_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
        """Adaptive ``(segment, t)`` samples for the reference mesh, two
        arrays in curve order (:func:`.bspline.adaptive_parameters`, with a
        chord error of 1e-4 of the curve's size)."""
        # (a disc's centre, where the tangent vanishes: along the disc)
        points, tangents = curve_functions(self.evaluate, self.derivative, 0.0)
        return adaptive_parameters(self.segment_count, points, tangents, max_angle_deg, 1e-4 * self.scale())


def _polyval(c: np.ndarray, t) -> np.ndarray:
    """Ascending coefficients ``c`` (..., k) at ``t`` (broadcast)."""
    t = np.asarray(t, dtype=np.float64)
    v = np.zeros(np.broadcast_shapes(c.shape[:-1], t.shape))
    for k in range(c.shape[-1] - 1, -1, -1):
        v = v * t + c[..., k]
    return v


def sor_coefficients(points: np.ndarray) -> np.ndarray:
    """Power coefficients (n - 3, 2, 4) of ``r^2`` and ``z`` of the wall
    segments, bottom to top, ``u`` running upwards (eqs. 19-20); no checks."""
    r, h = points[:, 0], points[:, 1]
    k = np.arange(len(points) - 3)
    h0, h1 = h[k + 1], h[k + 2]
    p0, p1 = r[k + 1] ** 2, r[k + 2] ** 2
    # Slopes d(r^2)/dh at both ends, times dh/du = h1 - h0.
    m0 = 2 * r[k + 1] * (r[k + 2] - r[k]) / (h[k + 2] - h[k]) * (h1 - h0)
    m1 = 2 * r[k + 2] * (r[k + 3] - r[k + 1]) / (h[k + 3] - h[k + 1]) * (h1 - h0)
    r2 = np.stack([p0, m0, 3 * (p1 - p0) - 2 * m0 - m1, 2 * (p0 - p1) + m0 + m1], axis=1)
    z = np.stack([h0, h1 - h0, 0 * h0, 0 * h0], axis=1)
    return np.stack([r2, z], axis=1)


def _reverse(c: np.ndarray) -> np.ndarray:
    """Coefficients of ``p(1 - u)`` for the cubics ``c`` (..., 4)."""
    a, b, cc, d = (c[..., k] for k in range(4))
    return np.stack([a + b + cc + d, -b - 2 * cc - 3 * d, cc + 3 * d, -d], axis=-1)


def make_sor_profile(points: np.ndarray, source: str, open_sheet: bool = False) -> SorProfile:
    """Validate ``sor`` points (module docstring) and build the profile."""
    p = _checked_points(points, source)
    wall = sor_coefficients(p)
    _check_radius(wall, p, source)
    # Clockwise: top to bottom, so reverse the wall.
    segments = list(_reverse(wall[::-1]))
    if not open_sheet:
        (r_lo, h_lo), (r_hi, h_hi) = p[1], p[-2]
        if r_hi > 0:
            segments.insert(0, np.array([[0, 0, r_hi * r_hi, 0], [h_hi, 0, 0, 0]], dtype=np.float64))
        if r_lo > 0:
            segments.append(np.array([[r_lo * r_lo, -2 * r_lo * r_lo, r_lo * r_lo, 0],
                                      [h_lo, 0, 0, 0]], dtype=np.float64))
    coef = np.array(segments)
    return SorProfile(points=p, coefficients=coef, source=source, open_sheet=open_sheet)


def _checked_points(points: np.ndarray, source: str) -> np.ndarray:
    """POV-Ray's checks of sor points: count, r >= 0, increasing heights."""
    try:
        p = np.array(points, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError) as e:
        raise SorError(f"{source}: sor points must be (r, h) pairs of numbers ({e})") from None
    check_point_count(len(p), source, "points", BSPLINE_SAMPLES_PER_SEGMENT, SorError)
    if len(p) < 4:
        raise SorError(f"{source}: a sor needs at least 4 points (the first and the last only "
                       f"set the end slopes), got {len(p)}")
    bad = ~np.all(np.isfinite(p), axis=1) | np.any(np.abs(p) >= MAX_COORDINATE, axis=1)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise SorError(f"{source}: sor point {k + 1} is not finite or too large: {p[k].tolist()}")
    if np.any(p[:, 0] < 0):
        k = int(np.argmax(p[:, 0] < 0))
        raise SorError(f"{source}: sor point {k + 1} has a negative radius r = {p[k, 0]:g} "
                       f"(POV-Ray: incorrect point)")
    h = p[:, 1]
    rising = h[2:-1] > h[1:-2]
    if not np.all(rising):
        k = int(np.argmin(rising)) + 2
        raise SorError(f"{source}: sor point {k + 1} (h = {h[k]:g}) is not above point {k} "
                       f"(h = {h[k - 1]:g}): the heights of points 2 .. n-1 must increase strictly "
                       f"(POV-Ray: incorrect point)")
    for a, b in ((0, 2), (len(p) - 3, len(p) - 1)):
        if h[a] == h[b]:
            raise SorError(f"{source}: sor points {a + 1} and {b + 1} have the same height h = {h[a]:g}: "
                           f"the slope at point {(a + b) // 2 + 1} is undefined (POV-Ray: incorrect point)")
    return p


def _check_radius(wall: np.ndarray, p: np.ndarray, source: str) -> None:
    """``r^2`` stays positive inside the wall (its exact minimum per
    segment); only the wall's two end points may lie on the axis."""
    tol = 1e-9 * float(np.max(p[:, 0]) ** 2 or 1.0)
    n = len(wall)
    for k, c in enumerate(wall[:, 0]):
        ts = [float(x.real) for x in np.roots([3 * c[3], 2 * c[2], c[1]]) if np.any(c[1:] != 0)
              and abs(x.imag) < 1e-12 and 0.0 < x.real < 1.0]
        ts += [] if k == 0 else [0.0]
        ts += [] if k == n - 1 else [1.0]
        if not ts:
            continue
        v = np.polynomial.polynomial.polyval(np.array(ts), c)
        j = int(np.argmin(v))
        h = float(np.polynomial.polynomial.polyval(ts[j], wall[k, 1]))
        if v[j] < -tol:
            raise SorError(f"{source}: sor radius is imaginary (r^2 = {v[j]:.4g} < 0) near h = {h:.6g}, "
                           f"between points {k + 2} and {k + 3}: the cubic r^2(h) dips below 0 "
                           f"(move the points, or their neighbours that set the slopes)")
        if v[j] <= tol:
            raise SorError(f"{source}: sor curve touches the axis (r = 0) near h = {h:.6g}, between "
                           f"points {k + 2} and {k + 3}; only its lowest and highest points may")
