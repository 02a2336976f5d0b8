"""Profile kinds as revolved surfaces: tessellation + exact kernels.

A *surface* (the :class:`Surface` protocol) bundles what the ``lathe`` plugin
needs from one profile kind, without any plugin code (so a native
``mi.Shape`` can reuse it):

* ``tessellate(steps)`` -- the reference mesh (local frame);
* ``intersect(o, d, tmax, active)`` / ``occluded(...)`` -- the exact kernel
  on local-frame rays, returning ``(t, seg, u, valid)`` hits;
* ``geometry(p, seg, u)`` -- geometric and shading normals, uv, dp_du, dp_dv.

:class:`PolylineSurface` is the paper's Method 1 (cone frustums, annuli,
interpolated normals); :class:`BSplineSurface` its Method 2 (uniform cubic
B-spline, degree-6 roots, exact normals).
"""

from __future__ import annotations

import functools
from typing import Protocol

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
    intersect_polyline,
    occluded_polyline,
    polyline_geometry,
    profile_polyline_data,
)
from .profiles import bspline as bs
from .profiles.bspline import BSplineProfile, make_bspline_profile
from .profiles.polyline import Profile, ProfileError, make_profile
from .tessellate import TriangleMesh, revolve, tessellate_profile

__all__ = ["Surface", "PolylineSurface", "BSplineSurface", "SURFACE_KINDS", "make_surface"]


class Surface(Protocol):
    """What a profile kind supplies to the ``lathe`` plugin."""

    #: The kind's name (the plugin's ``kind`` parameter).
    kind: str
    #: Whether shading normals are interpolated (always True for B-splines).
    smooth: bool
    #: The validated profile (numpy only).
    profile: Profile | BSplineProfile

    def tessellate(self, steps: int) -> TriangleMesh:
        """The reference mesh with ``steps`` azimuthal steps (local frame)."""

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> LatheHit:
        """Nearest hit with ``0 < t < tmax`` of local-frame rays ``o + t d``."""

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        """Whether local-frame rays hit the surface at some ``0 < t < tmax``."""

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        """Normals, uv and partials at a hit ``(seg, u)`` at local point ``p``."""


class _KernelSurface:
    """A surface whose exact kernel works on opaque data built on first use.

    Subclasses set ``_intersect`` and ``_occluded`` (the kind's kernels, as
    ``staticmethod``) and implement ``_build_data``."""

    _data = None

    def _build_data(self):
        raise NotImplementedError

    @property
    def data(self):
        """Opaque kernel buffers, built on first use."""
        if self._data is None:
            self._data = self._build_data()
        return self._data

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> LatheHit:
        return self._intersect(self.data, o, d, tmax, active)

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        return self._occluded(self.data, o, d, tmax, active)


class PolylineSurface(_KernelSurface):
    """Revolved polyline profile (paper Method 1)."""

    kind = "polyline"
    _intersect = staticmethod(intersect_polyline)
    _occluded = staticmethod(occluded_polyline)

    def __init__(self, profile: Profile, smooth: bool = True) -> None:
        self.profile = profile
        self.smooth = smooth

    def tessellate(self, steps: int) -> TriangleMesh:
        return tessellate_profile(self.profile, steps, smooth=self.smooth)

    def _build_data(self) -> PolylineData:
        return profile_polyline_data(self.profile, self.smooth)

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return polyline_geometry(self.data, p, seg, u, self.smooth)


class BSplineSurface(_KernelSurface):
    """Revolved uniform cubic B-spline profile (paper Method 2)."""

    kind = "bspline"
    smooth = True
    _intersect = staticmethod(intersect_bspline)
    _occluded = staticmethod(occluded_bspline)

    def __init__(self, profile: BSplineProfile, max_angle_deg: float = 1.0) -> None:
        self.profile = profile
        self.max_angle_deg = max_angle_deg

    @functools.cached_property
    def profile_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Adaptive (r, z) samples of the curve, exact unit normals there, and
        v = (segment + t) / segments (the exact kernel's texture v). A closed
        curve's last sample repeats its first (v = 1 there). Computed once:
        the reference mesh's rings, and its memory estimate."""
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
        points, normals, v = self.profile_samples
        start = np.arange(len(points) - 1)
        bands = np.stack([start, start + 1], axis=1)
        return revolve(points, normals, v, bands, steps)

    def _build_data(self) -> BSplineData:
        return build_bspline_data(self.profile.segment_controls)

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return bspline_geometry(self.data, p, seg, u)


def _polyline_surface(points, sharp, labels, source, crease_angle, smooth):
    profile = make_profile(points, sharp, labels, source=source, crease_angle=crease_angle)
    return PolylineSurface(profile, smooth)


def _bspline_surface(points, sharp, labels, source, crease_angle, smooth):
    if np.any(sharp):
        k = int(np.argmax(sharp))
        raise ProfileError(
            f"{labels[k]}: sharp flags are not supported for kind 'bspline' (the curve is smooth)"
        )
    return BSplineSurface(make_bspline_profile(points, source))


#: The registry of profile kinds: the ``kind`` parameter's values and the
#: factory that validates the points and builds the surface.
SURFACE_KINDS = {"polyline": _polyline_surface, "bspline": _bspline_surface}


def make_surface(
    kind: str,
    points: np.ndarray,
    sharp: np.ndarray,
    labels: list[str],
    source: str,
    crease_angle: float = 30.0,
    smooth: bool = True,
) -> PolylineSurface | BSplineSurface:
    """Validate the points (once) as a profile of ``kind`` and build its
    surface. ``labels[k]`` names point ``k`` and ``source`` the file or
    parameter in error messages; ``crease_angle`` and ``smooth`` concern
    polylines only (B-splines have exact normals)."""
    if kind not in SURFACE_KINDS:
        raise ProfileError(
            f"{source}: unknown profile kind '{kind}' (expected one of: {', '.join(SURFACE_KINDS)})"
        )
    return SURFACE_KINDS[kind](points, sharp, labels, source, crease_angle, smooth)
