"""Polyline profiles of solids of revolution (numpy only).

A profile is a closed 2D curve in the (r, z) half plane of the shape's local
frame: ``r >= 0`` is the distance from the axis (local +z), ``z`` the position
along it. Revolving it about the axis gives the solid.

Conventions (see docs/method.md, "The object"):

* **Closed.** A profile is closed when its last point equals its first, or
  when both its first and its last point lie on the axis (``r = 0``); the
  axis then closes it (that closing segment sweeps no surface).
* **Orientation.** Either orientation is accepted on input. Internally the
  points are stored *clockwise* in the (r right, z up) plane, so that walking
  from ``q_i`` to ``q_(i+1)`` the solid's interior lies on the right and the
  outward normal of a segment is its left-hand normal ``(-dz, dr)``.
* **Canonical chain.** The stored points form a chain ``q_0 .. q_(n-1)``.
  When ``closed_loop`` is true the chain wraps around (segment ``q_(n-1) ->
  q_0`` exists); otherwise both chain ends lie on the axis. A loop that runs
  along the axis for one segment is rotated into the second form.
* **Normals.** Each segment carries a shading normal at each of its ends.
  At a vertex the two adjacent segment normals are averaged (the paper's
  fig. 3) unless the corner turns by more than ``crease_angle`` degrees or the
  vertex is flagged sharp; then each segment keeps its own normal there.

The raw points come from :mod:`lathe_shape.profiles.sources` (inline
string, CSV file or arc spec); :func:`parse_profile_string` and
:func:`read_profile_csv` are re-exported here for existing callers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .crossings import first_crossing, touch_tolerance
from .errors import ProfileError
from .limits import MAX_COORDINATE, MIN_PROFILE_SIZE, check_point_count
from .sources import parse_profile_string, read_profile_csv
from .text import PointLabels

__all__ = [
    "ProfileError",
    "Profile",
    "parse_profile_string",
    "read_profile_csv",
    "make_profile",
]


@dataclass(frozen=True)
class Profile:
    """A validated, clockwise polyline profile with crease-aware normals."""

    #: (n, 2) float64 chain points (r, z), clockwise.
    points: np.ndarray
    #: (n,) bool, vertex flagged sharp (crease) by the user.
    sharp: np.ndarray
    #: True: the chain wraps around; False: both ends lie on the axis.
    closed_loop: bool
    #: Human-readable origin, used in error messages.
    source: str
    #: Crease angle in degrees used for the normals.
    crease_angle: float
    #: (m, 2) segment start vertex index and end vertex index into ``points``.
    segments: np.ndarray
    #: (m, 2) unit shading normal (nr, nz) at each segment's start.
    normal_start: np.ndarray
    #: (m, 2) unit shading normal (nr, nz) at each segment's end.
    normal_end: np.ndarray
    #: True for a single open sheet (no inside; ends anywhere), False for
    #: the profile of a solid.
    open_sheet: bool = False

    @property
    def segment_count(self) -> int:
        return len(self.segments)

    def segment_points(self) -> tuple[np.ndarray, np.ndarray]:
        """Start and end points, each (m, 2), of the surface segments."""
        return self.points[self.segments[:, 0]], self.points[self.segments[:, 1]]

    def segment_normals(self) -> np.ndarray:
        """(m, 2) geometric outward unit normals: left-hand normal (-dz, dr)."""
        p0, p1 = self.segment_points()
        return _left_normals(p1 - p0)

    def bounds(self) -> tuple[float, float, float]:
        """(r_max, z_min, z_max) of the profile."""
        return (
            float(self.points[:, 0].max()),
            float(self.points[:, 1].min()),
            float(self.points[:, 1].max()),
        )


# ---------------------------------------------------------------------------
# Validation and canonical form
# ---------------------------------------------------------------------------


def make_profile(
    points: np.ndarray,
    sharp: np.ndarray | None = None,
    labels: Sequence[str] | None = None,
    source: str = "profile",
    crease_angle: float = 30.0,
    open_sheet: bool = False,
) -> Profile:
    """Validate raw points and build the canonical clockwise :class:`Profile`
    (with ``open_sheet``: a single open sheet, see :func:`_open_profile`).

    Raises :class:`ProfileError` naming ``source`` (and the offending point's
    label) for: too many points (:mod:`.limits`), fewer than 3 points,
    non-finite or too large coordinates, a negative radius, consecutive
    duplicate points, an open profile, a self-intersecting profile, and a
    profile enclosing no area. Every tolerance is relative to the profile's
    own size (:func:`.crossings.touch_tolerance`), so a scaled copy of a
    profile is accepted or refused alike.
    """
    try:
        raw = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ProfileError(f"{source}: profile points must be (r, z) pairs of numbers ({e})") from None
    # (N, 2) rows, or the flat r0, z0, r1, z1, ... of the differentiable 'points'
    if not ((raw.ndim == 2 and raw.shape[1] == 2) or (raw.ndim == 1 and raw.size % 2 == 0)):
        raise ProfileError(f"{source}: profile points must be (r, z) pairs: an (N, 2) array or a flat "
                           f"r0, z0, r1, z1, ... list, got an array of shape {raw.shape}")
    pts = raw.reshape(-1, 2)
    check_point_count(len(pts), source)
    flags = np.zeros(len(pts), dtype=bool)
    if sharp is not None:
        given = np.asarray(sharp)
        if given.shape != (len(pts),):
            raise ProfileError(f"{source}: 'sharp' must hold one flag per point ({len(pts)}), "
                               f"got shape {given.shape}")
        flags = given.astype(bool)
    if labels is None:
        labels = PointLabels.counting(source, len(pts))
    elif len(labels) != len(pts):
        raise ProfileError(f"{source}: 'labels' must name every point ({len(pts)}), got {len(labels)}")
    if not isinstance(crease_angle, (int, float, np.floating, np.integer)) or isinstance(crease_angle, bool):
        raise ProfileError(f"{source}: crease_angle must be a number of degrees, got {crease_angle!r}")
    if not math.isfinite(crease_angle) or not 0.0 <= crease_angle <= 180.0:
        raise ProfileError(
            f"{source}: crease_angle must be within [0, 180] degrees, got {crease_angle}"
        )
    _check_coordinates(pts, labels)
    size = float(np.abs(pts).max()) if pts.size else 0.0
    if 0.0 < size < MIN_PROFILE_SIZE:
        raise ProfileError(f"{source}: the profile is too small to check: its largest coordinate is "
                           f"{size:g}, below {MIN_PROFILE_SIZE:g} (give it in larger units, and scale it "
                           "down in to_world)")
    if open_sheet:
        return _open_profile(pts, flags, labels, source, crease_angle)
    pts, flags, closed_loop = _closed_chain(pts, flags, source)
    _check_segment_lengths(pts, labels, closed_loop)

    # The polygon, closed along the axis when the chain is open. A polygon
    # that is not a line but encloses no area crosses itself (a bow-tie):
    # the crossing test comes before the area test to say so.
    tol = touch_tolerance(pts)
    _check_short_segments(pts, labels, closed_loop, tol)
    if _collinear(pts, tol):
        raise ProfileError(f"{source}: profile encloses no area (all points collinear?)")
    _check_simple(pts, labels, source, tol, closed_loop)
    area = _signed_area(pts)
    if abs(area) <= tol * _extent(pts):
        raise ProfileError(f"{source}: profile encloses no area (all points collinear?)")
    pts, flags, closed_loop = _canonical_chain(pts, flags, closed_loop, area)

    segments = _surface_segments(pts, closed_loop)
    n_start, n_end = _segment_end_normals(pts, flags, closed_loop, segments, crease_angle)
    pts.setflags(write=False)
    return Profile(
        points=pts,
        sharp=flags,
        closed_loop=closed_loop,
        source=source,
        crease_angle=float(crease_angle),
        segments=segments,
        normal_start=n_start,
        normal_end=n_end,
    )


def _open_profile(pts: np.ndarray, flags: np.ndarray, labels: Sequence[str], source: str,
                  crease_angle: float) -> Profile:
    """An open sheet: the chain as written (no closure, orientation or area
    test; its ends may lie anywhere with ``r >= 0``), at least 2 points, no
    zero-length segment and no self-intersection. The outward side of the
    sheet is the left of the chain, as for a solid's clockwise profile; the
    chain is reversed, if need be, so that it faces away from the axis."""
    if len(pts) < 2:
        raise ProfileError(f"{source}: an open profile needs at least 2 points, got {len(pts)}")
    if len(pts) > 2 and np.all(pts[0] == pts[-1]):
        # (else: "intersects itself" at the closing point, naming its two segments)
        raise ProfileError(f"{labels[len(pts) - 1]}: the profile is closed (its last point repeats the "
                           f"first, ({_fmt(pts[0])})), but it is read as an open sheet ('open' true): "
                           f"drop the repeated point for a sheet, or set 'open' false for a solid")
    _check_segment_lengths(pts, labels, False)
    tol = touch_tolerance(pts)
    _check_short_segments(pts, labels, False, tol)
    e_in, e_out = pts[1:-1] - pts[:-2], pts[2:] - pts[1:-1]
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    longer = np.maximum(np.hypot(e_in[:, 0], e_in[:, 1]), np.hypot(e_out[:, 0], e_out[:, 1]))
    folds = (np.abs(cross) <= tol * longer) & (np.einsum("ij,ij->i", e_in, e_out) < 0.0)
    if folds.any():
        k = int(np.argmax(folds)) + 1
        raise ProfileError(f"{labels[k]}: profile intersects itself: it folds back at ({_fmt(pts[k])})")
    pair = first_crossing(pts, closed=False, tol=tol)
    if pair is not None:
        i, j = pair
        raise ProfileError(f"{source}: profile intersects itself: segment ({_fmt(pts[i])}) -> "
                           f"({_fmt(pts[i + 1])}) meets segment ({_fmt(pts[j])}) -> ({_fmt(pts[j + 1])})")
    # Outward = away from the axis: the chain runs downwards on the whole
    # (sum of r dz < 0), like a solid's outer wall; a flat sheet keeps its way.
    r_dz = float(np.sum((pts[1:, 0] + pts[:-1, 0]) * np.diff(pts[:, 1])))
    if r_dz > tol * _extent(pts):
        pts, flags = pts[::-1], flags[::-1]
    pts, flags = np.ascontiguousarray(pts), np.ascontiguousarray(flags)
    segments = _surface_segments(pts, False)
    if len(segments) == 0:
        raise ProfileError(f"{source}: open profile lies on the axis: it sweeps no surface")
    n_start, n_end = _segment_end_normals(pts, flags, False, segments, crease_angle)
    pts.setflags(write=False)
    return Profile(points=pts, sharp=flags, closed_loop=False, source=source,
                   crease_angle=float(crease_angle), segments=segments, normal_start=n_start,
                   normal_end=n_end, open_sheet=True)


def _check_coordinates(pts: np.ndarray, labels: Sequence[str]) -> None:
    """Every point finite, within :data:`.limits.MAX_COORDINATE`, with a
    radius >= 0."""
    check_finite_points(pts, labels)
    negative = pts[:, 0] < 0.0
    if negative.any():
        k = int(np.argmax(negative))
        raise ProfileError(f"{labels[k]}: negative radius r = {pts[k, 0]:g} (r must be >= 0)")


def check_finite_points(pts: np.ndarray, labels: Sequence[str]) -> None:
    """Every point finite and within :data:`.limits.MAX_COORDINATE`;
    errors name the point by its label (file and line). The curve kinds'
    control points are checked by this too, before their own validation
    (which counts control points)."""
    pts = np.asarray(pts, dtype=np.float64)
    bad = ~np.isfinite(pts).all(axis=1)
    if bad.any():
        k = int(np.argmax(bad))
        raise ProfileError(f"{labels[k]}: non-finite coordinate ({_fmt(pts[k])})")
    huge = (np.abs(pts) >= MAX_COORDINATE).any(axis=1)
    if huge.any():
        k = int(np.argmax(huge))
        raise ProfileError(f"{labels[k]}: coordinate too large ({_fmt(pts[k])}): |r| and |z| "
                           f"must be below {MAX_COORDINATE:g} (their squares must fit in float32)")


def _closed_chain(pts: np.ndarray, flags: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray, bool]:
    """Drop the repeated closing point of the 'last == first' form (its sharp
    flag moves to the first point) and check that the chain is closed: a
    loop, or both ends on the axis. Returns (points, flags, closed_loop)."""
    closed_loop = len(pts) >= 2 and bool(np.all(pts[0] == pts[-1]))
    if closed_loop:
        last_sharp = bool(flags[-1])
        pts, flags = pts[:-1], flags[:-1]
        flags[0] |= last_sharp
    if len(pts) < 3:
        raise ProfileError(
            f"{source}: a profile needs at least 3 distinct points, got {len(pts)}"
        )
    if not closed_loop and not (pts[0, 0] == 0.0 and pts[-1, 0] == 0.0):
        raise ProfileError(
            f"{source}: profile is not closed: its ends ({_fmt(pts[0])}) and ({_fmt(pts[-1])}) "
            f"must be the same point, or both must lie on the axis (r = 0)"
        )
    return pts, flags, closed_loop


def _check_segment_lengths(pts: np.ndarray, labels: Sequence[str], closed_loop: bool) -> None:
    """No two consecutive points equal (zero-length segment)."""
    n = len(pts)
    nxt = np.arange(1, n + 1) % n if closed_loop else np.arange(1, n)
    repeats = (pts[nxt] == pts[: len(nxt)]).all(axis=1)  # (exact: a norm underflows at 1e-300)
    if repeats.any():
        k = int(np.argmax(repeats))
        k2 = (k + 1) % n
        raise ProfileError(
            f"{labels[k2]}: repeats the previous point ({_fmt(pts[k])}): zero-length segment"
        )


def _check_short_segments(pts: np.ndarray, labels: Sequence[str], closed_loop: bool, tol: float) -> None:
    """No segment as short as the touch tolerance ``tol``: its two
    neighbours would come within ``tol`` of each other, which the crossing
    test reports as the profile intersecting itself, between segments whose
    printed end points look alike. The short segment is named instead, with
    its end points in full precision (issue 24, item 14)."""
    n = len(pts)
    nxt = np.arange(1, n + 1) % n if closed_loop else np.arange(1, n)
    step = pts[nxt] - pts[: len(nxt)]
    seg_len = np.hypot(step[:, 0], step[:, 1])  # (no underflow of the squares at 1e-300)
    short = seg_len <= tol
    if short.any():
        k = int(np.argmax(short))
        k2 = int(nxt[k])
        a, b = pts[k], pts[k2]
        raise ProfileError(
            f"{labels[k2]}: segment ({_fmt_exact(a)}) -> ({_fmt_exact(b)}) is too short: "
            f"{seg_len[k]:.3g} long, not more than the profile's touch tolerance {tol:.3g} "
            f"(1e-12 of its size); remove the point or move it further from the previous one"
        )


def _canonical_chain(
    pts: np.ndarray, flags: np.ndarray, closed_loop: bool, area: float
) -> tuple[np.ndarray, np.ndarray, bool]:
    """The chain clockwise, and a loop with one segment on the axis rotated
    into an axis-ended chain. Returns (points, flags, closed_loop)."""
    # Clockwise in the (r right, z up) plane has negative shoelace area.
    if area > 0.0:
        pts, flags = pts[::-1], flags[::-1]
        if closed_loop:
            # Keep the first point first after reversal.
            pts, flags = np.roll(pts, 1, axis=0), np.roll(flags, 1)
    # A loop with one segment on the axis is an axis-ended chain: rotate it so
    # that the axis segment becomes the implicit closing one.
    if closed_loop:
        on_axis = (pts[:, 0] == 0.0) & (np.roll(pts[:, 0], -1) == 0.0)
        if on_axis.any():
            k = int(np.argmax(on_axis))
            pts, flags = np.roll(pts, -(k + 1), axis=0), np.roll(flags, -(k + 1))
            closed_loop = False
    return np.ascontiguousarray(pts), np.ascontiguousarray(flags), closed_loop


def _fmt(p: np.ndarray) -> str:
    return f"{p[0]:g}, {p[1]:g}"


def _fmt_exact(p: np.ndarray) -> str:
    """A point in full precision (``_fmt`` rounds to 6 digits)."""
    return f"{float(p[0])!r}, {float(p[1])!r}"


def _signed_area(pts: np.ndarray) -> float:
    """Shoelace area of the closed polygon (positive = counter-clockwise)."""
    r, z = pts[:, 0], pts[:, 1]
    return 0.5 * float(np.sum(r * np.roll(z, -1) - np.roll(r, -1) * z))


def _extent(pts: np.ndarray) -> float:
    """The larger side of the bounding box."""
    return float(np.max(pts.max(axis=0) - pts.min(axis=0)))


def _collinear(pts: np.ndarray, tol: float) -> bool:
    """Whether every point lies within ``tol`` of one line."""
    offsets = pts - pts[0]
    far = offsets[int(np.argmax(np.hypot(offsets[:, 0], offsets[:, 1])))]
    length = float(np.hypot(*far))
    cross = far[0] * offsets[:, 1] - far[1] * offsets[:, 0]
    return length == 0.0 or bool(np.all(np.abs(cross) <= tol * length))


def _check_simple(pts: np.ndarray, labels: Sequence[str], source: str, tol: float,
                  closed_loop: bool = True) -> None:
    """Raise if the closed polygon folds back at a vertex (an edge runs back
    over the previous one), if a chain with both ends on the axis
    (``closed_loop`` False) touches the axis between them, or if two
    non-adjacent edges come within ``tol`` of each other
    (:func:`.crossings.first_crossing`). Errors name the points by their
    ``labels`` (file and line) and give them in full precision."""
    e_in = pts - np.roll(pts, 1, axis=0)  # edge into vertex k
    e_out = np.roll(pts, -1, axis=0) - pts  # edge out of vertex k
    cross = e_in[:, 0] * e_out[:, 1] - e_in[:, 1] * e_out[:, 0]
    longer = np.maximum(np.hypot(e_in[:, 0], e_in[:, 1]), np.hypot(e_out[:, 0], e_out[:, 1]))
    # The shorter edge's far end within tol of the longer one's line, going back.
    folds = (np.abs(cross) <= tol * longer) & (np.einsum("ij,ij->i", e_in, e_out) < 0.0)
    if folds.any():
        k = int(np.argmax(folds))
        raise ProfileError(
            f"{labels[k]}: profile intersects itself: it folds back at ({_fmt(pts[k])})"
        )
    if not closed_loop:
        on_axis = np.flatnonzero(pts[1:-1, 0] <= tol) + 1
        if len(on_axis):
            k = int(on_axis[0])
            raise ProfileError(
                f"{labels[k]}: the profile touches the axis at ({_fmt(pts[k])}) between its ends: a "
                f"profile meets the axis (r = 0) only at its first and last point; split it into two "
                f"lathes, or move the point off the axis")
    pair = first_crossing(pts, closed=True, tol=tol)
    if pair is None:
        return
    n = len(pts)

    def edge_name(e: int) -> str:
        a, b = pts[e], pts[(e + 1) % n]
        ends = f"({_fmt_exact(a)}) -> ({_fmt_exact(b)})"
        if e == n - 1:
            return f"the closing segment {ends}" + (" (along the axis)" if not closed_loop else "")
        return f"the segment {ends} from {_where(labels[e])} to {_where(labels[e + 1])}"

    raise ProfileError(
        f"{source}: profile intersects itself: {edge_name(pair[0])} meets {edge_name(pair[1])}"
    )


def _where(label: str) -> str:
    """``"line 5"`` of a label ``"file.csv, line 5"`` (the message names the
    file once)."""
    return label.rsplit(", ", 1)[-1]


def _surface_segments(pts: np.ndarray, closed_loop: bool) -> np.ndarray:
    n = len(pts)
    start = np.arange(n if closed_loop else n - 1)
    end = (start + 1) % n
    # Segments lying on the axis sweep no surface.
    keep = ~((pts[start, 0] == 0.0) & (pts[end, 0] == 0.0))
    return np.stack([start[keep], end[keep]], axis=1)


def _left_normals(delta: np.ndarray) -> np.ndarray:
    """Unit left-hand normals (-dz, dr) of 2D direction vectors (dr, dz)."""
    n = np.stack([-delta[:, 1], delta[:, 0]], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _segment_end_normals(
    pts: np.ndarray,
    sharp: np.ndarray,
    closed_loop: bool,
    segments: np.ndarray,
    crease_angle: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Shading normals at both ends of every segment (paper fig. 3).

    A vertex shared by two segments gets the normalised average of their
    normals unless it is flagged sharp or the normals differ by more than
    ``crease_angle``; then each segment keeps its own (a crease). A chain end
    on the axis gets the axial normal ``(0, +-1)`` when its segment is within
    ``crease_angle`` of perpendicular to the axis (a smooth cap), else the
    segment's own normal (a cone tip).
    """
    seg_n = _left_normals(pts[segments[:, 1]] - pts[segments[:, 0]])
    n_start = seg_n.copy()
    n_end = seg_n.copy()
    cos_crease = math.cos(math.radians(crease_angle))
    m = len(segments)
    # Segment k ends where segment k+1 starts (if that segment exists).
    index = np.arange(m)
    nxt = (index + 1) % m
    shares_vertex = (segments[:, 1] == segments[nxt, 0]) & (closed_loop | (index + 1 < m))
    a, b = seg_n, seg_n[nxt]
    avg = a + b
    length = np.hypot(avg[:, 0], avg[:, 1])
    smooth = (shares_vertex & ~sharp[segments[:, 1]]
              & (np.einsum("ij,ij->i", a, b) >= cos_crease - 1e-12) & (length > 1e-12))
    averaged = avg[smooth] / length[smooth, None]
    n_end[smooth] = averaged
    n_start[nxt[smooth]] = averaged
    # Ends of the surface that lie on the axis.
    for k, end, normals in ((0, 0, n_start), (m - 1, 1, n_end)):
        v = segments[k, end]
        if pts[v, 0] != 0.0 or sharp[v]:
            continue
        axial = np.array([0.0, math.copysign(1.0, seg_n[k, 1])])
        if seg_n[k, 1] != 0.0 and float(seg_n[k] @ axial) >= cos_crease - 1e-12:
            normals[k] = axial
    return n_start, n_end
