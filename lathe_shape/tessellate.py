"""Reference tessellation of a lathe: profile -> triangle mesh (numpy).

The profile (a chain of (r, z) points with per-segment end normals) is swept
through ``azimuth_steps`` equal angular steps about the local +z axis:

* every profile vertex with ``r > 0`` becomes a ring of ``azimuth_steps + 1``
  vertices, the last repeating the first at the texture seam (u = 1); a
  vertex on the axis becomes one pole vertex per wedge, all coincident, whose
  normals are rotated to the wedge's middle azimuth (so a cone tip keeps its
  slanted normal and no triangle degenerates);
* texture coordinates are (azimuth / 2 pi, v) with the same v as the exact
  kernels (profile arclength fraction for polylines, (segment + t) / segments
  for B-splines), so textured BSDFs look the same in both render modes;
* a vertex where the shading normal is continuous is shared by its two
  segments; at a crease it is duplicated, one copy per normal;
* each segment between two rings becomes a band of quads split into two
  triangles, wound counter-clockwise seen from outside (outward face normal
  ``T_profile x T_azimuth``).

For the profile of a solid the result is watertight once coincident
positions are welded: every edge is shared by exactly two triangles
(``tests/profiles/test_tessellate.py`` checks this). An open sheet's profile gives an
open mesh, whose free ends are rings of boundary edges.
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
    #: (V, 2) float64 texture coordinates: (azimuth / 2 pi, profile v).
    texcoords: np.ndarray
    #: (F, 3) uint32 vertex indices, counter-clockwise seen from outside.
    faces: np.ndarray
    #: (F,) index of the band (pair of rings, see :func:`revolve`) that each
    #: face belongs to: the profile segment for polylines.
    face_band: np.ndarray


def revolve(
    ring_points: np.ndarray,
    ring_normals: np.ndarray,
    ring_v: np.ndarray,
    bands: np.ndarray,
    azimuth_steps: int,
    max_bands: int | None = None,
) -> TriangleMesh:
    """Sweep profile vertices ("rings") about the z axis and connect them.

    ``ring_points`` (k, 2), ``ring_normals`` (k, 2) and ``ring_v`` (k,) give
    each ring's (r, z), its 2D shading normal and its texture coordinate v;
    ``bands`` (m, 2) lists the ring pairs (start, end) that a profile segment
    connects. Rings with ``r == 0`` are poles.

    Every ring has ``azimuth_steps + 1`` vertex slots: column j sits at
    azimuth ``2 pi j / steps`` with u = j / steps, the last column repeating
    the first one's position (the texture seam). Pole rings use slot j for
    the copy of wedge j (normal and u at the wedge's middle azimuth).

    ``max_bands``: at most that many bands (a light proxy of a profile of
    a million points), see :func:`thin_bands`.
    """
    if azimuth_steps < 3:
        raise ValueError(f"mesh_segments must be at least 3, got {azimuth_steps}")
    band_of_band = np.arange(len(bands))
    if max_bands is not None and len(bands) > max_bands:
        ring_points, ring_normals, ring_v, bands, band_of_band = thin_bands(
            ring_points, ring_normals, ring_v, bands, max_bands)
    steps = int(azimuth_steps)
    cols = np.arange(steps + 1)
    # Column angles, with the seam column at exactly the first one's angle
    # so that its positions coincide bit for bit.
    phi = 2.0 * np.pi * (cols % steps) / steps
    phi_mid = 2.0 * np.pi * (cols + 0.5) / steps
    k = len(ring_points)
    pole = ring_points[:, 0] == 0.0

    r = ring_points[:, 0:1]
    positions = np.stack(
        [
            r * np.cos(phi)[None, :],
            r * np.sin(phi)[None, :],
            np.broadcast_to(ring_points[:, 1:2], (k, steps + 1)),
        ],
        axis=-1,
    )
    # Normals rotated to each column's azimuth (a pole: its wedge's middle).
    angle = np.where(pole[:, None], phi_mid[None, :], phi[None, :])
    nr, nz = ring_normals[:, 0:1], ring_normals[:, 1:2]
    normals = np.stack([nr * np.cos(angle), nr * np.sin(angle), np.broadcast_to(nz, (k, steps + 1))], axis=-1)
    u = np.where(pole[:, None], (cols + 0.5)[None, :] / steps, cols[None, :] / steps)
    texcoords = np.stack([u, np.broadcast_to(ring_v[:, None], (k, steps + 1))], axis=-1)

    # Two triangles per band and column, (m, 2, steps, 3) vertex indices
    # (vertex index of ring i at column j: i (steps + 1) + j):
    # (A_j, B_j, A_j+1), normal T_profile x T_azimuth = outward; and
    # (A_j+1, B_j, B_j+1), where a pole A's A_j stands for A_j+1. A pole
    # ring's own triangle is left out (it would be degenerate).
    a = bands[:, 0:1] * (steps + 1)
    b = bands[:, 1:2] * (steps + 1)
    j = np.arange(steps)[None, :]
    a_next = np.where(pole[bands[:, 0]][:, None], a + j, a + j + 1)
    first = np.stack([a + j, b + j, a + j + 1], axis=-1)
    second = np.stack([a_next, b + j, b + j + 1], axis=-1)
    faces = np.stack([first, second], axis=1)
    keep = np.stack([~pole[bands[:, 0]], ~pole[bands[:, 1]]], axis=1)
    band_of = np.broadcast_to(band_of_band[:, None, None], (len(bands), 2, steps))
    return TriangleMesh(
        positions=positions.reshape(-1, 3),
        normals=normals.reshape(-1, 3),
        texcoords=texcoords.reshape(-1, 2),
        faces=faces[keep].reshape(-1, 3).astype(np.uint32),
        face_band=band_of[keep].reshape(-1).astype(np.uint32),
    )


def thin_bands(
    ring_points: np.ndarray,
    ring_normals: np.ndarray,
    ring_v: np.ndarray,
    bands: np.ndarray,
    max_bands: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """At most about ``max_bands`` bands: runs of consecutive bands of one
    chain (each starting where the one before ends) become one band from
    the run's first ring to its last; unused rings are dropped. Returns the
    rings and bands as :func:`revolve` takes them, and each new band's
    first original band (its ``face_band``)."""
    m = len(bands)
    step = -(-m // max_bands)
    # A chain breaks before band j where it does not start at the point
    # band j - 1 ends at
    breaks = np.any(ring_points[bands[1:, 0]] != ring_points[bands[:-1, 1]], axis=1)
    head = np.zeros(m, dtype=bool)
    head[::step] = True
    head[1:] |= breaks
    first = np.flatnonzero(head)
    last = np.append(first[1:] - 1, m - 1)
    merged = np.stack([bands[first, 0], bands[last, 1]], axis=1)
    used, renumbered = np.unique(merged, return_inverse=True)
    return (ring_points[used], ring_normals[used], ring_v[used],
            renumbered.reshape(merged.shape), first)


def tessellate_profile(profile, azimuth_steps: int, smooth: bool = True,
                       max_bands: int | None = None) -> TriangleMesh:
    """Tessellate a :class:`lathe_shape.profiles.polyline.Profile`
    (``max_bands``: see :func:`revolve`).

    With ``smooth`` the vertex normals are the profile's crease-aware shading
    normals; without, every segment gets its flat geometric normal. The
    texture coordinate v is the profile arclength fraction (as in the exact
    kernel).
    """
    seg = profile.segments
    if smooth:
        n_start, n_end = profile.normal_start, profile.normal_end
    else:
        n_start = n_end = profile.segment_normals()
    p0, p1 = profile.segment_points()
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(p1 - p0, axis=1))])
    v = arc / arc[-1]
    ring_points, ring_normals, ring_v, bands = rings_for_chain(
        profile.points, seg, n_start, n_end, v[:-1], v[1:]
    )
    return revolve(ring_points, ring_normals, ring_v, bands, azimuth_steps, max_bands)


def rings_for_chain(
    points: np.ndarray,
    segments: np.ndarray,
    normal_start: np.ndarray,
    normal_end: np.ndarray,
    v_start: np.ndarray,
    v_end: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rings (one per distinct (vertex, normal, v), numbered in order of
    first use: each segment's start, then its end) and bands per segment."""
    m = len(segments)
    # Keys of the 2m segment ends, interleaved (start of s, end of s)
    keys = np.empty((2 * m, 4), dtype=np.float64)
    keys[0::2, 0], keys[1::2, 0] = segments[:, 0], segments[:, 1]
    keys[0::2, 1:3], keys[1::2, 1:3] = normal_start, normal_end
    keys[0::2, 3], keys[1::2, 3] = v_start, v_end
    # Equal keys as Python's float comparison has them (-0.0 == 0.0):
    # + 0.0 makes every zero positive for the comparison; the rings keep
    # the values of their first use.
    _, first, inverse = np.unique(keys + 0.0, axis=0, return_index=True, return_inverse=True)
    # np.unique numbers the keys in sorted order: renumber by first use
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    ends = first[order]
    vertex = keys[ends, 0].astype(np.int64)
    bands = rank[inverse.reshape(-1)].reshape(m, 2).astype(np.int64)
    return points[vertex], keys[ends, 1:3].copy(), keys[ends, 3].copy(), bands
