"""Selecting the Mitsuba variant a command asked for (``--variant``), with
a clear error where it or its Dr.Jit backend is missing."""

from __future__ import annotations

__all__ = ["select_variant"]


#: What the variants of each Dr.Jit backend need: prefix -> (backend name, what).
_BACKEND_NEEDS = {"cuda_": ("CUDA", "a CUDA GPU"), "llvm_": ("LLVM", "the LLVM library (libLLVM)")}


def _check_backend(variant: str) -> None:
    """Raise :class:`SceneError` when ``variant``'s Dr.Jit backend (CUDA,
    LLVM) cannot run here, instead of Dr.Jit's error at the first kernel
    (``jit_init_thread_state(): the CUDA backend hasn't been initialized``);
    a CUDA variant's message proposes the LLVM one."""
    import drjit as dr
    import mitsuba as mi

    from ..tools.scenes import SceneError

    for prefix, (backend, what) in _BACKEND_NEEDS.items():
        if variant.startswith(prefix) and not dr.has_backend(getattr(dr.JitBackend, backend)):
            cpu = "llvm_" + variant[len(prefix):]
            instead = f" (use {cpu})" if prefix == "cuda_" and cpu in mi.variants() else ""
            raise SceneError(f"variant '{variant}' needs {what}, and none was found{instead}")


def select_variant(variant: str) -> None:
    """Select the Mitsuba ``variant`` and register the package's plugins for
    it; raises :class:`SceneError` naming the available variants, or saying
    that the variant's backend (a CUDA GPU, LLVM) is missing."""
    import mitsuba as mi

    from ..tools.scenes import SceneError

    if variant not in mi.variants():
        raise SceneError(f"unknown variant '{variant}' (available: {', '.join(mi.variants())})")
    _check_backend(variant)
    try:
        mi.set_variant(variant)
        import lathe_shape

        lathe_shape.register()
    except (RuntimeError, ImportError) as e:
        raise SceneError(str(e)) from None
