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

import os

import drjit as dr
import mitsuba as mi

from .profiles.polyline import Profile, ProfileError, make_profile

__all__ = [
    "MIN_LLVM_VERSION",
    "Profile",
    "ProfileError",
    "check_llvm",
    "make_profile",
    "register",
]

__version__ = "0.1.0"

#: Lowest LLVM measured to work with Dr.Jit 1.5 here: libLLVM 14 is refused by
#: Dr.Jit, 15 and 16 abort at the first ``dr.minimum``/``dr.maximum``
#: ("Cannot select: fminimum/fmaximum"), 19 works; 17 and 18 are not packaged
#: for Debian 12 and were not measured (set LATHE_SHAPE_SKIP_LLVM_CHECK=1 to
#: try them).
MIN_LLVM_VERSION = (19, 0, 0)


def check_llvm(variant: str | None = None) -> None:
    """Raise a clear error if an LLVM variant would run on a broken libLLVM."""
    variant = variant or mi.variant()
    if not variant or not variant.startswith("llvm") or os.environ.get("LATHE_SHAPE_SKIP_LLVM_CHECK"):
        return
    version = tuple(dr.detail.llvm_version())
    if version == (0, 0, 0) or version < MIN_LLVM_VERSION:
        found = "no libLLVM" if version == (0, 0, 0) else "libLLVM " + ".".join(map(str, version))
        raise RuntimeError(
            f"lathe_shape: Mitsuba variant '{variant}' needs libLLVM >= "
            f"{MIN_LLVM_VERSION[0]}, but Dr.Jit found {found} (versions 15 and 16 crash "
            "with 'Cannot select fminimum'). Fix: 'apt-get install -y libllvm19' "
            "(Dr.Jit finds it by itself), or point DRJIT_LIBLLVM_PATH at libLLVM.so.19.1."
        )


def register(variant: str | None = None) -> None:
    """Register the ``lathe`` shape and ``lathe_path`` integrator for the
    active Mitsuba variant."""
    if variant is None:
        variant = mi.variant()
    if variant is None:
        return
    check_llvm(variant)
    from .plugin.lathe_path import register as register_integrator
    from .plugin.shape import register as register_shape

    register_shape()
    register_integrator()


def _on_variant_change(old: str | None, new: str | None) -> None:
    if new is not None:
        register(new)


mi.detail.add_variant_callback(_on_variant_change)
register()
