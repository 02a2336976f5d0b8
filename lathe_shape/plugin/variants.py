"""Registering plugins only where they can run (JIT variants)."""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr
import mitsuba as mi

__all__ = ["register_jit_plugin"]


def register_jit_plugin(
    register: Callable[[str, Callable], None],
    name: str,
    factory: Callable[[mi.Properties], object],
    describe: Callable[[mi.Properties], str],
) -> None:
    """``register(name, factory)`` on a JIT variant; on any other variant
    register a constructor that fails with a message naming the plugin
    (``describe(props)``) and the variants that work."""
    if dr.is_jit_v(mi.Float):
        register(name, factory)
        return

    def unsupported(props: mi.Properties) -> object:
        raise RuntimeError(
            f"{describe(props)}: Mitsuba variant '{mi.variant()}' is not supported; "
            "lathe_shape needs a JIT variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'"
        )

    register(name, unsupported)
