"""Profile kinds as revolved surfaces: tessellation + exact kernels.

A *surface* (the :class:`Surface` protocol) bundles what the ``lathe`` plugin
needs from one profile kind, without any plugin code (so a native
``mi.Shape`` can reuse it):

* ``tessellate(steps, max_bands)`` -- the reference mesh (local frame);
* ``intersect(o, d, tmax, active)`` / ``occluded(...)`` -- the exact kernel
  on local-frame rays, returning ``(t, seg, u, valid)`` hits;
* ``next_crossing(...)`` -- the kernel that walks a ray through its
  crossings from one origin, each found once (no offsets);
* ``geometry(p, seg, u)`` -- geometric and shading normals, uv, dp_du, dp_dv.

:class:`PolylineSurface` is the paper's Method 1 (cone frustums, annuli,
interpolated normals); :class:`BSplineSurface` its Method 2 (uniform cubic
B-spline, degree-6 roots, exact normals). POV-Ray's other curve kinds share
Method 2: ``bezier``, ``catmull_rom`` and ``quadratic`` profiles convert to
per-segment B-spline cubics (:mod:`.profiles.spline_kinds`), and ``sor``
(:class:`SorSurface`) gives ``r^2`` as a cubic directly
(:mod:`.profiles.sor`).

Every kind but ``sor`` may be a single open sheet (``open_sheet``): a curve
whose ends are not joined, with no inside.

The registry of profile kinds: one :class:`Kind` record per kind in
:data:`KINDS` carries all that the package knows of it (the factory that
validates the points and builds the surface, the surface class, the kernel
layout its lathe sets use, which kernel family its attached and outline code
follows, whether its points are differentiable, its ``lathe-profile --kind``
name). The plugin, the scene geometry, the differentiable code and the CLI
read the record; :func:`register_kind` adds a kind.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import mitsuba as mi
import numpy as np

from .kernels.bspline import (
    BSplineData,
    bspline_geometry,
    build_bspline_data,
    build_cubic_data,
    intersect_bspline,
    next_crossing_bspline,
    occluded_bspline,
)
from .kernels.common import LatheGeometry, LatheHit
from .kernels.polyline import (
    PolylineData,
    intersect_polyline,
    next_crossing_polyline,
    occluded_polyline,
    polyline_geometry,
    profile_polyline_data,
    walk_and_test_polyline,
)
from .kernels.top_level import BSPLINE_LAYOUT, POLYLINE_LAYOUT, KindLayout
from .profiles import bspline as bs
from .profiles.bspline import BSplineProfile, make_bspline_profile
from .profiles.polyline import Profile, ProfileError, check_finite_points, make_profile
from .profiles.sor import SorProfile, make_sor_profile
from .profiles.spline_kinds import CUBIC_KINDS, make_cubic_profile
from .tessellate import TriangleMesh, revolve, tessellate_profile

__all__ = ["Surface", "CurveSurface", "PolylineSurface", "BSplineSurface", "SorSurface", "Kind", "KINDS",
           "SURFACE_KINDS", "cli_kind_names", "get_kind", "kind_of", "make_surface", "check_curve_points",
           "register_kind",
           "unregister_kind"]


class Surface(Protocol):
    """What a profile kind supplies to the ``lathe`` plugin."""

    #: The kind's name (the plugin's ``kind`` parameter).
    kind: str
    #: Whether shading normals are interpolated (always True for B-splines).
    smooth: bool
    #: The validated profile (numpy only).
    profile: Profile | BSplineProfile
    #: The user's input it was built from, where the ``lathe`` plugin keeps
    #: it (a ``plugin.profile_param.ProfileInput``, set by
    #: ``remember_input``; absent on surfaces built otherwise).
    given: Any

    @property
    def data(self) -> Any:
        """The kernel's opaque buffers (``PolylineData``, ``BSplineData``),
        built on first use; the kind's layout (:attr:`Kind.layout`) says how
        lathe sets concatenate them."""

    def mesh_rings(self) -> int:
        """Profile rings of the full reference mesh, at most (its memory
        estimate)."""

    def tessellate(self, steps: int, max_bands: int | None = None) -> TriangleMesh:
        """The reference mesh with ``steps`` azimuthal steps (local frame),
        with at most about ``max_bands`` profile bands where given (a
        proxy)."""

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> LatheHit:
        """Nearest hit with ``0 < t < tmax`` of local-frame rays ``o + t d``."""

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        """Whether local-frame rays hit the surface at some ``0 < t < tmax``."""

    def next_crossing(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float
                      ) -> tuple[LatheHit, mi.Float, mi.UInt32]:
        """The crossing after a previous one of local-frame rays walked from
        one origin: ``(hit, s, key)``."""

    def walk_and_test(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float,
                      shadow_o: mi.Point3f, shadow_d: mi.Vector3f, shadow_tmax: mi.Float,
                      shadow_active: mi.Bool) -> tuple[LatheHit, mi.Float, mi.UInt32, mi.Bool]:
        """:meth:`next_crossing` of the walked rays and :meth:`occluded` of
        the shadow rays ``shadow_o + t shadow_d``: ``(hit, s, key, occluded)``."""

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        """Normals, uv and partials at a hit ``(seg, u)`` at local point ``p``."""


class CurveSurface(Surface, Protocol):
    """What the curve kinds (every kind but ``polyline``) supply besides."""

    @property
    def profile_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Adaptive (r, z) samples of the curve, exact unit normals there,
        and the kernel's texture v (the reference mesh's rings)."""


