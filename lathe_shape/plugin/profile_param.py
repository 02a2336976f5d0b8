"""A lathe's profile as a scene parameter: ``<id>.points`` in ``mi.traverse``.

The parameter is the flat ``(r, z, r, z, ...)`` array of the points exactly
as the user gave them (polyline vertices or B-spline control points, in the
user's order and orientation, a closed profile's repeated first point
included). The kernels work on the validated, clockwise *canonical* profile
(lathe_shape/profiles), which may reverse, rotate or shorten that list, so
this module also keeps the index maps from the canonical segments back to
the user's points: the attached hits (lathe_shape/kernels/attached.py)
gather their coordinates through them, and the gradients land on the
user's points.

Closed polyline and B-spline profiles given in the ``last == first`` form:
the canonical profile refers to the first point only, in either orientation
of the list, so the gradient of the repeated last point (the closing copy)
is zero. An update's value of the copy is not read: the copy follows the
first point (moving the copy alone is accepted and changes nothing; the
parameter keeps the value given). The cubic kinds (``bezier``,
``catmull_rom``, ``quadratic``) have no closing copy: every point given
is read, a loop's repeated points each get their own share of the
gradient, and an update that moves one of them alone opens the curve and
is refused.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..profiles import ProfileError
from ..profiles.spline_kinds import CUBIC_KINDS, control_weights
from ..profiles.text import PointLabels
from ..surfaces import BSplineSurface, PolylineSurface, kind_of, make_surface

__all__ = ["ProfileInput", "ProfileIndex", "profile_index", "rebuild_surface", "remember_input"]


@dataclass(frozen=True)
class ProfileInput:
    """What the user gave for a profile (everything but the points is kept
    when the points are updated)."""

    #: ``polyline`` or ``bspline``.
    kind: str
    #: (n, 2) float64 points in the user's order.
    points: np.ndarray
    #: (n,) bool sharp flags.
    sharp: np.ndarray
    #: Labels of the points for error messages.
    labels: Sequence[str]
    #: The file or parameter that gave them.
    source: str
    crease_angle: float
    smooth: bool
    #: Whether the profile is an open sheet (the ``open`` parameter).
    open_sheet: bool = False


def remember_input(surface: PolylineSurface | BSplineSurface, points, sharp, labels, source: str,
                   crease_angle: float, smooth: bool,
                   open_sheet: bool = False) -> PolylineSurface | BSplineSurface:
    """Attach the user's input to a freshly built surface (``surface.given``)
    so that the ``points`` parameter can expose and rebuild it."""
    surface.given = ProfileInput(surface.kind, np.array(points, dtype=np.float64).reshape(-1, 2),
                                 np.asarray(sharp, dtype=bool).copy(),
                                 labels if isinstance(labels, PointLabels) else list(labels), source,
                                 float(crease_angle), bool(smooth), bool(open_sheet))
    return surface


def _repeats_first_point(given: ProfileInput) -> bool:
    """Whether a solid polyline or B-spline profile was given in the
    closed form whose last point repeats the first."""
    points = np.asarray(given.points)
    return (given.kind in ("polyline", "bspline") and not given.open_sheet and len(points) > 3
            and bool(np.all(points[0] == points[-1])))


def rebuild_surface(given: ProfileInput, values: mi.Float | np.ndarray,
                    who: str = "lathe: parameter 'points'") -> PolylineSurface | BSplineSurface:
    """Validate new point coordinates (flat ``r, z`` pairs, the user's order)
    as the profile ``given`` describes and build its surface; raises
    :class:`ProfileError` with the messages of loading, naming ``who`` (the
    parameter) and the points by their number in it (``point 1`` first)."""
    flat = np.asarray(values, dtype=np.float64).ravel()
    if flat.size != given.points.size:
        raise ProfileError(
            f"{who} needs {given.points.size} values "
            f"({len(given.points)} (r, z) pairs, as loaded), got {flat.size}"
        )
    points = flat.reshape(-1, 2)
    if _repeats_first_point(given):
        # The closing copy of the first point follows it: the gradient
        # reaches the first copy alone (the surface reads that one), so an
        # optimiser moved only it, and the next update refused the profile
        # as open. (Its own value in ``points`` is not read.)
        points = points.copy()
        points[-1] = points[0]
    labels = PointLabels.counting(who, len(points))  # "WHO, point 1", ... (built only when read)
    surface = make_surface(given.kind, points, given.sharp, labels, who, given.crease_angle,
                           given.smooth, given.open_sheet)
    return remember_input(surface, points, given.sharp, given.labels, given.source,
                          given.crease_angle, given.smooth, given.open_sheet)


@dataclass
class ProfileIndex:
    """Index maps from the canonical surface to the user's points (opaque
    Dr.Jit buffers, built once per profile).

    Polylines: ``ends`` holds per segment the user indices of its start and
    end point (2 per segment); ``blend`` per segment end ``(w_own, w_nb, c_r,
    c_z)`` and ``neighbour`` the segment averaged there: the shading normal
    at that end is ``normalize(w_own n_seg + w_nb n_neighbour + (c_r, c_z))``
    (eq. 10's vertex normals: an average, a crease, or the axial normal of
    a smooth cap). B-splines: ``controls`` holds the user indices of the 4
    control points of every segment. The kinds converted to B-splines
    (``bezier``, ``catmull_rom``, ``quadratic``): each of a segment's 4
    B-spline controls is a weighted sum of ``width`` user points (eq. 18),
    ``controls`` their indices and ``weights`` their weights (``width`` per
    control, 4 controls per segment); for ``bspline`` ``width`` is 1 and
    ``weights`` None. ``held``: per user point, whether it is a solid's
    end on the axis, where it stays (its ``r`` has no derivative; see
    :func:`_held_on_axis`).
    """

    ends: mi.UInt32 | None = None
    blend: mi.Float | None = None
    neighbour: mi.UInt32 | None = None
    controls: mi.UInt32 | None = None
    weights: mi.Float | None = None
    width: int = 1
    held: mi.Bool | None = None


def _user_index(user: np.ndarray, canonical: np.ndarray) -> np.ndarray:
    """For every canonical point, the index of the first equal user point
    (the canonical profile copies the user's coordinates bit for bit)."""
    first: dict[tuple[float, float], int] = {}
    for k, point in enumerate(map(tuple, user.tolist())):
        first.setdefault(point, k)
    try:
        return np.array([first[point] for point in map(tuple, canonical.tolist())], dtype=np.int64)
    except KeyError:
        raise AssertionError("profile point not found among the given points") from None


def _end_blend(profile, seg_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per segment end (start, end interleaved): ``(w_own, w_nb, c_r, c_z)``
    and the neighbour segment, recovering which rule of
    ``profiles.polyline._segment_end_normals`` gave each shading normal."""
    m = len(profile.segments)
    blend = np.zeros((m, 2, 4))
    neighbour = np.zeros((m, 2), dtype=np.uint32)
    for k in range(m):
        ends = ((0, profile.normal_start, (k - 1) % m), (1, profile.normal_end, (k + 1) % m))
        for side, normals, nb in ends:
            target = normals[k]
            shared = profile.segments[k, side] == profile.segments[nb, 1 - side] and m > 1
            average = seg_n[k] + seg_n[nb]
            if shared and np.linalg.norm(average) > 1e-12 and np.allclose(
                    average / np.linalg.norm(average), target, atol=1e-9):
                blend[k, side] = (1.0, 1.0, 0.0, 0.0)
                neighbour[k, side] = nb
            elif profile.points[profile.segments[k, side], 0] == 0.0 and target[0] == 0.0:
                # A chain end on the axis with the axial normal (a smooth
                # cap): fixed while the cap stays within the crease angle
                blend[k, side] = (0.0, 0.0, target[0], target[1])
            else:  # a crease (or a cone's tip): the segment's own normal
                blend[k, side] = (1.0, 0.0, 0.0, 0.0)
    return blend, neighbour


def _bspline_controls(given: ProfileInput, profile) -> np.ndarray:
    """(n_seg, 4) user indices of every segment's control points, built as
    ``profiles.bspline`` builds the segments (closed: wrapped; open: ends
    tripled), after its orientation."""
    n = len(given.points)
    index = np.arange(n)
    if not np.array_equal(profile.points, given.points):
        index = index[::-1]  # the profile was reversed to run clockwise
    if profile.closed_loop:
        # The loop drops the profile's last point, the repeat of its first.
        # Reversed, the first is the user's closing copy (n - 1): the
        # surface reads (and the gradient goes to) the user's first point.
        q = np.where(index[:-1] == n - 1, 0, index[:-1])
        seg = q[(np.arange(len(q))[:, None] + np.arange(4)[None, :]) % len(q)]
    else:
        q = np.concatenate([index[:1], index[:1], index, index[-1:], index[-1:]])
        seg = q[np.arange(len(q) - 3)[:, None] + np.arange(4)[None, :]]
    return seg


def _cubic_controls(given: ProfileInput, profile) -> tuple[np.ndarray, np.ndarray]:
    """``(indices, weights)``, both (n_seg, 4, w): the user points and
    weights whose sums are the canonical segments' B-spline controls of a
    ``bezier``, ``catmull_rom`` or ``quadratic`` profile (eq. 18), after
    its orientation (a reversed curve reverses the segments and each
    segment's controls)."""
    windows, weights = control_weights(given.kind, len(given.points))
    weights = np.where(np.abs(weights) < 1e-12, 0.0, weights)  # (the basis change's rounding)
    indices = np.broadcast_to(windows[:, None, :], (len(windows), 4, windows.shape[1]))
    weights = np.broadcast_to(weights[None], indices.shape)
    controls = np.einsum("ikj,ikjc->ikc", weights, given.points[indices])
    scale = max(float(np.abs(given.points).max()), 1.0)
    if not np.allclose(controls, profile.segment_controls, rtol=0.0, atol=1e-9 * scale):
        indices, weights = indices[::-1, ::-1], weights[::-1, ::-1]  # reversed to run clockwise
        controls = controls[::-1, ::-1]
    if not np.allclose(controls, profile.segment_controls, rtol=0.0, atol=1e-9 * scale):
        raise AssertionError("B-spline controls of the profile not found from its points")
    return indices, weights


def _held_on_axis(given: ProfileInput) -> np.ndarray:
    """Per user point, whether its r is held on the axis: a solid's first
    and last point when they lie there (a polyline's ends, an open
    B-spline's or a Bezier curve's, which the curve passes through). The
    ends of an open sheet are free, and so are the control points of
    ``catmull_rom`` and ``quadratic`` curves, whose ends are weighted sums
    of several points (keep those on the axis in the optimiser)."""
    points = np.asarray(given.points)
    held = np.zeros(len(points), dtype=bool)
    loop = len(points) > 1 and bool(np.all(points[0] == points[-1]))  # (a closed loop's points are free)
    if not given.open_sheet and not loop and given.kind in ("polyline", "bspline", "bezier"):
        for k in (0, len(points) - 1):
            held[k] = points[k, 0] == 0.0
    return held


def profile_index(surface: PolylineSurface | BSplineSurface) -> ProfileIndex:
    """The :class:`ProfileIndex` of a surface built with :func:`remember_input`."""
    given = surface.given
    profile = surface.profile
    held = mi.Bool(_held_on_axis(given))
    dr.make_opaque(held)
    if given.kind in CUBIC_KINDS:
        indices, weights = _cubic_controls(given, profile)
        index = ProfileIndex(controls=mi.UInt32(indices.ravel().astype(np.uint32)),
                             weights=mi.Float(weights.ravel().astype(np.float32)), width=indices.shape[2],
                             held=held)
        dr.make_opaque(index.controls, index.weights)
        return index
    if kind_of(surface).kernel == "bspline":
        seg = _bspline_controls(given, profile)
        controls = mi.UInt32(seg.ravel().astype(np.uint32))
        dr.make_opaque(controls)
        return ProfileIndex(controls=controls, held=held)
    user = _user_index(given.points, profile.points)
    ends = user[profile.segments]
    blend, neighbour = _end_blend(profile, profile.segment_normals())
    index = ProfileIndex(ends=mi.UInt32(ends.ravel().astype(np.uint32)),
                         blend=mi.Float(blend.ravel().astype(np.float32)),
                         neighbour=mi.UInt32(neighbour.ravel()), held=held)
    dr.make_opaque(index.ends, index.blend, index.neighbour)
    return index
