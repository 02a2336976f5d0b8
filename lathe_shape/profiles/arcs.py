"""Glass-wall profiles built from circular arcs and lines (numpy only).

This is the care the paper recommends for polyline profiles (docs/method.md,
"Known limits of polylines (section 2.3, Figs. 5-6)"):

* every circular arc is divided into **equal** parts (constant angle between
  successive segments = constant curvature of the polyline along the arc);
* the inner wall is made of arcs **concentric** with the outer ones, their
  radius changed by the wall thickness ``t``, and divided at the *same*
  angles, so that each inner vertex lies on the outer vertex's radius at
  distance exactly ``t`` (constant wall thickness; the distance from an inner
  vertex to the outer *polyline* is ``t cos(step / 2)``, to the outer *arc*
  exactly ``t``).

The profile is described like a turtle walk in the (r right, z up) half
plane, starting at a point (usually on the axis, at the bottom) and walking
with the solid on the **left** (counter-clockwise): out along the foot's
underside, round the foot, up the stem, then up the outer wall of the bowl.
Three parts:

``base``
    elements of the solid part (foot, stem): only one surface, no offset.
``wall``
    elements of the bowl's outer wall, which must be tangent-continuous. The
    builder adds the rim, then the inner wall (the offset elements walked
    backwards: concentric arcs with radius ``R - t`` for arcs turning left,
    ``R + t`` for arcs turning right; lines moved by ``t`` to the left).
``bottom``
    how the inner wall reaches the axis: ``"axis"`` (default: if the first
    wall element is an arc centred on the axis, its inner arc is continued,
    equally divided with the same step, down to the axis -- a round bowl
    bottom; otherwise like ``"flat"``), ``"flat"`` (a horizontal line to the
    axis), ``"none"`` (stop where the inner wall ends), or a list of further
    elements.

Elements (dicts; the same in Python, JSON and TOML):

``{"line": {"to": [r, z]}}`` or ``{"line": {"length": L}}``
    a straight line to a point, or of length ``L`` along the current heading;
    optional ``"segments": n`` (equal parts, default 1).
``{"arc": {"radius": R, "sweep": deg}}``
    a tangent-continuous arc: the centre lies at distance ``R`` on the left
    of the current heading for ``sweep > 0`` (turning left,
    counter-clockwise), on the right for ``sweep < 0``.
``{"arc": {"center": [r, z], "sweep": deg}}`` or ``{"arc": {"center": [r, z], "end_angle": deg}}``
    an arc about an explicit centre starting at the current point (radius =
    distance to the centre), sweeping ``sweep`` degrees (+ = counter-
    clockwise) or to the polar angle ``end_angle`` (about the centre, the
    shorter way).

Every arc is divided into ``"segments": n`` equal parts, or into
``ceil(|sweep| / max_step_deg)`` equal parts (the element's
``"max_step_deg"``, else the spec's, default 7.5 degrees). Any element may
carry ``"sharp": true`` (its end vertex is a crease). The heading starts as
``heading_deg`` (default 0: along +r) and follows the elements.

The spec (:func:`build_from_spec`, :func:`load_profile_spec`)::

    {
      "start": [0.0, 0.1],          # first point
      "heading_deg": 0.0,           # optional initial direction
      "max_step_deg": 7.5,          # optional default arc step
      "thickness": 0.18,            # wall thickness (needed with "wall")
      "base": [ ...elements... ],   # optional
      "wall": [ ...elements... ],   # optional
      "rim": {"type": "round", "segments": 4},   # or {"type": "flat"}
      "bottom": "axis"              # or "flat", "none", [ ...elements... ]
    }

The result is returned clockwise (the package's convention, docs/method.md "The
object") with the sharp flags, ready for :func:`lathe_shape.profiles.polyline.make_profile`.
"""

from __future__ import annotations

import copy
import json
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import ProfileError
from .limits import MAX_COORDINATE, MAX_PROFILE_POINTS, check_point_count
from .text import PointLabels, decode_utf8

