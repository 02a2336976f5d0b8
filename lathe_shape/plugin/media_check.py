"""Refusing participating media that an exact integrator does not handle.

``lathe_path``, ``lathe_whitted`` and ``lathe_prb`` ignore media: a lathe
with an ``interior`` or ``exterior`` medium would render as if the medium
were absent. Each integrator calls :func:`refuse_media` where it first sees
the scene's lathes (its ``geometry()``), so such a scene is an error naming
the lathe, the medium and the integrator that renders media
(:data:`MEDIUM_INTEGRATOR`).
"""

from __future__ import annotations

from collections.abc import Iterable

import mitsuba as mi

__all__ = ["MEDIUM_INTEGRATOR", "lathe_media", "refuse_media"]

#: The integrator of the package that renders lathes with media.
MEDIUM_INTEGRATOR = "lathe_volpath"


def _name(obj: object, what: str) -> str:
    """``what 'id'`` or ``a what`` (no id: Mitsuba gives generated ids to
    unnamed objects, shown too)."""
    ident = obj.id() if hasattr(obj, "id") else ""
    return f"{what} '{ident}'" if ident else f"a {what} without id"


def lathe_media(lathes: Iterable[mi.Shape]) -> list[tuple[mi.Shape, str, mi.Medium]]:
    """``(lathe, 'interior' | 'exterior', medium)`` for every medium attached
    to one of ``lathes``."""
    found = []
    for lathe in lathes:
        for side in ("interior", "exterior"):
            medium = getattr(lathe, f"{side}_medium")()
            if medium is not None:
                found.append((lathe, side, medium))
    return found


def refuse_media(lathes: Iterable[mi.Shape], integrator: str) -> None:
    """Raise a ``RuntimeError`` if one of ``lathes`` has an interior or
    exterior medium, which ``integrator`` would silently ignore."""
    found = lathe_media(lathes)
    if not found:
        return
    lathe, side, medium = found[0]
    more = f" ({len(found) - 1} more lathe media in the scene)" if len(found) > 1 else ""
    raise RuntimeError(
        f"{_name(lathe, 'lathe')} has an {side} medium ({_name(medium, medium.class_name())}), "
        f"and the integrator {integrator} does not handle participating media: it would render "
        f"the lathe as if the medium were absent{more}. Use {MEDIUM_INTEGRATOR} for lathes with "
        "media (or remove the medium)."
    )
