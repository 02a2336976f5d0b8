"""Kernel data of big polyline profiles (issue 24, item 7): the segment tree
built level by level (kernels/common.py, ``sah_tree``) is bit for bit the
recursive builder's (``_sah_split`` + ``_store_copies``), the joint side
points likewise, and a million-point profile builds. Timings:
scripts/bench_tree_build.py."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.kernels import common
from lathe_shape.kernels.common import BVH_DEPTH, LEAF
from lathe_shape.kernels.polyline import (
    _node_records,
    _side_points,
    build_polyline_data,
    intersect_polyline,
)


def vase(n: int, seed: int = 0) -> np.ndarray:
    """A closed wavy, noisy vase profile of ``n`` points (both ends on the
    axis, the wall's z increasing: no self-intersection)."""
    rng = np.random.default_rng(seed)
    z = np.linspace(0.0, 10.0, n - 2)
    r = 2.0 + 0.6 * np.sin(1.3 * z) + 0.25 * np.sin(17.0 * z) + 0.002 * rng.standard_normal(n - 2)
    return np.vstack([[[0.0, 0.0]], np.stack([r, z], axis=1), [[0.0, 10.0]]])


def wall_radius(points: np.ndarray, z: np.ndarray) -> np.ndarray:
    """The vase wall's radius at heights ``z`` (the polyline between points)."""
    wall = points[1:-1]
    return np.interp(z, wall[:, 1], wall[:, 0])


def segments(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points[:-1], points[1:]


def boxes(kind: str, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if kind == "geometric":  # the heuristic peels one box at a time
        size = 1.5 ** np.arange(n)
        return np.stack([np.zeros(n), size, np.zeros(n), size], axis=1)
    lo = rng.uniform(0, 1, (n, 2))
    box = np.stack([lo[:, 0], lo[:, 0] + rng.uniform(0, 0.3, n), lo[:, 1], lo[:, 1] + rng.uniform(0, 0.3, n)],
                   axis=1)
    if kind == "ties":  # many equal centres on both axes
        box = np.round(box * 4) / 4
        box[:, 1] = box[:, 0] + 0.25
        box[:, 3] = box[:, 2] + 0.25
    if kind == "wall":  # a cylinder wall (one r centre) and a disc (one z centre)
        z = np.linspace(0, 1, n // 2 + 1)
        r = np.linspace(0, 1, n - n // 2 + 1)
        box = np.vstack([np.stack([np.full(n // 2, 0.99), np.full(n // 2, 1.01), z[:-1], z[1:]], axis=1),
                         np.stack([r[:-1], r[1:], np.zeros(n - n // 2), np.full(n - n // 2, 1e-3)], axis=1)])
    return box


CASES = [(kind, n) for kind in ("random", "ties", "wall") for n in (1, 2, 3, 7, 8, 9, 33, 600)]
CASES += [("geometric", 40), ("ties", 3000)]


@pytest.mark.parametrize(("kind", "n"), CASES)
def test_level_by_level_trees_equal_the_recursive_ones(kind, n):
    """Records (float32 bits) and links of both tree layouts, with and
    without the depth limit, equal the recursive builder's."""
    box = boxes(kind, n, n)

    def child(b):
        return [b[1] * b[1], common.box_rmin2(b[0]), b[2], b[3]]

    leaf_rec = np.arange(8.0 * n).reshape(n, 8) / 7.0
    old = common._child_box_bvh_recursive(box, child, lambda k, b: leaf_rec[k])
    rows = common.child_box_arrays(box)
    assert rows.n_nodes == old[2] == 2 * n - 1
    assert np.array_equal(_node_records(rows, leaf_rec).view(np.uint32),
                          np.asarray(old[0], dtype=np.float32).view(np.uint32))
    assert np.array_equal(rows.links, np.asarray(old[1], dtype=np.uint32))
    new = common.child_box_bvh(box, child, lambda k, b: leaf_rec[k])
    assert np.array_equal(np.asarray(new[0]), np.asarray(old[0])) and new[1] == old[1]

    def record(b):
        return [float(v) for v in b]

    old = common._threaded_bvh_recursive(box, record, lambda k, b: [k, *record(b)[:3]])
    new = common.threaded_bvh(box, record, lambda k, b: [k, *record(b)[:3]])
    assert new[2] == old[2]
    assert np.array_equal(np.asarray(new[0]), np.asarray(old[0])) and new[1] == old[1]


def test_depth_limit_is_kept():
    """Geometric boxes, which make the heuristic peel one at a time, stay
    within the depth limit (levels: depth + 1)."""
    box = boxes("geometric", 40, 0)
    assert len(common.sah_tree(box).levels) > 7
    assert len(common.sah_tree(box, BVH_DEPTH).levels) <= BVH_DEPTH + 1
    assert len(common.sah_tree(box, 6).levels) <= 7


def side_points_loop(r0, z0, r1, z1, normal, shift):
    """The joint side points as they were computed, one segment at a time."""
    start = np.stack([r0, z0], axis=1)
    end = np.stack([r1, z1], axis=1)
    side = np.concatenate([start, end, start, end], axis=1)
    starting_at = {tuple(p): k for k, p in enumerate(start)}
    for k, p in enumerate(end):
        j = starting_at.get(tuple(p))
        bisector = normal[k] + normal[j] if j is not None else np.zeros(2)
        norm = np.linalg.norm(bisector)
        if norm > 1e-6:
            q = p - shift * bisector / norm
            q[0] = max(q[0], 0.0)
            side[k, 6:] = q
            side[j, 4:6] = q
    return side


@pytest.mark.parametrize("kind", ["vase", "closed loop", "shuffled"])
def test_side_points_equal_the_loop(kind):
    points = vase(2000)
    p0, p1 = segments(points)
    if kind == "closed loop":  # a ring: every segment has a successor
        p0, p1 = np.vstack([p0[1:-1], p1[-2:-1]]), np.vstack([p1[1:-1], p0[1:2]])
    if kind == "shuffled":
        order = np.random.default_rng(1).permutation(len(p0))
        p0, p1 = p0[order], p1[order]
    d = p1 - p0
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.hypot(d[:, 0], d[:, 1])[:, None]
    args = (p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1], normal, 1e-4)
    assert np.array_equal(_side_points(*args).astype(np.float32).view(np.uint32),
                          side_points_loop(*args).astype(np.float32).view(np.uint32))


def test_200k_profile_hits_its_wall():
    """Horizontal rays at random heights towards the axis of a 200,000-point
    vase hit its wall where the polyline has it."""
    points = vase(200_000)
    data = build_polyline_data(*segments(points))
    assert data.n_seg == len(points) - 1
    rng = np.random.default_rng(3)
    z = rng.uniform(0.1, 9.9, 256)
    o = mi.Point3f(np.zeros(256), np.full(256, -30.0), z)
    d = mi.Vector3f(0, 1, 0)
    hit = intersect_polyline(data, o, d, mi.Float(np.inf), mi.Bool(True))
    assert np.all(hit.valid.numpy())
    assert np.allclose(hit.t.numpy(), 30.0 - wall_radius(points, z), atol=1e-4)
    # every segment's leaf once per copy
    links = data.links.numpy()
    leaves = links[(links & LEAF) != 0] & (LEAF - 1)
    assert np.array_equal(np.bincount(leaves), np.full(data.n_seg, 4))


@pytest.mark.slow
def test_million_point_kernel_data_builds():
    """A 1,000,000-point profile's kernel data builds: a tree of 2 m - 1
    nodes per copy, every segment a leaf once per copy, the root's child
    boxes holding every segment."""
    points = vase(1_000_000)
    data = build_polyline_data(*segments(points))
    m = len(points) - 1
    assert data.n_seg == m and int(data.n_nodes.numpy()[0]) == 2 * m - 1
    links = data.links.numpy()
    assert len(links) == 4 * (2 * m - 1)
    leaves = links[(links & LEAF) != 0] & (LEAF - 1)
    assert np.array_equal(np.bincount(leaves, minlength=m), np.full(m, 4))
    # The root's (rmax^2, rmin^2, zmin, zmax) of its two children: together
    # the whole profile (unit frame: size 10, z in [-0.5, 0.5])
    root = data.nodes.numpy()[:8]
    r_max = wall_radius(points, points[1:-1, 1]).max() / 10.0
    assert min(root[2], root[6]) <= -0.5 and max(root[3], root[7]) >= 0.5
    assert max(root[0], root[4]) >= np.float32(r_max) ** 2 and min(root[1], root[5]) == -1.0


def test_clustered_tree_hits_what_the_heuristic_tree_hits(monkeypatch):
    """The tree of huge profiles (``clustered_tree``, built above
    ``CLUSTERED_ABOVE`` boxes) finds the same nearest hits, bit for bit,
    as the heuristic's tree, and is a valid tree: every box a leaf once,
    each node's bounds the union of its children's, within BVH_DEPTH."""
    points = vase(20_000)
    box_rows = common.sah_tree  # the heuristic's tree, for the comparison
    rng = np.random.default_rng(5)
    n = 4096
    origin = np.stack([rng.uniform(-5, 5, n), np.full(n, -30.0), rng.uniform(0, 10, n)])
    target = np.stack([rng.uniform(-3, 3, n), rng.uniform(-3, 3, n), rng.uniform(0, 10, n)])
    d = (target - origin) / np.linalg.norm(target - origin, axis=0)
    hits = []
    for above in (10**9, 0):
        monkeypatch.setattr(common, "CLUSTERED_ABOVE", above)
        data = build_polyline_data(*segments(points))
        hit = intersect_polyline(data, mi.Point3f(*origin), mi.Vector3f(*d), mi.Float(np.inf), mi.Bool(True))
        hits.append((hit.valid.numpy(), hit.t.numpy()))
    assert np.array_equal(hits[0][0], hits[1][0]) and hits[0][0].mean() > 0.5
    assert np.array_equal(hits[0][1], hits[1][1])

    p0, p1 = segments(points)
    box = np.stack([np.minimum(p0[:, 0], p1[:, 0]), np.maximum(p0[:, 0], p1[:, 0]),
                    np.minimum(p0[:, 1], p1[:, 1]), np.maximum(p0[:, 1], p1[:, 1])], axis=1)
    tree = common.clustered_tree(box)
    assert box_rows(box).bounds.shape == tree.bounds.shape
    leaf = tree.leaf >= 0
    assert np.array_equal(np.sort(tree.leaf[leaf]), np.arange(len(box)))
    assert np.array_equal(tree.bounds[leaf], box[tree.leaf[leaf]])
    inner = np.flatnonzero(~leaf)
    lo, hi = tree.bounds[tree.lower[inner]], tree.bounds[tree.upper[inner]]
    union = np.stack([np.minimum(lo[:, 0], hi[:, 0]), np.maximum(lo[:, 1], hi[:, 1]),
                      np.minimum(lo[:, 2], hi[:, 2]), np.maximum(lo[:, 3], hi[:, 3])], axis=1)
    assert np.array_equal(tree.bounds[inner], union)
    assert tree.size[0] == 2 * len(box) - 1
    depth = np.zeros(len(tree.axis), dtype=int)
    for ids in tree.levels:
        depth[tree.lower[ids]] = depth[ids] + 1
        depth[tree.upper[ids]] = depth[ids] + 1
    assert depth.max() <= BVH_DEPTH


def test_proxy_of_a_big_profile_is_thinned(tmp_path):
    """A 100,000-point lathe with ``reference="proxy"`` carries a proxy of
    about PROXY_BANDS bands (runs of segments merged), spanning the same
    heights and radii; a small profile's proxy keeps every segment; chains
    are not merged across (a hollow profile of two loops)."""
    from lathe_shape.plugin.reference_mesh import PROXY_BANDS, PROXY_SEGMENTS
    from lathe_shape.profiles import write_profile_csv
    from lathe_shape.tessellate import thin_bands

    def proxy(points, name):
        return mi.load_dict({"type": "lathe", "reference": "proxy",
                             "filename": str(write_profile_csv(tmp_path / name, points))})

    points = vase(100_000)
    lathe = proxy(points, "big.csv")
    faces = lathe.face_count()
    assert faces <= 2 * PROXY_SEGMENTS * (PROXY_BANDS + 2)
    bands = lathe.local_mesh.face_band
    assert bands.max() < len(points) - 1 and np.all(np.diff(bands[:: 2 * PROXY_SEGMENTS]) >= 0)
    local = lathe.local_mesh.positions
    assert np.isclose(local[:, 2].min(), 0.0) and np.isclose(local[:, 2].max(), 10.0)
    assert np.isclose(np.hypot(local[:, 0], local[:, 1]).max(), points[:, 0].max(), rtol=0.02)

    small = proxy(vase(200), "small.csv")
    assert np.array_equal(np.unique(small.local_mesh.face_band), np.arange(199))

    # Two chains of 6 bands each, thinned to runs of 4: the run from band 4
    # stops at the first chain's end (band 5), the second chain starts anew
    ring = np.array([[1, 0], [2, 0], [2, 1], [2, 2], [1, 2], [1, 1], [5, 0], [6, 0], [6, 1], [6, 2],
                     [5, 2], [5, 1]], dtype=float)
    bands = np.array([[k, (k + 1) % 6] for k in range(6)] + [[6 + k, 6 + (k + 1) % 6] for k in range(6)])
    pts, _, _, thin, first = thin_bands(ring, ring, np.arange(12.0), bands, 3)
    assert np.array_equal(first, [0, 4, 6, 8])
    assert np.array_equal(pts[thin].tolist(), [[[1, 0], [1, 2]], [[1, 2], [1, 0]],
                                                [[5, 0], [6, 1]], [[6, 1], [5, 0]]])