__all__ = [
    "ArcPiece",
    "LinePiece",
    "ArcProfileBuilder",
    "build_from_spec",
    "load_profile_spec",
    "read_profile_spec",
    "spec_with_step",
    "DEFAULT_STEP_DEG",
]

#: Default maximum angle step of an equally divided arc (degrees).
DEFAULT_STEP_DEG = 7.5
#: Relative tolerance for "lies on the axis" and tangent continuity checks
#: (relative to the size of the coordinates: a scaled spec builds alike).
_TOL = 1e-9


def _size(points: np.ndarray) -> float:
    """The largest coordinate magnitude: the scale of the tolerances."""
    return float(np.abs(points).max())


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def _left(v: np.ndarray) -> np.ndarray:
    """Left-hand normal of a 2D direction (rotate by +90 degrees)."""
    return np.array([-v[1], v[0]])


@dataclass
class LinePiece:
    """A straight piece ``p0 -> p1`` divided into ``n`` equal segments."""

    p0: np.ndarray
    p1: np.ndarray
    n: int
    sharp_end: bool = False

    def points(self) -> np.ndarray:
        """The ``n`` division points after ``p0`` (``p1`` included)."""
        f = np.arange(1, self.n + 1)[:, None] / self.n
        return self.p0 + f * (self.p1 - self.p0)

    def end(self) -> np.ndarray:
        return self.p1

    def heading_end(self) -> np.ndarray:
        d = self.p1 - self.p0
        return d / np.linalg.norm(d)

    def offset_left(self, t: float) -> LinePiece:
        """The line moved by ``t`` to the left, walked backwards."""
        shift = t * _left(self.heading_end())
        return LinePiece(self.p1 + shift, self.p0 + shift, self.n)


@dataclass
class ArcPiece:
    """A circular arc about ``center`` from polar angle ``a0`` to ``a1``
    (radians, ``a1 > a0`` = counter-clockwise), ``n`` equal parts."""

    center: np.ndarray
    radius: float
    a0: float
    a1: float
    n: int
    sharp_end: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    def point(self, angle: float) -> np.ndarray:
        return self.center + self.radius * _unit(angle)

    def points(self) -> np.ndarray:
        """The ``n`` equally spaced points after the start (end included):
        angles ``a0 + k (a1 - a0) / n``, k = 1..n (paper section 2.3)."""
        k = np.arange(1, self.n + 1)
        angles = self.a0 + (self.a1 - self.a0) * k / self.n
        return self.center + self.radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)

    def end(self) -> np.ndarray:
        return self.point(self.a1)

    def heading_end(self) -> np.ndarray:
        # Tangent of a counter-clockwise arc at angle a is (-sin a, cos a).
        tangent = _left(_unit(self.a1))
        return tangent if self.a1 > self.a0 else -tangent

    def offset_left(self, t: float) -> ArcPiece:
        """The concentric arc ``t`` to the left, walked backwards, divided at
        the same angles. Left of a counter-clockwise walk is the centre side:
        radius ``R - t``; of a clockwise walk, ``R + t``."""
        radius = self.radius - t if self.a1 > self.a0 else self.radius + t
        return ArcPiece(self.center.copy(), radius, self.a1, self.a0, self.n)


Piece = LinePiece | ArcPiece


