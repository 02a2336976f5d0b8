"""How much reference mesh a lathe carries, and whether the machine can hold it.

A lathe's reference mesh is what stock integrators render. ``lathe_path``
intersects the exact surface and never traces the mesh, so a scene of many
lathes rendered exactly can ask for a light proxy instead
(``<string name="reference" value="proxy"/>``): a coarse tessellation that
keeps the object recognisable in a stock-integrator preview at a fraction of
the memory and load time. Emitting lathes should keep the full mesh: area
lights sample points on the mesh.
"""

from __future__ import annotations

from ..memory import available_memory

__all__ = [
    "BYTES_PER_VERTEX",
    "PROXY_BANDS",
    "PROXY_SEGMENTS",
    "REFERENCE_MODES",
    "check_mesh_budget",
    "reference_bands",
    "reference_steps",
]

#: Values of the ``reference`` parameter.
REFERENCE_MODES = ("mesh", "proxy")

#: Azimuthal steps of a proxy mesh.
PROXY_SEGMENTS = 12

#: Profile bands of a proxy mesh, at most (about): a profile of a million
#: points gets a proxy of this many (runs of its segments merged), so its
#: load is not spent sweeping and building Mitsuba's BVH over 24 million
#: triangles that nothing but a stock-integrator preview would show.
PROXY_BANDS = 4096

#: Peak bytes per reference-mesh vertex while a lathe is built: float64
#: positions, normals and texture coordinates with the temporaries of the
#: revolution, the float32 Mitsuba buffers, and about two faces per vertex
#: (numpy and Mitsuba copies). Measured on the scene profiles: 250-300.
BYTES_PER_VERTEX = 320

#: Share of the available memory one lathe's reference mesh may take.
MEMORY_SHARE = 0.5


def reference_steps(mode: str, mesh_segments: int, who: str) -> int:
    """Azimuthal steps of the reference mesh for the ``reference`` mode."""
    if mode not in REFERENCE_MODES:
        raise ValueError(
            f"{who}: parameter 'reference': unknown mode '{mode}' (expected one of: "
            f"{', '.join(REFERENCE_MODES)})"
        )
    return min(mesh_segments, PROXY_SEGMENTS) if mode == "proxy" else mesh_segments


def reference_bands(mode: str) -> int | None:
    """Profile bands of the reference mesh at most for the ``reference``
    mode (``None``: every band)."""
    return PROXY_BANDS if mode == "proxy" else None


def check_mesh_budget(rings: int, steps: int, who: str, available: int | None = None) -> None:
    """Refuse, before tessellating, a reference mesh of ``rings`` profile
    rings x (``steps`` + 1) columns that would take more than half the
    available memory, with the estimate in the message."""
    vertices = rings * (steps + 1)
    need = vertices * BYTES_PER_VERTEX
    available = available_memory() if available is None else available
    if available is not None and need > MEMORY_SHARE * available:
        raise ValueError(
            f"{who}: parameter 'mesh_segments' = {steps} asks for a reference mesh of "
            f"{vertices:,} vertices, about {need / 2**30:.1f} GiB, more than half the memory "
            f"available ({available / 2**30:.1f} GiB); lower mesh_segments, or render with "
            "lathe_path and <string name=\"reference\" value=\"proxy\"/>"
        )
