"""The line a command prints when a stock (non-lathe) integrator renders a
scene with lathes: those lathes are then their reference meshes, not the
exact surfaces, and the user should know it without reading the docs."""

from __future__ import annotations

__all__ = ["EXACT_INTEGRATOR", "is_exact_integrator", "mesh_note"]

#: The integrator that renders lathes exactly, named in the note.
EXACT_INTEGRATOR = "lathe_path"


def is_exact_integrator(integrator) -> bool:
    """Whether ``integrator`` is one of the package's (``lathe_path``, ...),
    or a Mitsuba integrator wrapping one (``aov`` around ``lathe_path``: its
    description names the nested integrator)."""
    if type(integrator).__module__.split(".")[0] == "lathe_shape":
        return True
    return "Lathe" in str(integrator)


def mesh_note(scene, integrator) -> str | None:
    """``None`` when ``integrator`` renders the lathes of ``scene`` exactly
    or the scene has none; else one line saying how many lathes the stock
    integrator renders as their reference meshes, of how many azimuthal
    steps, and which integrator renders them exactly (``lathe_volpath``
    where a lathe bounds a medium, else ``lathe_path``)."""
    from ..plugin.media_check import MEDIUM_INTEGRATOR, lathe_media
    from ..plugin.shape import scene_lathes

    lathes = scene_lathes(scene)
    if not lathes or is_exact_integrator(integrator):
        return None
    steps = sorted({int(lathe.mesh_segments) for lathe in lathes})
    step_text = "/".join(str(s) for s in steps)
    count = len(lathes)
    what = "lathe rendered as its" if count == 1 else "lathes rendered as their"
    meshes = "reference mesh" if count == 1 else "reference meshes"
    # Lathes with media: lathe_path refuses them, lathe_volpath renders them
    exact = MEDIUM_INTEGRATOR if lathe_media(lathes) else EXACT_INTEGRATOR
    return (f"note: {count} {what} {step_text}-step {meshes} by this stock integrator; "
            f"{exact} renders them exactly (e.g. <integrator type=\"{exact}\">)")
