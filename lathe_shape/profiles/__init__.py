"""Profiles of solids of revolution: polylines, cubic B-splines and arc specs
(numpy only, no Mitsuba).

* :mod:`.sources` -- the raw points of a profile (inline string, CSV file,
  arc spec) and the CSV writer;
* :mod:`.polyline` -- the validated polyline :class:`Profile` (Method 1);
* :mod:`.bspline` -- the validated :class:`BSplineProfile` (Method 2);
* :mod:`.spline_kinds` -- POV-Ray's Bezier, Catmull-Rom (``cubic_spline``)
  and quadratic curves as B-spline segments; :mod:`.sor` -- POV-Ray's
  ``sor``; :mod:`.pov` -- the reader of POV-Ray ``lathe``/``sor`` blocks;
* :mod:`.arcs` -- profiles from lines and equally divided arcs (section 2.3);
* :mod:`.crossings` -- the one segment-intersection test both profile kinds
  use (``n log n``);
* :mod:`.limits` -- the most points and the largest coordinates a profile
  may have;
* :mod:`.text` -- UTF-8 decoding of profile files and the point labels of
  error messages.

Every check's tolerance is relative to the profile's own size: a profile
scaled by any factor (within :data:`.limits.MAX_COORDINATE`) is accepted or
refused alike.
"""

from .arcs import build_from_spec, load_profile_spec, spec_with_step
from .bspline import BSplineError, BSplineProfile, make_bspline_profile
from .errors import ProfileError
from .limits import MAX_COORDINATE, MAX_PROFILE_POINTS
from .polyline import Profile, make_profile
from .sources import (
    format_profile_csv,
    parse_profile_string,
    read_points,
    read_profile_csv,
    read_profile_options,
    write_profile_csv,
)

__all__ = [
    "MAX_COORDINATE",
    "MAX_PROFILE_POINTS",
    "BSplineError",
    "BSplineProfile",
    "Profile",
    "ProfileError",
    "build_from_spec",
    "format_profile_csv",
    "load_profile_spec",
    "make_bspline_profile",
    "make_profile",
    "parse_profile_string",
    "read_points",
    "read_profile_csv",
    "read_profile_options",
    "spec_with_step",
    "write_profile_csv",
]