class ArcProfileBuilder:
    """Turtle-style builder of a profile from lines and equally divided arcs.

    ``source`` names the spec in error messages. Methods append pieces and
    return ``self``; :meth:`arrays` gives the points.
    """

    def __init__(self, start: tuple[float, float] | np.ndarray, heading_deg: float = 0.0,
                 max_step_deg: float = DEFAULT_STEP_DEG, source: str = "arc profile") -> None:
        self.source = source
        self.start = np.asarray(start, dtype=np.float64).reshape(2)
        self.heading = _unit(math.radians(heading_deg))
        self.max_step_deg = float(max_step_deg)
        self.pieces: list[Piece] = []
        self.point_count = 1  # points of the profile so far
        self.start_sharp = False
        if not self.max_step_deg > 0.0:
            raise ProfileError(f"{source}: max_step_deg must be > 0, got {max_step_deg}")

    @property
    def last(self) -> np.ndarray:
        """The current point (end of the last piece)."""
        return self.pieces[-1].end() if self.pieces else self.start

    def _count(self, sweep_rad: float, segments: int | None, step_deg: float | None, where: str) -> int:
        if segments is not None:
            if int(segments) != segments or segments < 1 or segments > MAX_PROFILE_POINTS:
                raise ProfileError(f"{where}: 'segments' must be a positive integer, at most "
                                   f"{MAX_PROFILE_POINTS:,}, got {segments!r}")
            return int(segments)
        step = self.max_step_deg if step_deg is None else float(step_deg)
        if not step > 0.0:
            raise ProfileError(f"{where}: 'max_step_deg' must be > 0, got {step_deg!r}")
        parts = abs(math.degrees(sweep_rad)) / step - 1e-9
        if parts > MAX_PROFILE_POINTS:
            raise ProfileError(f"{where}: 'max_step_deg' {step:g} divides the arc into more than "
                               f"{MAX_PROFILE_POINTS:,} parts (the most points of a profile)")
        return max(1, math.ceil(parts))

    def add(self, piece: Piece) -> ArcProfileBuilder:
        """Append a ready piece (its start must be the current point)."""
        self.point_count += piece.n
        check_point_count(self.point_count, self.source)
        self.pieces.append(piece)
        self.heading = piece.heading_end()
        return self

    def line(self, to: tuple[float, float] | None = None, length: float | None = None,
             segments: int = 1, sharp: bool = False, where: str = "line") -> ArcProfileBuilder:
        """Straight line to ``to`` or of ``length`` along the heading, divided
        into ``segments`` equal parts."""
        where = f"{self.source}: {where}"
        if (to is None) == (length is None):
            raise ProfileError(f"{where}: give exactly one of 'to' and 'length'")
        p0 = self.last.copy()
        if to is not None:
            p1 = np.asarray(to, dtype=np.float64).reshape(2)
        else:
            p1 = p0 + float(length) * self.heading
        if not np.all(np.isfinite(p1)) or np.linalg.norm(p1 - p0) <= _TOL * _size([p0, p1]):
            raise ProfileError(f"{where}: a line needs a finite end point different from its start "
                               f"({p0[0]:g}, {p0[1]:g})")
        n = self._count(0.0, segments, None, where)
        return self.add(LinePiece(p0, p1, n, bool(sharp)))

    def arc(self, sweep_deg: float | None = None, radius: float | None = None,
            center: tuple[float, float] | None = None, end_angle_deg: float | None = None,
            segments: int | None = None, max_step_deg: float | None = None,
            sharp: bool = False, where: str = "arc") -> ArcProfileBuilder:
        """Circular arc from the current point, equally divided.

        Tangent-continuous form: ``radius`` and ``sweep_deg`` (> 0 turns
        left: centre on the left of the heading). Explicit form: ``center``
        and ``sweep_deg`` (> 0 counter-clockwise) or ``end_angle_deg`` (polar
        angle of the end about the centre; the shorter way).
        """
        where = f"{self.source}: {where}"
        p0 = self.last.copy()
        if (radius is None) == (center is None):
            raise ProfileError(f"{where}: give exactly one of 'radius' (tangent arc) and 'center'")
        if center is None:
            if sweep_deg is None or end_angle_deg is not None:
                raise ProfileError(f"{where}: a tangent arc ('radius') needs 'sweep' (and no 'end_angle')")
            R = float(radius)
            if not (math.isfinite(R) and R > 0.0):
                raise ProfileError(f"{where}: 'radius' must be > 0, got {radius!r}")
            sweep = math.radians(float(sweep_deg))
            side = 1.0 if sweep > 0 else -1.0
            c = p0 + side * R * _left(self.heading)
        else:
            c = np.asarray(center, dtype=np.float64).reshape(2)
            R = float(np.linalg.norm(p0 - c))
            if not (math.isfinite(R) and R > _TOL * _size([p0, c])):
                raise ProfileError(f"{where}: 'center' ({c[0]:g}, {c[1]:g}) must differ from the "
                                   f"arc's start point ({p0[0]:g}, {p0[1]:g})")
            if (sweep_deg is None) == (end_angle_deg is None):
                raise ProfileError(f"{where}: an arc about a 'center' needs exactly one of 'sweep' "
                                   f"and 'end_angle'")
            if sweep_deg is not None:
                sweep = math.radians(float(sweep_deg))
            else:
                a_start = math.atan2(p0[1] - c[1], p0[0] - c[0])
                d = math.radians(float(end_angle_deg)) - a_start
                sweep = (d + math.pi) % (2 * math.pi) - math.pi
        if not math.isfinite(sweep) or abs(sweep) < 1e-12 or abs(sweep) > 2 * math.pi:
            raise ProfileError(f"{where}: the sweep must be non-zero and at most 360 degrees, "
                               f"got {math.degrees(sweep):g}")
        a0 = math.atan2(p0[1] - c[1], p0[0] - c[0])
        n = self._count(sweep, segments, max_step_deg, where)
        return self.add(ArcPiece(c, R, a0, a0 + sweep, n, bool(sharp)))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """All points (start + every piece's division points) and sharp flags,
        in walking order (counter-clockwise for a solid on the left)."""
        pts = [self.start[None, :]]
        sharp = [self.start_sharp]
        for piece in self.pieces:
            p = piece.points()
            pts.append(p)
            sharp += [False] * (len(p) - 1) + [piece.sharp_end]
        points = np.concatenate(pts)
        points[np.abs(points) < 1e-12 * _size(points)] = 0.0  # clean round-off on the axis / z = 0
        return points, np.array(sharp, dtype=bool)


