"""The transmittance of a straight segment through a homogeneous medium,
in closed form: what ``lathe_volpath``'s light-traced caustics multiply
along the particles' paths and the camera connections (the unscattered
part of the light; the scattered part stays path traced)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["heterogeneous_medium", "segment_transmittance"]


def segment_transmittance(medium: mi.MediumPtr, p: mi.Point3f, length: mi.Float,
                          active: mi.Bool) -> mi.Spectrum:
    """Eq. 44: ``exp(-sigma_t * length)`` of a segment from ``p`` through the
    homogeneous ``medium`` (lanes ``active``); 1 where there is no medium
    or the lane is not active."""
    inside = mi.Bool(active) & (medium != None)  # noqa: E711 (Dr.Jit's test)
    mei = dr.zeros(mi.MediumInteraction3f, max(dr.width(p), dr.width(length)))
    mei.p = p
    mei.medium = medium
    _, _, sigma_t = medium.get_scattering_coefficients(mei, inside)
    return dr.select(inside, dr.exp(-sigma_t * length), 1.0)


def heterogeneous_medium(scene: mi.Scene) -> tuple[mi.Shape, mi.Medium] | None:
    """The first (shape, medium) of ``scene`` whose medium (interior or
    exterior) is not homogeneous, or None."""
    for shape in scene.shapes():
        for medium in (shape.interior_medium(), shape.exterior_medium()):
            if medium is not None and not medium.is_homogeneous():
                return shape, medium
    return None
