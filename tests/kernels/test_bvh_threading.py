"""The lathes' threaded BVH (kernels/common.py): the surface-area-heuristic
tree is complete and correctly threaded, and boxes reaching the axis are
never skipped by rays through the axis."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
from conftest import SCENES

from lathe_shape.kernels.common import LEAF, box_rmin2, threaded_bvh


def test_threaded_tree_visits_every_leaf_once():
    """Each of the four copies, walked entering every node, visits every
    leaf exactly once; skipping an inner node jumps past its whole subtree."""
    rng = np.random.default_rng(5)
    lo = rng.uniform(0, 1, (37, 2))
    box = np.stack([lo[:, 0], lo[:, 0] + rng.uniform(0, 0.3, 37),
                    lo[:, 1], lo[:, 1] + rng.uniform(0, 0.3, 37)], axis=1)
    records, links, n_nodes = threaded_bvh(box, lambda b: ["inner"], lambda k, b: ["leaf", k])
    assert n_nodes == 2 * len(box) - 1
    for copy in range(4):
        first, end = copy * n_nodes, (copy + 1) * n_nodes
        leaves = [records[k][1] for k in range(first, end) if links[k] & LEAF]
        assert sorted(leaves) == list(range(len(box)))
        for k in range(first, end):
            if not links[k] & LEAF:
                below = [j for j in range(k + 1, links[k]) if links[j] & LEAF]
                assert k < links[k] <= end and len(below) >= 2


def test_box_rmin2():
    assert box_rmin2(0.0) < 0
    assert box_rmin2(0.5) == 0.25


def test_rays_through_axis_vertices_hit_there():
    """Rays aimed exactly at the profile's points on the axis hit the lathe
    no farther than that point (the sundae cup's foot is a thin annulus:
    its box, thin in z, was once skipped when r(s)^2 rounded below 0 on
    the axis)."""
    scene = mi.load_dict({"type": "scene", "lathe": {"type": "lathe",
                                                      "filename": str(SCENES / "sundae_cup.csv")}})
    lathe = scene.shapes()[0]
    start, _ = lathe.profile.segment_points()
    axis = start[start[:, 0] == 0]
    assert len(axis) > 0
    rng = np.random.default_rng(11)
    n = 4000
    target = np.stack([np.zeros(n), np.zeros(n), axis[rng.integers(0, len(axis), n), 1]], axis=1)
    v = rng.normal(size=(n, 3))
    o = target + 30.0 * v / np.linalg.norm(v, axis=1, keepdims=True)
    d = (target - o) / np.linalg.norm(target - o, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    si = lathe.ray_intersect_exact(ray, True)
    distance = np.linalg.norm(target - o, axis=1)
    assert np.all(si.t.numpy() <= distance * (1 + 1e-4))