class _KernelSurface:
    """A surface whose exact kernel works on opaque data built on first use.

    Subclasses set ``_intersect``, ``_occluded`` and ``_next_crossing``
    (the kind's kernels, as ``staticmethod``) and implement
    ``_build_data``."""

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

    def next_crossing(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float
                      ) -> tuple[LatheHit, mi.Float, mi.UInt32]:
        """The crossing after ``(after_s, after_key)`` (or after ``after_t``
        where the key is ``NO_CROSSING``) of a ray walked from one origin
        (see ``next_crossing_polyline``): ``(hit, s, key)``."""
        return self._next_crossing(self.data, o, d, tmax, active, after_s, after_key, after_t)

    def walk_and_test(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float,
                      shadow_o: mi.Point3f, shadow_d: mi.Vector3f, shadow_tmax: mi.Float,
                      shadow_active: mi.Bool) -> tuple[LatheHit, mi.Float, mi.UInt32, mi.Bool]:
        """:meth:`next_crossing` and :meth:`occluded` as two queries (kinds
        with a shared traversal override this)."""
        hit, s, key = self.next_crossing(o, d, tmax, active, after_s, after_key, after_t)
        return hit, s, key, self.occluded(shadow_o, shadow_d, shadow_tmax, shadow_active)


class PolylineSurface(_KernelSurface):
    """Revolved polyline profile (paper Method 1)."""

    kind = "polyline"
    _intersect = staticmethod(intersect_polyline)
    _occluded = staticmethod(occluded_polyline)
    _next_crossing = staticmethod(next_crossing_polyline)

    def __init__(self, profile: Profile, smooth: bool = True) -> None:
        self.profile = profile
        self.smooth = smooth

    def tessellate(self, steps: int, max_bands: int | None = None) -> TriangleMesh:
        return tessellate_profile(self.profile, steps, smooth=self.smooth, max_bands=max_bands)

    def _build_data(self) -> PolylineData:
        return profile_polyline_data(self.profile, self.smooth)

    def mesh_rings(self) -> int:
        """Two per segment (where every vertex is a crease)."""
        return 2 * self.profile.segment_count

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return polyline_geometry(self.data, p, seg, u, self.smooth)

    def walk_and_test(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float,
                      shadow_o: mi.Point3f, shadow_d: mi.Vector3f, shadow_tmax: mi.Float,
                      shadow_active: mi.Bool) -> tuple[LatheHit, mi.Float, mi.UInt32, mi.Bool]:
        """Both queries in one traced traversal (``walk_and_test_polyline``):
        the kernel's traversal is compiled once, not twice."""
        return walk_and_test_polyline(self.data, o, d, tmax, active, after_s, after_key, after_t,
                                      shadow_o, shadow_d, shadow_tmax, shadow_active)


