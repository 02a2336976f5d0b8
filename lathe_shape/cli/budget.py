"""The limits a render must fit before it starts (memory and samples;
the rules are in :mod:`.common`'s docstring): :func:`check_render_budget`."""

from __future__ import annotations

from ..memory import MAX_SAMPLES, available_memory, format_bytes
from .errors import CliError

__all__ = [
    "FILM_BYTES_PER_PIXEL",
    "MAX_SAMPLES",
    "MEMORY_FRACTION",
    "available_memory",
    "check_render_budget",
    "format_bytes",
]


#: Memory a render needs per film pixel, in bytes: the film's image block
#: (RGB, alpha, weight: 5 float32), the developed image (4 float32) and its
#: (H, W, 3) float32 NumPy copy, rounded up (measured: about 30 bytes).
FILM_BYTES_PER_PIXEL = 48


#: A render whose memory estimate exceeds this fraction of the available
#: memory is refused.
MEMORY_FRACTION = 0.8




def check_render_budget(width: int, height: int, spp: int, available: int | None = None) -> None:
    """Refuse a render of ``spp`` samples per pixel on a ``width`` x ``height``
    film that cannot run correctly: more memory than :data:`MEMORY_FRACTION`
    of ``available`` (default: :func:`available_memory`), or more than
    :data:`MAX_SAMPLES` samples (the rules are in this module's docstring).
    Raises :class:`CliError` with the numbers."""
    width, height, spp = int(width), int(height), int(spp)
    pixels = width * height
    needed = pixels * FILM_BYTES_PER_PIXEL
    available = available_memory() if available is None else available
    if available is not None and needed > MEMORY_FRACTION * available:
        raise CliError(
            f"a {width}x{height} film needs about {format_bytes(needed)} of memory, more than "
            f"{MEMORY_FRACTION:.0%} of the {format_bytes(available)} available: use a smaller --resolution")
    if pixels > MAX_SAMPLES:
        raise CliError(f"a {width}x{height} film has more pixels than the {MAX_SAMPLES} samples one render "
                       "can take: use a smaller --resolution")
    if pixels * spp > MAX_SAMPLES:
        raise CliError(
            f"{spp} spp on a {width}x{height} film is {pixels * spp} samples, more than the {MAX_SAMPLES} "
            f"one render can take: use at most --spp {MAX_SAMPLES // pixels} (or average renders with "
            "different --seed values)")
