"""Reliability of the lathe geometry (issue 24): each test here failed
before its fix. Horizontal rays at a vertex's height, near-zero segments,
projective and singular transforms, scales float32 cannot trace, emitting
proxies, many lathes loaded in parallel and very long polylines."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from lathe_shape.kernels.polyline import build_polyline_data, count_crossings_polyline
from lathe_shape.plugin.line_walk import start_walk
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry

# ---------------------------------------------------------------------------
# 13. Horizontal rays at a convex vertex's height cross it once
# ---------------------------------------------------------------------------

BULGE = "0 0, 1 0, 1.5 1, 1 2, 0 2"  # convex vertex (1.5, 1) between two slanted segments
#: Heights of horizontal rays about the vertex: on it, and off it by less
#: than the kernel's joint tolerance (2e-5 for this profile) on both sides.
NEAR_VERTEX = [0.0, 1e-7, -1e-7, 1e-6, -1e-6, 1e-5, -1e-5, 1.9e-5, -1.9e-5]


def _walk_hits(geometry: ExactSceneGeometry, o, d) -> list[float]:
    """The ``t`` of every hit of the ray ``o + t d`` walked along its line
    as lathe_path walks it (spawn_ray between hits)."""
    ray = mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))
    walk, active, hits = start_walk(1), mi.Bool(True), []
    for _ in range(8):
        si, walk = geometry.ray_intersect_walk(ray, active, walk)
        if not si.is_valid()[0]:
            break
        hits.append(float(si.t[0]))
        ray = si.spawn_ray(ray.d)
    return hits


def test_horizontal_ray_at_convex_vertex_walks_two_crossings():
    """Exactly horizontal rays at (and within the joint tolerance of) the
    height of the convex vertex of ``BULGE``: the walk reports two
    crossings (enter, leave), not four (the vertex's pair once on each
    segment, the second at t = 0 after the first)."""
    geometry = ExactSceneGeometry(mi.load_dict({
        "type": "scene", "bulge": {"type": "lathe", "profile": BULGE, "mesh_segments": 16}}))
    for dz in NEAR_VERTEX:
        for direction in ((1.0, 0.0, 0.0), (0.6, 0.8, 0.0), (-1.0, 0.0, 0.0)):
            o = [-5.0 * direction[0], -5.0 * direction[1] + 0.1, 1.0 + dz]
            hits = _walk_hits(geometry, o, direction)
            assert len(hits) == 2, (dz, direction, hits)
            assert all(t > 1e-3 for t in hits), (dz, direction, hits)


def _exact_horizontal_count(pts: np.ndarray, h: float, r_min: float) -> int:
    """Crossings of a horizontal line at height ``h`` (distance ``r_min``
    from the axis) with the polyline ``pts`` revolved, in float64: two per
    segment whose heights straddle ``h`` strictly, where its radius at ``h``
    exceeds ``r_min``."""
    total = 0
    for (r0, z0), (r1, z1) in zip(pts[:-1], pts[1:], strict=True):
        if min(z0, z1) < h < max(z0, z1):
            total += 2 * (r0 + (r1 - r0) * (h - z0) / (z1 - z0) > r_min)
    return total


def test_horizontal_rays_near_vertex_heights_count_exactly():
    """The kernel's crossing count of horizontal rays near each vertex
    height of a profile with monotone joints, a spike (apex) and a notch
    (valley): within the joint tolerance but off the vertex, the exact
    count (never the pair of both segments at a monotone joint); on the
    vertex height, even, and two through the bulge's rim."""
    pts = np.array([[0, 0], [1, 0], [1.5, 1], [1.3, 0.7], [1.2, 2], [1.6, 2.5], [0, 3]], float)
    data = build_polyline_data(pts[:-1], pts[1:])
    offsets = np.array([1e-6, -1e-6, 1e-5, -1e-5, 2e-5, -2e-5])
    heights = np.concatenate([z + offsets for z in (0.7, 1.0, 2.0, 2.5)] + [[0.7, 1.0, 2.0, 2.5]])
    n, r_min = len(heights), 0.05
    o = mi.Point3f(np.full(n, -5.0, np.float32), np.full(n, r_min, np.float32), heights.astype(np.float32))
    d = mi.Vector3f(np.ones(n, np.float32), np.zeros(n, np.float32), np.zeros(n, np.float32))
    count = count_crossings_polyline(data, o, d, mi.Bool(True)).numpy()
    h32 = heights.astype(np.float32).astype(np.float64)
    for k in range(n - 4):
        assert count[k] == _exact_horizontal_count(pts, h32[k], r_min), (h32[k], count[k])
    on_vertex = dict(zip((0.7, 1.0, 2.0, 2.5), count[n - 4:].tolist(), strict=True))
    assert all(c % 2 == 0 for c in on_vertex.values()), on_vertex
    assert on_vertex[2.0] == 2 and on_vertex[2.5] == 2 and on_vertex[1.0] == 2, on_vertex