class BSplineSurface(_KernelSurface):
    """Revolved uniform cubic B-spline profile (paper Method 2), or a
    profile of another cubic kind converted to it (``profile.kind``)."""

    smooth = True
    _intersect = staticmethod(intersect_bspline)
    _occluded = staticmethod(occluded_bspline)
    _next_crossing = staticmethod(next_crossing_bspline)

    def __init__(self, profile: BSplineProfile | SorProfile, max_angle_deg: float = 1.0) -> None:
        self.profile = profile
        self.max_angle_deg = max_angle_deg
        #: The kind's name: ``bspline``, ``bezier``, ``catmull_rom``, ``quadratic``, ``sor``.
        self.kind = profile.kind

    def _samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Adaptive ``(segment, t)`` parameters of the reference mesh's
        rings, in curve order."""
        return bs.sample_adaptive(self.profile.segment_controls, max_angle_deg=self.max_angle_deg)

    def _evaluate(self, index: np.ndarray, t: np.ndarray):
        return bs.evaluate(self.profile.segment_controls, index, t)

    def _derivative(self, index: np.ndarray, t: np.ndarray):
        return bs.derivative(self.profile.segment_controls, index, t)

    @functools.cached_property
    def profile_samples(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Adaptive (r, z) samples of the curve, exact unit normals there, and
        v = (segment + t) / segments (the exact kernel's texture v). A closed
        curve's last sample repeats its first (v = 1 there). Computed once:
        the reference mesh's rings, and its memory estimate."""
        index, t = self._samples()
        r, z = self._evaluate(index, t)
        dr, dz = self._derivative(index, t)
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
        return _split_corners(points, normals, v, index, t, self._derivative)

    def mesh_rings(self) -> int:
        """One per adaptive sample (:attr:`profile_samples`)."""
        return len(self.profile_samples[0])

    def tessellate(self, steps: int, max_bands: int | None = None) -> TriangleMesh:
        points, normals, v = self.profile_samples
        start = np.arange(len(points) - 1)
        # (a corner's two rings, at one point: no band between them)
        start = start[np.any(points[start] != points[start + 1], axis=1)]
        bands = np.stack([start, start + 1], axis=1)
        return revolve(points, normals, v, bands, steps, max_bands)

    def _build_data(self) -> BSplineData:
        return build_bspline_data(self.profile.segment_controls, free_ends=self.profile.open_sheet)

    def geometry(self, p: mi.Point3f, seg: mi.UInt32, u: mi.Float) -> LatheGeometry:
        return bspline_geometry(self.data, p, seg, u)


def _split_corners(points: np.ndarray, normals: np.ndarray, v: np.ndarray, index: np.ndarray, t: np.ndarray,
                   derivative) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples with a second ring at every joint where the curve turns
    a corner (a ``bezier`` or ``catmull_rom`` joint whose tangents differ
    by more than 0.5 degrees): the first ring with the normal the segment
    before ends with, the second with the one after starts with. With a
    single ring at a corner its normal was the next segment's: a straight
    Bezier wall between two corners was shaded with the bottom's normal at
    its foot, in black bands on the reference mesh."""
    joints = np.flatnonzero((t == 0.0) & (index > 0))
    if len(joints) == 0:
        return points, normals, v
    dr, dz = derivative(index[joints] - 1, np.ones(len(joints)))
    before = np.stack([-dz, dr], axis=1)  # (the left-hand normal, as in profile_samples)
    length = np.linalg.norm(before, axis=1)
    usable = length > 0.0
    before[usable] /= length[usable, None]
    corner = usable & (np.einsum("ij,ij->i", before, normals[joints]) < np.cos(np.radians(0.5)))
    at = joints[corner]
    if len(at) == 0:
        return points, normals, v
    return (np.insert(points, at, points[at], axis=0), np.insert(normals, at, before[corner], axis=0),
            np.insert(v, at, v[at]))


class SorSurface(BSplineSurface):
    """Revolved POV-Ray ``sor``: ``r^2`` a cubic in the height (eqs. 19-20),
    solved by the Method 2 kernel with ``r_squared``."""

    def _samples(self) -> tuple[np.ndarray, np.ndarray]:
        return self.profile.sample_parameters(self.max_angle_deg)

    def _evaluate(self, index: np.ndarray, t: np.ndarray):
        return self.profile.evaluate(index, t)

    def _derivative(self, index: np.ndarray, t: np.ndarray):
        return self.profile.derivative(index, t)

    def _build_data(self) -> BSplineData:
        return build_cubic_data(self.profile.coefficients, r_squared=True,
                                free_ends=self.profile.open_sheet)


def _polyline_surface(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet):
    profile = make_profile(points, sharp, labels, source=source, crease_angle=crease_angle,
                           open_sheet=open_sheet)
    return PolylineSurface(profile, smooth)


def check_curve_points(kind: str, points: np.ndarray, sharp: np.ndarray, labels) -> None:
    """The checks of a curve kind's points that name a point by its label
    (file and line, not its control-point number): finite and not too
    large, and no sharp flag (the curve kinds are smooth)."""
    check_finite_points(points, labels)
    if np.any(sharp):
        k = int(np.argmax(sharp))
        raise ProfileError(
            f"{labels[k]}: sharp flags are not supported for kind '{kind}' (the curve is smooth)"
        )


def _bspline_surface(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet):
    check_curve_points(kind, points, sharp, labels)
    if open_sheet:
        raise ProfileError(f"{source}: kind 'bspline' has no open form; use 'bezier' or "
                           f"'catmull_rom' for an open sheet")
    return BSplineSurface(make_bspline_profile(points, source))


def _cubic_surface(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet):
    """Bezier, Catmull-Rom and quadratic profiles (converted to B-spline cubics)."""
    check_curve_points(kind, points, sharp, labels)
    return BSplineSurface(make_cubic_profile(kind, points, source, open_sheet))


def _sor_surface(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet):
    check_curve_points(kind, points, sharp, labels)
    return SorSurface(make_sor_profile(points, source, open_sheet))


#: A kind's factory: ``(kind, points, sharp, labels, source, crease_angle,
#: smooth, open_sheet) -> Surface`` (see :func:`make_surface`).
SurfaceFactory = Callable[[str, np.ndarray, np.ndarray, list, str, float, bool, bool], Surface]


@dataclass(frozen=True)
class Kind:
    """One profile kind: all that the package knows of it.

    ``name``: the ``lathe`` plugin's ``kind`` value (and the surfaces'
    ``kind``); ``factory``: validates the points and builds the surface
    (:data:`SurfaceFactory`); ``surface_class``: the class it builds;
    ``layout``: the kernel layout (``kernels.top_level``) by which lathe
    sets of this kind concatenate their data (lathes of one layout share a
    set); ``kernel``: the kernel family, ``"polyline"`` or ``"bspline"``,
    whose attached hits, profile points and outlines the differentiable code
    uses; ``differentiable``: whether hits are attached to the points (the
    ``points`` parameter has derivatives); ``cli_name``: the
    ``lathe-profile --kind`` value (None: not offered there)."""

    name: str
    factory: SurfaceFactory
    surface_class: type
    layout: KindLayout
    kernel: str
    differentiable: bool = False
    cli_name: str | None = None

    @property
    def seg_stride(self) -> int:
        """Floats per profile segment in the kernel's first segment buffer."""
        return next(iter(self.layout.seg_buffers.values()))

    @property
    def leaf_stride(self) -> int | None:
        """Floats per BVH leaf record (None: the leaves are segments)."""
        return next(iter(self.layout.leaf_buffers.values()), None)


