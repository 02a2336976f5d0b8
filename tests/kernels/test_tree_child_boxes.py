"""The polyline kernel's BVH with child boxes (kernels/common.py,
``child_box_bvh``), its box test without a quadratic (``enter_child_box``)
and the per-lane stack that walks it (kernels/polyline.py)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.kernels.common import (
    BVH_DEPTH,
    LEAF,
    LatheData,
    LatheRay,
    _sah_split,
    box_rmin2,
    child_box_bvh,
    enter_child_box,
)
from lathe_shape.kernels.polyline import build_polyline_data, count_crossings_polyline, intersect_polyline


def random_boxes(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0, 1, (n, 2))
    return np.stack([lo[:, 0], lo[:, 0] + rng.uniform(0, 0.3, n),
                     lo[:, 1], lo[:, 1] + rng.uniform(0, 0.3, n)], axis=1)


def tree_depth(node) -> int:
    return 0 if node[0] == "leaf" else 1 + max(tree_depth(node[3]), tree_depth(node[4]))


def test_child_box_tree_holds_every_leaf_once_with_its_box():
    """Each copy, walked from its root through both children of every
    inner node, reaches every leaf once; an inner node's record holds the
    bounds of the subtrees at its two children."""
    box = random_boxes(37, 5)
    records, links, n_nodes = child_box_bvh(box, lambda b: list(b), lambda k, b: ["leaf", k])
    assert n_nodes == 2 * len(box) - 1 and len(records) == 4 * n_nodes

    def walk(node):
        """Leaves below ``node`` and their union box."""
        if links[node] & LEAF:
            k = links[node] & (LEAF - 1)
            assert records[node] == ["leaf", k]
            return [k], box[k]
        found, bounds = [], []
        for child, stored in ((node + 1, records[node][:4]), (links[node], records[node][4:])):
            leaves, union = walk(child)
            assert np.allclose(stored, union)
            found += leaves
            bounds.append(union)
        a, b = bounds
        return found, np.array([min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3])])

    for copy in range(4):
        assert sorted(walk(copy * n_nodes)[0]) == list(range(len(box)))


def test_depth_limit_halves_where_the_heuristic_would_go_deeper():
    """Boxes of geometrically growing size make the surface area heuristic
    peel one box at a time; a depth limit halves the rest instead."""
    n = 40
    size = 1.5 ** np.arange(n)
    box = np.stack([np.zeros(n), size, np.zeros(n), size], axis=1)
    assert tree_depth(_sah_split(box, np.arange(n))) > 6
    assert tree_depth(_sah_split(box, np.arange(n), 6)) <= 6
    assert tree_depth(_sah_split(box, np.arange(n), BVH_DEPTH)) <= BVH_DEPTH


def rays(n: int, seed: int):
    rng = np.random.default_rng(seed)
    target = rng.uniform([-1, -1, -1], [1, 1, 1], (n, 3))
    d = rng.normal(size=(n, 3))
    d[: n // 8, :2] = 0  # some rays parallel to the axis
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = target - rng.uniform(0.5, 4, (n, 1)) * d
    return o, d


@pytest.mark.parametrize("rmin", [0.0, 0.3])
@pytest.mark.slow
def test_enter_child_box_matches_sampled_points(rmin):
    """The box test agrees with points sampled densely along each ray (up
    to points within a small distance of the box surface)."""
    n = 4000
    o, d = rays(n, 7)
    box = (rmin, 0.6, -0.2, 0.4)  # rmin, rmax, zmin, zmax
    data = LatheData(bound_r=mi.Float(2.0), bound_z_lo=mi.Float(-2.0), bound_z_hi=mi.Float(2.0),
                     inv_scale=mi.Float(1.0), z_shift=mi.Float(0.0), n_nodes=mi.UInt32(1))
    ray = LatheRay(data, mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)),
                   dr.full(mi.Float, dr.inf, n), dr.full(mi.Bool, True, n))
    record = mi.Vector4f(box[1] ** 2, box_rmin2(box[0]), box[2], box[3])
    entered, _ = enter_child_box(ray, record, ray.s_hi)
    entered = entered.numpy() & ray.active.numpy()

    t = np.linspace(0, 8, 4001)[None, :, None]
    p = o[:, None, :] + t * d[:, None, :]
    r = np.hypot(p[..., 0], p[..., 1])
    eps = 5e-3
    deep = ((r >= box[0] + eps) | (box[0] == 0)) & (r <= box[1] - eps) & (p[..., 2] >= box[2] + eps) \
        & (p[..., 2] <= box[3] - eps)
    assert np.all(entered[deep.any(axis=1)])
    assert entered.sum() > 100
    near = (r >= box[0] - eps) & (r <= box[1] + eps) & (p[..., 2] >= box[2] - eps) \
        & (p[..., 2] <= box[3] + eps)
    assert not np.any(entered & ~near.any(axis=1))


def nearest(data, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Hit distances of the rays ``o + t d`` (numpy (n, 3))."""
    n = len(o)
    hit = intersect_polyline(data, mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)),
                             dr.full(mi.Float, dr.inf, n), dr.full(mi.Bool, True, n))
    return hit.t.numpy()


