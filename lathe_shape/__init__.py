"""lathe_shape: exact rendering of transparent solids of revolution in Mitsuba 3.

Importing the package registers its Mitsuba plugins for the active variant
(and again on every later ``mi.set_variant``):

* ``<shape type="lathe">`` -- a solid of revolution; stock integrators render
  its reference tessellation, ``lathe_path`` renders it exactly;
* ``<integrator type="lathe_path">`` -- a path tracer that intersects every
  lathe exactly.

Call :func:`register` by hand only if plugins were cleared.
"""

from __future__ import annotations

import mitsuba as mi

from .plugin.variants import MIN_LLVM_VERSION, check_llvm, on_variant_change, register
from .profiles import Profile, ProfileError, make_profile

__all__ = [
    "MIN_LLVM_VERSION",
    "Profile",
    "ProfileError",
    "check_llvm",
    "make_profile",
    "register",
]

__version__ = "0.1.0"

mi.detail.add_variant_callback(on_variant_change)
register()
