"""Profile kinds as revolved surfaces: tessellation + exact kernels.

A *surface* bundles what the ``lathe`` plugin needs from one profile kind,
without any plugin code (so a native ``mi.Shape`` can reuse it):

* ``tessellate(steps)`` -- the reference mesh (local frame);
* ``intersect(o, d, tmax, active)`` / ``occluded(...)`` -- the exact kernel
  on local-frame rays, returning ``(t, seg, u, valid)`` hits;
* ``geometry(p, seg, u)`` -- geometric and shading normals, uv, dp_du, dp_dv.

:class:`PolylineSurface` is the paper's Method 1 (cone frustums, annuli,
interpolated normals); :class:`BSplineSurface` its Method 2 (uniform cubic
B-spline, degree-6 roots, exact normals).
"""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from .kernels.bspline import (
    BSplineData,
    bspline_geometry,
    build_bspline_data,
    intersect_bspline,
    occluded_bspline,
)
from .kernels.common import LatheGeometry, LatheHit
from .kernels.polyline import (
    PolylineData,
    build_polyline_data,
    intersect_polyline,
    occluded_polyline,
    polyline_geometry,
)
from .profiles import bspline as bs
from .profiles.polyline import Profile
from .tessellate import TriangleMesh, revolve, tessellate_profile

__all__ = ["PolylineSurface", "BSplineProfile", "BSplineSurface", "SURFACE_KINDS"]


class PolylineSurface:
    """Revolved polyline profile (paper Method 1)."""

    kind = "polyline"

    def __init__(self, profile: Profile, smooth: bool = True) -> None:
        self.profile = profile
        self.smooth = smooth
        self._data = None

    def tessellate(self, steps: int) -> TriangleMesh:
        return tessellate_profile(self.profile, steps, smooth=self.smooth)

    def _end_normals(self) -> tuple[np.ndarray, np.ndarray]:
        if self.smooth:
            return self.profile.normal_start, self.profile.normal_end
        flat = self.profile.segment_normals()
        return flat, flat

    @property
    def data(self) -> PolylineData:
        """Opaque kernel buffers, built on first use."""
        if self._data is None:
            p0, p1 = self.profile.segment_points()
            n0, n1 = self._end_normals()
            self._data = build_polyline_data(
                p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1], n0[:, 0], n0[:, 1], n1[:, 0], n1[:, 1]
            )
        return self._data

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> LatheHit:
        return intersect_polyline(self.data, o, d, tmax, active)

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        return occluded_polyline(self.data, o, d, tmax, active)

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return polyline_geometry(self.data, p, seg, u, self.smooth)


@dataclass(frozen=True)
class BSplineProfile:
    """A validated, clockwise uniform cubic B-spline profile."""

    #: (m, 2) control points (clockwise; closed form without the repeat).
    points: np.ndarray
    #: (n_seg, 4, 2) control points of each curve segment.
    segment_controls: np.ndarray
    #: True for the closed periodic form, False for the open form.
    closed_loop: bool
    source: str

    @property
    def segment_count(self) -> int:
        return len(self.segment_controls)

    def bounds(self) -> tuple[float, float, float]:
        """(r_max, z_min, z_max) of the control polygon (bounds the curve)."""
        c = self.segment_controls.reshape(-1, 2)
        return float(c[:, 0].max()), float(c[:, 1].min()), float(c[:, 1].max())


def make_bspline_profile(points: np.ndarray, source: str) -> BSplineProfile:
    """Validate B-spline control points (see :mod:`lathe_shape.profiles.bspline`) and
    orient them clockwise."""
    points = bs.orient_clockwise(np.asarray(points, dtype=np.float64), source)
    closed = bs.is_closed(points)
    controls = bs.bspline_segments(points, source)
    return BSplineProfile(points=points, segment_controls=controls, closed_loop=closed, source=source)


class BSplineSurface:
    """Revolved uniform cubic B-spline profile (paper Method 2)."""

    kind = "bspline"
    smooth = True

    def __init__(self, profile: BSplineProfile, max_angle_deg: float = 1.0) -> None:
        self.profile = profile
        self.max_angle_deg = max_angle_deg
        self._data = None

    def sample_profile(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Adaptive (r, z) samples of the curve, exact unit normals there, and
        v = (segment + t) / segments (the exact kernel's texture v). A closed
        curve's last sample repeats its first (v = 1 there)."""
        seg = self.profile.segment_controls
        samples = bs.sample_adaptive(seg, max_angle_deg=self.max_angle_deg)
        index = np.array([i for i, _ in samples])
        t = np.array([t for _, t in samples])
        r, z = bs.evaluate(seg, index, t)
        dr, dz = bs.derivative(seg, index, t)
        points = np.stack([r, z], axis=1)
        tangent = np.stack([dr, dz], axis=1)
        v = (index + t) / self.profile.segment_count
        # Where the tangent vanishes (the tripled ends of the open form, whose
        # first and last segments are straight lines), use the chord.
        scale = float(np.abs(points).max()) or 1.0
        length = np.linalg.norm(tangent, axis=1)
        degenerate = length <= 1e-9 * scale
        chord = np.zeros_like(points)
        chord[:-1] = points[1:] - points[:-1]
        chord[-1] = points[-1] - points[-2]
        tangent[degenerate] = chord[degenerate]
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        normals = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)  # left-hand: outward
        points[np.abs(points[:, 0]) < 1e-12 * scale, 0] = 0.0
        if self.profile.closed_loop:
            points[-1] = points[0]  # bit-identical seam positions
        return points, normals, v

    def tessellate(self, steps: int) -> TriangleMesh:
        points, normals, v = self.sample_profile()
        start = np.arange(len(points) - 1)
        bands = np.stack([start, start + 1], axis=1)
        return revolve(points, normals, v, bands, steps)

    @property
    def data(self) -> BSplineData:
        """Opaque kernel buffers, built on first use."""
        if self._data is None:
            self._data = build_bspline_data(self.profile.segment_controls)
        return self._data

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> LatheHit:
        return intersect_bspline(self.data, o, d, tmax, active)

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        return occluded_bspline(self.data, o, d, tmax, active)

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return bspline_geometry(self.data, p, seg, u)


#: Profile kinds the ``kind`` parameter accepts.
SURFACE_KINDS = ("polyline", "bspline")
