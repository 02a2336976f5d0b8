"""Refusing participating media that an exact integrator does not handle.

``lathe_path``, ``lathe_whitted`` and ``lathe_prb`` ignore media: a lathe
with an ``interior`` or ``exterior`` medium would render as if the medium
were absent. Each integrator calls :func:`refuse_media` where it first sees
the scene's lathes (its ``geometry()``), so such a scene is an error naming
the lathe, the medium and the integrator that renders media
(:data:`MEDIUM_INTEGRATOR`). :func:`refuse_negative_extinction` refuses a
homogeneous medium whose extinction is negative or not a number, which that
integrator would otherwise render as NaN pixels.
"""

from __future__ import annotations

from collections.abc import Iterable

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["MEDIUM_INTEGRATOR", "lathe_media", "refuse_media", "refuse_negative_extinction"]

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


def refuse_negative_extinction(scene: mi.Scene, integrator: str) -> None:
    """Raise a ``ValueError`` naming the medium if a homogeneous medium of
    ``scene`` (a shape's interior or exterior) has an
    extinction ``sigma_t`` times ``scale`` that is negative or not a
    number: ``integrator`` would render NaN pixels (a negative RGB
    ``sigma_t`` Mitsuba refuses itself; a negative ``scale`` or float
    ``sigma_t`` it accepts); or an ``albedo`` outside [0, 1] (Mitsuba
    accepts it, and the render gains or loses energy)."""
    media = [m for shape in scene.shapes() for m in (shape.interior_medium(), shape.exterior_medium())]
    seen = set()
    for medium in media:
        if medium is None or not medium.is_homogeneous() or id(medium) in seen:
            continue
        seen.add(id(medium))
        mei = dr.zeros(mi.MediumInteraction3f, 1)
        if mi.is_spectral:
            mei.wavelengths = mi.Spectrum(550.0)
        sigma_s, _, sigma_t = medium.get_scattering_coefficients(mei, mi.Bool(True))
        values = np.array(sigma_t, dtype=np.float64).ravel()
        if not np.all(values >= 0.0):
            shown = ", ".join(f"{v:g}" for v in values)
            raise ValueError(
                f"{_name(medium, medium.class_name())}: its extinction 'sigma_t' times 'scale' is ({shown}); "
                f"it must be >= 0 (the integrator {integrator} would render NaN pixels)")
        scattering = np.array(sigma_s, dtype=np.float64).ravel()
        positive = values > 0.0
        albedo = np.divide(scattering, values, out=np.zeros_like(values), where=positive)
        if np.all((albedo >= 0.0) & (albedo <= 1.0 + 1e-6)):
            continue
        shown = ", ".join(f"{v:g}" for v in albedo)
        raise ValueError(
            f"{_name(medium, medium.class_name())}: its 'albedo' is ({shown}); it must be in [0, 1] "
            f"(above 1 the medium scatters more light than it absorbs and scatters away, and "
            f"{integrator} would add energy; below 0 it would subtract it)")