def test_single_ray_and_many_segments():
    """One ray alone (a width-1 traversal) finds what it finds among many,
    and a profile of 2002 segments (a deeper tree) keeps crossing counts even."""
    z = np.linspace(1, 0, 2001)
    wall = np.stack([0.5 + 0.1 * np.sin(40 * z), z], axis=1)
    pts = np.vstack([[[0.0, 1.0]], wall, [[0.0, 0.0]]])
    data = build_polyline_data(pts[:-1], pts[1:])
    o, d = rays(512, 9)
    many = nearest(data, o, d)
    assert np.isfinite(many).sum() > 100
    for k in (0, 17, 200, int(np.argmax(np.isfinite(many)))):
        assert nearest(data, o[k:k + 1], d[k:k + 1])[0] == many[k]
    far = (o - 10 * d).T.astype(np.float32)
    count = count_crossings_polyline(data, mi.Point3f(far), mi.Vector3f(d.T.astype(np.float32)),
                                     dr.full(mi.Bool, True, len(o))).numpy()
    assert np.all(count % 2 == 0) and np.any(count > 2)


def test_stack_holds_a_leaf_at_the_depth_limit():
    """100 copies of one segment: the heuristic splits one box off per level
    until the depth limit, so leaves sit BVH_DEPTH levels deep, and rays
    that enter every box fill the stack (it overflowed by one entry and
    crashed: a leaf's unpushed child overwrote the top entry)."""
    from lathe_shape.kernels.polyline import next_crossing_polyline, occluded_polyline

    copies = 100
    data = build_polyline_data(np.tile([[1.0, 1.0]], (copies, 1)), np.tile([[1.0, 0.0]], (copies, 1)))
    on = mi.Bool(True)
    # Across the axis: every copy is crossed twice (r = 1 on both sides).
    o, d = mi.Point3f(2.0, 0.0, 0.5), mi.Vector3f(-1.0, 0.0, 0.0)
    assert count_crossings_polyline(data, o, d, on).numpy().tolist() == [2 * copies]
    assert occluded_polyline(data, o, d, mi.Float(10.0), on).numpy().tolist() == [True]
    assert intersect_polyline(data, o, d, mi.Float(10.0), on).t.numpy().tolist() == [1.0]
    # Along the wall inside the boxes' padding: every box entered, no hit.
    o, d = mi.Point3f(1.0 + 2e-5, 0.0, -1.0), mi.Vector3f(0.0, 0.0, 1.0)
    assert occluded_polyline(data, o, d, mi.Float(10.0), on).numpy().tolist() == [False]
    assert not intersect_polyline(data, o, d, mi.Float(10.0), on).valid.numpy().any()
    assert not next_crossing_polyline(data, o, d, mi.Float(10.0), on)[0].valid.numpy().any()
