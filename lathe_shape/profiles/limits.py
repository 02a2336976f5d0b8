"""The size limits of a profile, checked before anything large is built.

* :data:`MAX_PROFILE_POINTS` -- at most 10 million points (polyline points,
  or B-spline curve samples: :data:`BSPLINE_SAMPLES_PER_SEGMENT` per curve
  segment). The kernels carry a segment index in float32 (exact integers up
  to ``2^24``) and uint32 buffers, and the reference tessellation multiplies
  the point count by its angular steps; beyond this a profile is refused
  with an estimate of the memory it would take, rather than exhausting the
  machine.
* :data:`MAX_COORDINATE` -- every coordinate is below ``1e18`` in magnitude,
  so that squared coordinates (and sums of a few of them) stay finite in
  float32, the precision of the rendering kernels (float32 overflows at
  about ``3.4e38``), and comfortably finite in float64 for the validation.
"""

from __future__ import annotations

from .errors import ProfileError

__all__ = [
    "BSPLINE_SAMPLES_PER_SEGMENT",
    "BYTES_PER_POINT",
    "MAX_COORDINATE",
    "MAX_PROFILE_POINTS",
    "MIN_PROFILE_SIZE",
    "check_point_count",
]

#: Most points (polyline points or flattened B-spline samples) of a profile.
MAX_PROFILE_POINTS = 10_000_000

#: Largest coordinate magnitude: squares stay finite in float32.
MAX_COORDINATE = 1e18

#: Smallest size (largest coordinate magnitude) of a profile: products of
#: coordinates stay normal floats in float64.
MIN_PROFILE_SIZE = 1e-100

#: Samples per B-spline curve segment of the flattened curve that the
#: self-intersection and regularity checks examine.
BSPLINE_SAMPLES_PER_SEGMENT = 48

#: Estimated peak memory per point of reading and validating a profile
#: (bytes): the validation of a polyline peaks at about 300 bytes per point;
#: the rest is margin for the reader and the caller's copies.
BYTES_PER_POINT = 600


def check_point_count(points: int, source: str, what: str = "points", per_point: int = 1,
                      error: type[ProfileError] = ProfileError, at_least: bool = False) -> None:
    """Raise ``error`` (a :class:`ProfileError`) when ``points`` (each
    standing for ``per_point`` profile points, e.g. curve samples per
    B-spline control point) exceed :data:`MAX_PROFILE_POINTS`; the message
    names the count (``at_least``: a reader stopped counting there) and the
    memory it would take."""
    total = points * per_point
    if total <= MAX_PROFILE_POINTS:
        return
    count = f"{'at least ' if at_least else ''}{points:,} {what}"
    if per_point > 1:
        count += f" ({total:,} curve samples)"
    raise error(f"{source}: {count} is too many: validating them would take about "
                f"{total * BYTES_PER_POINT / 1e9:.1f} GB; at most "
                f"{MAX_PROFILE_POINTS // per_point:,} {what} are supported")
