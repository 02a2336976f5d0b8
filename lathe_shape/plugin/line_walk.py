"""A path's rays as walks along lines: what an integrator carries from one
bounce to the next so that a ray passing straight through a lathe's
surface continues exactly where it crossed, without an offset.

Mitsuba's ``si.spawn_ray`` restarts a ray past a hit from a point moved
off the surface along its normal. That makes a new line, which at a corner
of the profile can miss a second crossing closer than the offset, or find
the one just taken again: a ray that entered then never leaves (an odd
number of crossings). A :class:`LineWalk` instead remembers the line that
the last lathe crossing was found on (its origin and direction, as the
kernel saw them) and the crossing's place on it. When the next ray goes on
in the same direction (a straight continuation: a parity walk, an
index-matched or thin dielectric, a null interface), its lathe queries run
on that same line and ask for the crossing after the one taken
(``next_crossing_polyline``): every crossing of the line is found once.
Rays that turn (reflection, refraction) start a new line.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.common import NO_CROSSING, VariantStruct
from ..kernels.top_level import NO_LATHE

__all__ = ["LineWalk", "SAME_DIRECTION", "continues_line", "start_walk"]

#: Largest squared difference of unit directions (about 1e-5 radians) for
#: which a ray continues the walked line: the rounding of a direction sent
#: through a shading frame and back, far below the spawn offset's angle.
SAME_DIRECTION = 1e-10


class LineWalk(metaclass=VariantStruct):
    """The line walked so far (``o``, ``d``: world space, as the lathe
    queries saw it) and the last crossing taken on it: ``lathe`` (the scene
    geometry's lathe index; ``NO_LATHE`` when the last hit was no lathe's
    walked crossing), its kernel place ``(s, key)`` and its ray parameter
    ``t`` along the line."""

    _FIELDS = {"o": "Point3f", "d": "Vector3f", "lathe": "UInt32", "s": "Float", "key": "UInt32",
               "t": "Float"}

    def __init__(self, o=None, d=None, lathe=None, s=None, key=None, t=None) -> None:
        self.o = mi.Point3f(0.0) if o is None else o
        self.d = mi.Vector3f(0.0) if d is None else d
        self.lathe = mi.UInt32(NO_LATHE) if lathe is None else lathe
        self.s = mi.Float(0.0) if s is None else s
        self.key = mi.UInt32(NO_CROSSING) if key is None else key
        self.t = mi.Float(0.0) if t is None else t


def start_walk(width: int) -> LineWalk:
    """``width`` walks that have crossed nothing yet (camera rays)."""
    return LineWalk(lathe=dr.full(mi.UInt32, NO_LATHE, width))


def continues_line(ray: mi.Ray3f, walk: LineWalk) -> mi.Bool:
    """Whether ``ray`` goes on along ``walk``'s line past its last lathe
    crossing: same direction within :data:`SAME_DIRECTION` (relative)."""
    diff = dr.squared_norm(ray.d - walk.d)
    return (walk.lathe != NO_LATHE) & (diff <= SAME_DIRECTION * dr.squared_norm(walk.d))
