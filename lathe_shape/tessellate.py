"""Reference tessellation of a lathe: profile -> closed triangle mesh (numpy).

The profile (a chain of (r, z) points with per-segment end normals) is swept
through ``azimuth_steps`` equal angular steps about the local +z axis:

* every profile vertex with ``r > 0`` becomes a ring of ``azimuth_steps``
  vertices; a vertex on the axis becomes ``azimuth_steps`` coincident pole
  vertices, one per wedge, whose normals are rotated to the wedge's middle
  azimuth (so a cone tip keeps its slanted normal and no triangle degenerates);
* a vertex where the shading normal is continuous is shared by its two
  segments; at a crease it is duplicated, one copy per normal;
* each segment between two rings becomes a band of quads split into two
  triangles, wound counter-clockwise seen from outside (outward face normal
  ``T_profile x T_azimuth``).

The result is watertight once coincident positions are welded: every edge is
shared by exactly two triangles (``tests/test_tessellate.py`` checks this).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TriangleMesh", "tessellate_profile", "revolve"]


@dataclass(frozen=True)
class TriangleMesh:
    """A triangle mesh in the shape's local frame."""

    #: (V, 3) float64 positions.
    positions: np.ndarray
    #: (V, 3) float64 unit vertex normals.
    normals: np.ndarray
    #: (F, 3) uint32 vertex indices, counter-clockwise seen from outside.
    faces: np.ndarray


def revolve(
    ring_points: np.ndarray,
    ring_normals: np.ndarray,
    bands: np.ndarray,
    azimuth_steps: int,
) -> TriangleMesh:
    """Sweep profile vertices ("rings") about the z axis and connect them.

    ``ring_points`` (k, 2) and ``ring_normals`` (k, 2) give each ring's (r, z)
    and its 2D shading normal; ``bands`` (m, 2) lists the ring pairs (start,
    end) that a profile segment connects. Rings with ``r == 0`` are poles.
    """
    if azimuth_steps < 3:
        raise ValueError(f"mesh_segments must be at least 3, got {azimuth_steps}")
    steps = int(azimuth_steps)
    phi = 2.0 * np.pi * np.arange(steps) / steps
    phi_mid = phi + np.pi / steps
    k = len(ring_points)
    pole = ring_points[:, 0] == 0.0

    # Ring vertex positions at phi_j (r = 0 puts pole copies on the axis);
    # pole copies carry normals rotated to the wedge's middle azimuth.
    angle = np.where(pole[:, None], phi_mid[None, :], phi[None, :])  # (k, steps)
    cos_a, sin_a = np.cos(angle), np.sin(angle)
    r = ring_points[:, 0:1]
    positions = np.stack(
        [
            r * np.cos(phi)[None, :],
            r * np.sin(phi)[None, :],
            np.broadcast_to(ring_points[:, 1:2], (k, steps)),
        ],
        axis=-1,
    )
    nr, nz = ring_normals[:, 0:1], ring_normals[:, 1:2]
    normals = np.stack([nr * cos_a, nr * sin_a, np.broadcast_to(nz, (k, steps))], axis=-1)

    # Vertex index of ring i at azimuth step j.
    def vid(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return i * steps + j

    j = np.arange(steps)
    j1 = (j + 1) % steps
    faces = []
    for a, b in bands:
        ia, ib = np.full(steps, a), np.full(steps, b)
        if not pole[a]:
            # (A_j, B_j, A_j+1): normal T_profile x T_azimuth = outward.
            faces.append(np.stack([vid(ia, j), vid(ib, j), vid(ia, j1)], axis=1))
        if not pole[b]:
            # (A_j+1, B_j, B_j+1); with A a pole, A_j stands for A_j+1.
            a_next = vid(ia, j) if pole[a] else vid(ia, j1)
            faces.append(np.stack([a_next, vid(ib, j), vid(ib, j1)], axis=1))
    return TriangleMesh(
        positions=positions.reshape(-1, 3),
        normals=normals.reshape(-1, 3),
        faces=np.concatenate(faces).astype(np.uint32),
    )


def tessellate_profile(profile, azimuth_steps: int, smooth: bool = True) -> TriangleMesh:
    """Tessellate a :class:`lathe_shape.profile.Profile`.

    With ``smooth`` the vertex normals are the profile's crease-aware shading
    normals; without, every segment gets its flat geometric normal.
    """
    seg = profile.segments
    if smooth:
        n_start, n_end = profile.normal_start, profile.normal_end
    else:
        n_start = n_end = profile.segment_normals()
    ring_points, ring_normals, bands = rings_for_chain(profile.points, seg, n_start, n_end)
    return revolve(ring_points, ring_normals, bands, azimuth_steps)


def rings_for_chain(
    points: np.ndarray,
    segments: np.ndarray,
    normal_start: np.ndarray,
    normal_end: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rings (one per distinct (vertex, normal) pair) and bands per segment."""
    keys: dict[tuple[int, float, float], int] = {}
    ring_points: list[np.ndarray] = []
    ring_normals: list[np.ndarray] = []

    def ring(vertex: int, normal: np.ndarray) -> int:
        key = (int(vertex), float(normal[0]), float(normal[1]))
        if key not in keys:
            keys[key] = len(ring_points)
            ring_points.append(points[vertex])
            ring_normals.append(normal)
        return keys[key]

    bands = np.array(
        [
            (ring(a, normal_start[s]), ring(b, normal_end[s]))
            for s, (a, b) in enumerate(segments)
        ],
        dtype=np.int64,
    )
    return np.array(ring_points), np.array(ring_normals), bands
