"""The Mitsuba plugins: the ``lathe`` shape, the scene geometry that merges
exact lathe hits with Mitsuba's, the ``lathe_path`` integrator and their
registration for JIT variants (:func:`register`, run on import of
``lathe_shape`` and on every later ``mi.set_variant``)."""

from __future__ import annotations

import mitsuba as mi

from .variants import check_llvm

__all__ = ["on_variant_change", "register"]


def register(variant: str | None = None) -> None:
    """Register the ``lathe`` shape, the ``lathe_path``, ``lathe_whitted``,
    ``lathe_prb`` and ``lathe_volpath`` integrators and the
    ``dispersive_dielectric`` BSDF for the active Mitsuba variant (or
    ``variant``, once it is active)."""
    if variant is None:
        variant = mi.variant()
    if variant is None:
        return
    check_llvm(variant)
    from .dispersive_dielectric import register as register_dispersive
    from .lathe_path import register as register_path
    from .lathe_prb import register as register_prb
    from .lathe_volpath import register as register_volpath
    from .lathe_whitted import register as register_whitted
    from .shape import register as register_shape

    register_shape()
    register_path()
    register_whitted()
    register_prb()
    register_dispersive()
    register_volpath()


def on_variant_change(old: str | None, new: str | None) -> None:
    """Mitsuba variant callback: register the plugins for the new variant."""
    if new is not None:
        register(new)