# ---------------------------------------------------------------------------
# Spec -> profile
# ---------------------------------------------------------------------------

_TOP_KEYS = {"start", "heading_deg", "max_step_deg", "thickness", "base", "wall", "rim", "bottom",
             "description", "name"}
_LINE_KEYS = {"to", "length", "segments", "sharp"}
_ARC_KEYS = {"radius", "center", "sweep", "end_angle", "segments", "max_step_deg", "sharp"}


def _number(value: Any, where: str, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(value) < math.inf:
        raise ProfileError(f"{where}: expected a finite number, got {_short(value)}")
    if not abs(value) < MAX_COORDINATE:  # also an int too large for a float
        raise ProfileError(f"{where}: must be below {MAX_COORDINATE:g} in magnitude, got {_short(value)}")
    if positive and value <= 0:
        raise ProfileError(f"{where}: must be > 0, got {value!r}")
    return float(value)


def _short(value: Any) -> str:
    """``repr(value)``, cut short (a spec may hold a huge number or list)."""
    if isinstance(value, int) and abs(value) >= 10**30:
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _point(value: Any, where: str) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ProfileError(f"{where}: expected a point [r, z], got {value!r}")
    return _number(value[0], where), _number(value[1], where)


def _optional(d: dict, key: str, where: str, kind: str) -> Any:
    if key not in d:
        return None
    if kind == "number":
        return _number(d[key], f"{where}.{key}")
    if kind == "point":
        return _point(d[key], f"{where}.{key}")
    if kind == "int":
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ProfileError(f"{where}.{key}: expected a positive integer, got {v!r}")
        return v
    if kind == "bool":
        if not isinstance(d[key], bool):
            raise ProfileError(f"{where}.{key}: expected true or false, got {d[key]!r}")
        return d[key]
    raise AssertionError(kind)


def _add_element(b: ArcProfileBuilder, element: Any, where: str) -> None:
    """Append one spec element (see the module docstring) to the builder."""
    if not isinstance(element, dict) or len(element) != 1 or next(iter(element)) not in ("line", "arc"):
        raise ProfileError(f"{b.source}: {where}: an element must be {{\"line\": {{...}}}} or "
                           f"{{\"arc\": {{...}}}}, got {element!r}")
    kind, body = next(iter(element.items()))
    w = f"{where}.{kind}"
    if not isinstance(body, dict):
        raise ProfileError(f"{b.source}: {w}: expected a table of parameters, got {body!r}")
    allowed = _LINE_KEYS if kind == "line" else _ARC_KEYS
    unknown = sorted(set(body) - allowed)
    if unknown:
        raise ProfileError(f"{b.source}: {w}: unknown key '{unknown[0]}' "
                           f"(allowed: {', '.join(sorted(allowed))})")
    try:
        sharp = bool(_optional(body, "sharp", w, "bool"))
        segments = _optional(body, "segments", w, "int")
        if kind == "line":
            b.line(to=_optional(body, "to", w, "point"), length=_optional(body, "length", w, "number"),
                   segments=segments or 1, sharp=sharp, where=w)
        else:
            b.arc(sweep_deg=_optional(body, "sweep", w, "number"),
                  radius=_optional(body, "radius", w, "number"),
                  center=_optional(body, "center", w, "point"),
                  end_angle_deg=_optional(body, "end_angle", w, "number"),
                  segments=segments, max_step_deg=_optional(body, "max_step_deg", w, "number"),
                  sharp=sharp, where=w)
    except ProfileError as e:
        msg = str(e)
        if not msg.startswith(b.source):
            msg = f"{b.source}: {msg}"
        raise ProfileError(msg) from None


def _elements(spec: dict, key: str, source: str) -> list:
    value = spec.get(key, [])
    if not isinstance(value, list):
        raise ProfileError(f"{source}: '{key}' must be a list of elements, got {type(value).__name__}")
    return value


def build_from_spec(spec: dict, source: str = "arc profile spec") -> tuple[np.ndarray, np.ndarray]:
    """Build a closed glass profile from a spec dict (module docstring).

    Returns ``(points (n, 2), sharp (n,))``, clockwise in the (r right, z up)
    plane. Raises :class:`ProfileError` starting with ``source`` and naming
    the bad key.
    """
    if not isinstance(spec, dict):
        raise ProfileError(f"{source}: the spec must be a table/object, got {type(spec).__name__}")
    unknown = sorted(set(spec) - _TOP_KEYS)
    if unknown:
        raise ProfileError(f"{source}: unknown key '{unknown[0]}' (allowed: {', '.join(sorted(_TOP_KEYS))})")
    if "start" not in spec:
        raise ProfileError(f"{source}: missing key 'start' (the first point [r, z])")
    start = _point(spec["start"], f"{source}: start")
    heading = _number(spec["heading_deg"], f"{source}: heading_deg") if "heading_deg" in spec else 0.0
    step = spec.get("max_step_deg", DEFAULT_STEP_DEG)
    step = _number(step, f"{source}: max_step_deg", positive=True)
    b = ArcProfileBuilder(start, heading, step, source)

    for k, element in enumerate(_elements(spec, "base", source)):
        _add_element(b, element, f"base[{k}]")
    wall = _elements(spec, "wall", source)
    if wall:
        if "thickness" not in spec:
            raise ProfileError(f"{source}: missing key 'thickness' (needed by 'wall')")
        t = _number(spec["thickness"], f"{source}: thickness", positive=True)
        n_base = len(b.pieces)
        for k, element in enumerate(wall):
            _add_element(b, element, f"wall[{k}]")
        outer = b.pieces[n_base:]
        _check_tangent(b, outer, n_base)
        _add_rim(b, spec.get("rim", {"type": "round"}), t)
        # Inner wall: concentric offsets walked backwards (constant thickness).
        for k, piece in enumerate(reversed(outer)):
            inner = piece.offset_left(t)
            if isinstance(inner, ArcPiece) and inner.radius <= 0.0:
                raise ProfileError(f"{source}: wall[{len(outer) - 1 - k}]: arc radius "
                                   f"{piece.radius:g} is not larger than the thickness {t:g}")
            b.add(inner)
        _add_bottom(b, spec.get("bottom", "axis"), outer[0])
    elif "rim" in spec or "thickness" in spec:
        raise ProfileError(f"{source}: 'rim' and 'thickness' need a 'wall'")
    else:
        for k, element in enumerate(_elements(spec, "bottom", source)):
            _add_element(b, element, f"bottom[{k}]")

    points, sharp = b.arrays()
    scale = _size(points)
    if abs(points[-1, 0]) < 1e-9 * scale:
        points[-1, 0] = 0.0
    if np.linalg.norm(points[-1] - points[0]) < 1e-9 * scale:
        points[-1] = points[0]
    # Counter-clockwise (solid on the left) -> clockwise, the package's order.
    return points[::-1].copy(), sharp[::-1].copy()


def _check_tangent(b: ArcProfileBuilder, outer: list[Piece], n_base: int) -> None:
    """The offset construction needs a tangent-continuous outer wall."""
    for k in range(1, len(outer)):
        h_end = outer[k - 1].heading_end()
        nxt = outer[k]
        if isinstance(nxt, LinePiece):
            h0 = nxt.heading_end()
        else:
            h0 = _left(_unit(nxt.a0)) * (1.0 if nxt.a1 > nxt.a0 else -1.0)
        if float(h_end @ h0) < 1.0 - 1e-9:
            angle = math.degrees(math.acos(max(-1.0, min(1.0, float(h_end @ h0)))))
            raise ProfileError(f"{b.source}: wall[{k}]: the wall must be tangent-continuous for a "
                               f"constant-thickness inner wall; it turns by {angle:.3g} degrees here")


def _add_rim(b: ArcProfileBuilder, rim: Any, t: float) -> None:
    """Close the wall at the top: a half circle of diameter ``t`` (``round``,
    centre midway between the outer and inner wall ends, so it is concentric
    with neither but tangent to both) or a flat cut (``flat``, two sharp
    corners)."""
    where = f"{b.source}: rim"
    if isinstance(rim, str):
        rim = {"type": rim}
    if not isinstance(rim, dict):
        raise ProfileError(f"{where}: expected {{\"type\": \"round\"|\"flat\", ...}}, got {rim!r}")
    unknown = sorted(set(rim) - {"type", "segments", "max_step_deg"})
    if unknown:
        raise ProfileError(f"{where}: unknown key '{unknown[0]}' (allowed: max_step_deg, segments, type)")
    kind = rim.get("type", "round")
    if kind == "round":
        b.arc(sweep_deg=180.0, radius=0.5 * t, segments=_optional(rim, "segments", where, "int"),
              max_step_deg=_optional(rim, "max_step_deg", where, "number"), where="rim")
    elif kind == "flat":
        if "max_step_deg" in rim:
            raise ProfileError(f"{where}: a flat rim takes no 'max_step_deg'")
        b.pieces[-1].sharp_end = True
        b.line(to=b.last + t * _left(b.heading), segments=_optional(rim, "segments", where, "int") or 1,
               sharp=True, where="rim")
    else:
        raise ProfileError(f"{where}.type: expected 'round' or 'flat', got {kind!r}")


def _add_bottom(b: ArcProfileBuilder, bottom: Any, first_wall: Piece) -> None:
    """Take the inner wall to the axis (see the module docstring)."""
    where = f"{b.source}: bottom"
    p = b.last
    scale = _size(b.arrays()[0])
    if isinstance(bottom, list):
        for k, element in enumerate(bottom):
            _add_element(b, element, f"bottom[{k}]")
        return
    if bottom not in ("axis", "flat", "none"):
        raise ProfileError(f"{where}: expected 'axis', 'flat', 'none' or a list of elements, got {bottom!r}")
    if bottom == "none" or abs(p[0]) <= 1e-9 * scale:
        return
    inner = b.pieces[-1]
    if (bottom == "axis" and isinstance(inner, ArcPiece) and abs(inner.center[0]) <= 1e-9 * scale
            and isinstance(first_wall, ArcPiece)):
        # Continue the inner arc (same centre, same direction, same step) to
        # the polar angle where it meets the axis: -90 or +90 degrees.
        going = 1.0 if inner.a1 > inner.a0 else -1.0
        target = -0.5 * math.pi if going < 0 else 0.5 * math.pi
        # Angles are unwrapped; move the target into the walking direction.
        while going * (target - inner.a1) <= 0.0:
            target += going * 2 * math.pi
        while going * (target - inner.a1) > 2 * math.pi:
            target -= going * 2 * math.pi
        sweep = target - inner.a1
        if abs(sweep) < math.pi:
            step = abs(inner.a1 - inner.a0) / inner.n
            n = max(1, math.ceil(abs(sweep) / step - 1e-9))
            b.add(ArcPiece(inner.center.copy(), inner.radius, inner.a1, target, n))
            return
    b.line(to=(0.0, float(p[1])), where="bottom")


def spec_with_step(spec: dict, step_deg: float) -> dict:
    """The same lines and arcs with every arc divided at ``step_deg``: the
    elements' own ``segments`` and ``max_step_deg`` are dropped, a round rim
    is divided at ``4 step_deg`` (a near-exact reference for small steps, or
    a coarser polyline of the same object)."""
    out = copy.deepcopy(spec)
    out["max_step_deg"] = step_deg
    for key in ("base", "wall"):
        for element in out.get(key, []):
            for body in element.values():
                body.pop("segments", None)
                body.pop("max_step_deg", None)
    if isinstance(out.get("rim"), dict) and out["rim"].get("type") == "round":
        out["rim"] = {"type": "round", "max_step_deg": 4 * step_deg}
    return out


# ---------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------

def load_profile_spec(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read a JSON (``.json``) or TOML (``.toml``, Python >= 3.11) arc
    profile spec and build it.

    Returns ``(points, sharp, labels)`` like
    :func:`lathe_shape.profiles.sources.read_profile_csv`; labels name the file and the
    point, counted along the spec's walk from its start (``"glass.json, point 12"``;
    the points themselves come clockwise, the walk reversed). Raises
    :class:`~lathe_shape.profiles.errors.ProfileError` with a message starting with
    the file path and naming the bad key.
    """
    path = os.fspath(path)
    points, sharp = build_from_spec(read_profile_spec(path), source=path)
    # The points come clockwise, the spec's walk reversed: labels count
    # along the walk (its start is point 1), as its author counts them
    labels = PointLabels(path, np.arange(len(points), 0, -1))
    return points, sharp, labels


#: Largest spec file read (bytes): a spec is a few lines of lines and arcs.
MAX_SPEC_BYTES = 1 << 24


def read_profile_spec(path: str | os.PathLike) -> Any:
    """The spec in a JSON (``.json``) or TOML (``.toml``) file, unchecked
    (:func:`build_from_spec` checks it). UTF-8 text, a byte order mark
    accepted, at most :data:`MAX_SPEC_BYTES`."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_SPEC_BYTES + 1)
    except OSError as e:
        raise ProfileError(f"{path}: cannot read profile spec ({e.strerror})") from None
    if len(data) > MAX_SPEC_BYTES:
        raise ProfileError(f"{path}: a profile spec must be at most {MAX_SPEC_BYTES:,} bytes")
    text = decode_utf8(data, path)
    toml = path.lower().endswith(".toml")
    if toml:
        try:
            import tomllib
        except ImportError:  # Python < 3.11
            raise ProfileError(f"{path}: TOML profile specs need Python >= 3.11 (tomllib); "
                               f"use JSON instead") from None
    try:
        return tomllib.loads(text) if toml else json.loads(text)
    except (ValueError, RecursionError) as e:  # the decode errors are ValueErrors
        raise ProfileError(f"{path}: not a valid {'TOML' if toml else 'JSON'} file ({e})") from None