#: The registry of profile kinds, by name (:func:`register_kind` adds one).
KINDS: dict[str, Kind] = {}

#: (the former name of the registry)
SURFACE_KINDS = KINDS


def register_kind(kind: Kind, replace: bool = False) -> Kind:
    """Add ``kind`` to :data:`KINDS` (``replace``: also over a kind of the
    same name); returns it."""
    if kind.kernel not in ("polyline", "bspline"):
        raise ValueError(f"kind '{kind.name}': unknown kernel family '{kind.kernel}'")
    if kind.name in KINDS and not replace:
        raise ValueError(f"profile kind '{kind.name}' is registered already")
    KINDS[kind.name] = kind
    return kind


def unregister_kind(name: str) -> None:
    """Remove the kind ``name`` from :data:`KINDS`."""
    del KINDS[name]


def get_kind(name: str, source: str = "lathe") -> Kind:
    """The record of the kind ``name``; a :class:`ProfileError` naming
    ``source`` and the known kinds if there is none."""
    kind = KINDS.get(name)
    if kind is None:
        raise ProfileError(
            f"{source}: unknown profile kind '{name}' (expected one of: {', '.join(KINDS)})"
        )
    return kind


def kind_of(surface: Surface) -> Kind:
    """The record of ``surface``'s kind."""
    return KINDS[surface.kind]


def cli_kind_names() -> tuple[str, ...]:
    """The ``lathe-profile --kind`` values, in registration order."""
    return tuple(kind.cli_name for kind in KINDS.values() if kind.cli_name)


register_kind(Kind("polyline", _polyline_surface, PolylineSurface, POLYLINE_LAYOUT, "polyline",
                   differentiable=True, cli_name="polyline"))
register_kind(Kind("bspline", _bspline_surface, BSplineSurface, BSPLINE_LAYOUT, "bspline",
                   differentiable=True, cli_name="bspline"))
for _name in CUBIC_KINDS:
    register_kind(Kind(_name, _cubic_surface, BSplineSurface, BSPLINE_LAYOUT, "bspline", differentiable=True,
                       cli_name=_name))
register_kind(Kind("sor", _sor_surface, SorSurface, BSPLINE_LAYOUT, "bspline", cli_name="sor"))


def make_surface(
    kind: str,
    points: np.ndarray,
    sharp: np.ndarray,
    labels: list[str],
    source: str,
    crease_angle: float = 30.0,
    smooth: bool = True,
    open_sheet: bool = False,
) -> Surface:
    """Validate the points (once) as a profile of ``kind`` and build its
    surface (its kind's factory, :data:`KINDS`). ``labels[k]`` names point
    ``k`` and ``source`` the file or parameter in error messages;
    ``crease_angle`` and ``smooth`` concern polylines only (the curve kinds
    have exact normals); ``open_sheet`` makes the profile a single open
    sheet (``sor``: POV-Ray's ``open``, no end discs)."""
    record = get_kind(kind, source)
    surface = record.factory(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet)
    surface.kind = record.name
    return surface
