"""What registering a plugin for the active Mitsuba variant needs: only JIT
variants run the plugins, and LLVM variants need a libLLVM that Dr.Jit can
use. A leaf: it imports nothing of the package (each plugin module calls
:func:`register_jit_plugin`; :func:`lathe_shape.plugin.register` registers
them all)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterator

import drjit as dr
import mitsuba as mi

__all__ = ["MIN_LLVM_VERSION", "check_llvm", "cuda_callable_safe_kernels", "register_jit_plugin"]


def register_jit_plugin(
    register: Callable[[str, Callable], None],
    name: str,
    factory: Callable[[mi.Properties], object],
    describe: Callable[[mi.Properties], str],
    polarized: bool = True,
) -> None:
    """``register(name, factory)`` on a JIT variant (and, unless
    ``polarized`` is false, also on a polarized one); on any other variant
    register a constructor that fails with a message naming the plugin
    (``describe(props)``) and the variants that work."""
    jit = dr.is_jit_v(mi.Float)
    defined_for = _defined_for(factory)
    if jit and defined_for is None and (polarized or not mi.is_polarized):
        register(name, factory)
        return
    if jit and defined_for is not None:
        why = (f"lathe_shape was imported under the variant '{defined_for}', and its plugin "
               "classes derive from that variant's Mitsuba classes; select the variant before "
               "importing lathe_shape (switching between JIT variants in one process is not supported)")
    elif jit:
        why = ("this integrator does not carry polarization (Mueller matrices); use an "
               "unpolarized variant such as 'llvm_ad_rgb' or 'llvm_ad_spectral', or the "
               "'lathe_prb' integrator")
    else:
        why = "lathe_shape needs a JIT variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'"

    def unsupported(props: mi.Properties) -> object:
        raise RuntimeError(f"{describe(props)}: Mitsuba variant '{mi.variant()}' is not supported: {why}")

    register(name, unsupported)


def _defined_for(factory: Callable) -> str | None:
    """None if ``factory`` (a plugin class, or any callable) suits the
    active variant; else the variant its Mitsuba base class belongs to
    (Python classes are bound to the variant active when their module was
    imported)."""
    for base in getattr(factory, "__mro__", ())[1:]:
        if base.__module__ == "mitsuba" and hasattr(mi, base.__name__):
            if getattr(mi, base.__name__) is base:
                return None
            return _variant_of(base) or "another variant"
    return None


def _variant_of(cls: type) -> str | None:
    """The Mitsuba variant whose module defines the class ``cls``."""
    for variant in mi.variants():
        module = sys.modules.get(f"mitsuba.{variant}")
        if module is not None and getattr(module, cls.__name__, None) is cls:
            return variant
    return None


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


@contextlib.contextmanager
def cuda_callable_safe_kernels() -> Iterator[None]:
    """Within: on a CUDA variant, Dr.Jit assembles its kernels without
    ``JitFlag.SpillToSharedMemory``. Dr.Jit 1.5 marks every plain CUDA
    kernel (any kernel that traces no ray through OptiX) with the PTX
    pragma ``enable_smem_spilling``, and the PTX assembler of CUDA 13
    drivers (580, sm_90) refuses it in a kernel that calls functions
    through the ABI ("Smem spilling should not be enabled when functions use
    abi"): Dr.Jit aborts the process. The reverse and forward AD passes of a
    scene with several emitters or BSDFs are such kernels (their method
    calls are function calls), so the differential passes run inside this.
    On LLVM variants it does nothing."""
    if dr.backend_v(mi.Float) != dr.JitBackend.CUDA:
        yield
        return
    with dr.scoped_set_flag(dr.JitFlag.SpillToSharedMemory, False):
        yield
