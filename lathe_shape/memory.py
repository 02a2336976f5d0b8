"""How much memory the machine has left: the one estimate that the shape's
reference-mesh budget and the commands' render budget compare against; and
how many samples one render may take (:data:`MAX_SAMPLES`)."""

from __future__ import annotations

import os

__all__ = ["MAX_SAMPLES", "available_memory", "format_bytes"]

#: Samples (pixels x spp, or light particles) one render may take: Mitsuba
#: 3.9.1's LLVM variants silently render a black image a little below 2**32
#: samples and crash when Mitsuba splits a larger render into passes; this
#: many render correctly (the commands' budget, cli/budget.py, and the
#: caustics' particles, plugin/caustic_render.py).
MAX_SAMPLES = 2**32 - 2**24


def available_memory() -> int | None:
    """Bytes of memory available now without swapping (``MemAvailable`` of
    ``/proc/meminfo``; else the free physical pages), None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):
        return None


def format_bytes(count: float) -> str:
    """``3.2e9`` -> ``"3.2 GB"`` (decimal units)."""
    for unit in ("bytes", "kB", "MB", "GB", "TB"):
        if count < 1000 or unit == "TB":
            return f"{count:.0f} {unit}" if unit == "bytes" else f"{count:.1f} {unit}"
        count /= 1000
    raise AssertionError("unreachable")
