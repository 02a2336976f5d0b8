"""The skeleton shared by the lathe intersection kernels.

A lathe kernel (polyline: kernels/polyline.py, B-spline: kernels/bspline.py)
intersects rays, given in the lathe's local frame (axis of revolution = +z),
with a profile revolved about that axis. Every kind works the same way and
only supplies its leaf test (one segment or one piece of curve) and its
local geometry; this module holds the rest:

* :class:`LatheData`: the opaque buffers every kind has (BVH and padded
  bounding cylinder), built with :func:`opaque` values so that new profile
  data never recompiles a kernel;
* :func:`threaded_bvh`: the stackless BVH over annular boxes in the (r, z)
  plane, stored four times with different child orders (B-splines), and
  :func:`child_box_bvh`, the same tree for a traversal with a stack, each
  inner node holding its children's boxes (polylines);
* :func:`unit_frame`: the profile's size and centre, by which every kind
  stores its data divided (see "Units" below);
* :class:`LatheRay`: ray set-up: into the unit frame, clip against the
  bounding cylinder, move the origin to the entry point, the ray's radial
  quadratic and its BVH copy;
* :func:`enter_annular_box`, :func:`bvh_link`, :func:`bvh_next`: one step of
  the threaded traversal; :func:`enter_child_box`: the box test of the
  child-box tree;
* the result types :class:`LatheHit` and :class:`LatheGeometry`.

Units. Whatever the user's units (a profile 1e-30 or 1e20 across), the
kernels compute in a *unit frame*: each kind stores its profile data as
``r / S``, ``(z - z_c) / S`` (``S`` the profile's size, ``z_c`` the centre of
its z range; :func:`unit_frame`), and the ray set-up maps the local ray there
(origin scaled and shifted, direction scaled to unit length), so every
tolerance, pad and threshold of a kernel is relative to the profile and to
``|d|``, and no square over- or underflows float32. Ray parameters found
in the unit frame are scaled back with one multiply (``LatheRay.t_scale``).

Float32 precision. A ray that starts far from the lathe (a camera ray, or a
long shadow ray) has ``|o|`` much larger than the profile, and the constant
terms of the quadratics below (``|o_xy|^2 - R^2``) then lose most of their
digits to cancellation. Every kernel therefore first moves the origin to the
ray's entry into the (padded) bounding cylinder and measures ``s`` from
there; the clip itself uses a factored discriminant that does not cancel.
A ray with ``d_z = 0`` would make the slab bounds ``0 * inf``; ``d_z`` is
nudged to a tiny value instead, which makes the slab all or nothing.

The result classes are Dr.Jit structs (usable with ``dr.select``,
``dr.zeros`` and as loop state) whose field types come from the active
Mitsuba variant, so the kernels can be imported before ``mi.set_variant``.
All Dr.Jit functions here are traceable inside an outer symbolic loop.
"""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = [
    "BVH_DEPTH",
    "LEAF",
    "LatheData",
    "LatheGeometry",
    "LatheHit",
    "LatheRay",
    "NO_CROSSING",
    "VariantStruct",
    "after_t_with_ties",
    "aligned_empty",
    "box_rmin2",
    "clustered_tree",
    "bvh_link",
    "bvh_next",
    "child_box_bvh",
    "enter_annular_box",
    "enter_child_box",
    "opaque",
    "radial_interval",
    "threaded_bvh",
    "to_unit_frame",
    "unit_frame",
]

#: Flag bit in a threaded-BVH link word marking a leaf (low bits: its index).
LEAF = 0x80000000

#: The crossing key of a place along a ray that is no crossing of the lathe
#: at hand (the kernels' ``next_crossing_*``: continue after a ray parameter).
NO_CROSSING = 0xFFFFFFFF


class VariantStruct(type):
    """Metaclass: ``DRJIT_STRUCT`` built from ``_FIELDS`` (Mitsuba type
    names) for the variant active at the time of use."""

    @property
    def DRJIT_STRUCT(cls) -> dict:  # noqa: N802 (Dr.Jit's name)
        return {key: getattr(mi, name) for key, name in cls._FIELDS.items()}


class LatheHit(metaclass=VariantStruct):
    """Nearest hit of a local-frame ray: ``t`` (units of the ray direction,
    inf on a miss), profile segment ``seg``, position ``u`` in [0, 1] along
    the segment (the curve parameter for B-splines), and ``valid``."""

    _FIELDS = {"t": "Float", "seg": "UInt32", "u": "Float", "valid": "Bool"}

    def __init__(self, t=None, seg=None, u=None, valid=None) -> None:
        self.t = mi.Float(dr.inf) if t is None else t
        self.seg = mi.UInt32(0) if seg is None else seg
        self.u = mi.Float(0) if u is None else u
        self.valid = mi.Bool(False) if valid is None else valid


class LatheGeometry(metaclass=VariantStruct):
    """Local differential geometry at a hit: unit outward geometric normal
    ``n``, unit shading normal ``sh_n``, ``uv`` and the partials ``dp_du``,
    ``dp_dv``."""

    _FIELDS = {"n": "Vector3f", "sh_n": "Vector3f", "uv": "Point2f", "dp_du": "Vector3f", "dp_dv": "Vector3f"}

    def __init__(self, n=None, sh_n=None, uv=None, dp_du=None, dp_dv=None) -> None:
        self.n = mi.Vector3f(0, 0, 1) if n is None else n
        self.sh_n = mi.Vector3f(0, 0, 1) if sh_n is None else sh_n
        self.uv = mi.Point2f(0) if uv is None else uv
        self.dp_du = mi.Vector3f(0) if dp_du is None else dp_du
        self.dp_dv = mi.Vector3f(0) if dp_dv is None else dp_dv


def _revolved_area(rmin, rmax, zmin, zmax):
    """Surface area (over 2 pi) of annular boxes revolved about the axis:
    the chance that a random ray meets one is proportional to it (the
    surface area heuristic)."""
    return (rmax + rmin) * (zmax - zmin) + (rmax - rmin) * (rmax + rmin)


def _sah_split(box: np.ndarray, idx: np.ndarray, depth: int | None = None):
    """Tree over the boxes ``idx`` of ``box`` (rows ``(rmin, rmax, zmin,
    zmax)``): ``('leaf', k, bounds)`` or ``('node', bounds, axis, lower,
    upper)``, ``lower`` holding the smaller centres along ``axis`` (0: r,
    1: z). The split, along either axis between boxes sorted by centre,
    minimises the surface area heuristic (:func:`_revolved_area` of each
    side times its box count): fewer nodes visited per ray than a median
    split. ``depth``: at most that many levels below this node (``None``:
    any); where the heuristic's split would need more, the split halves
    the boxes instead."""
    # (whole-array numpy calls, and plain Python for small nodes, where
    # numpy's overhead per call dominates: the tree is built in the first
    # render of a lathe, whose time a user waits for)
    if len(idx) <= _SMALL_NODE:
        return _sah_split_small(box, [int(k) for k in idx], depth)
    sub = box[idx]
    low, high = sub.min(axis=0), sub.max(axis=0)
    bounds = (low[0], high[1], low[2], high[3])
    best = None
    count = np.arange(1, len(idx))
    for axis in (0, 1):
        perm = np.argsort(sub[:, 2 * axis] + sub[:, 2 * axis + 1], kind="stable")
        b = sub[perm]
        # Bounds of the first k boxes (prefix) and of the last n - k
        # (suffix): columns (rmin, zmin) and (rmax, zmax)
        pre_lo, pre_hi = np.minimum.accumulate(b[:, 0::2]), np.maximum.accumulate(b[:, 1::2])
        suf_lo = np.minimum.accumulate(b[::-1, 0::2])[::-1]
        suf_hi = np.maximum.accumulate(b[::-1, 1::2])[::-1]
        cost = (_revolved_area(pre_lo[:-1, 0], pre_hi[:-1, 0], pre_lo[:-1, 1], pre_hi[:-1, 1]) * count
                + _revolved_area(suf_lo[1:, 0], suf_hi[1:, 0], suf_lo[1:, 1], suf_hi[1:, 1]) * count[::-1])
        k = int(cost.argmin())
        if best is None or cost[k] < best[0]:
            best = (cost[k], axis, idx[perm], k + 1)
    _, axis, order, half = best
    if depth is not None:
        if max(half, len(idx) - half) > 1 << (depth - 1):
            half = len(idx) // 2
        depth -= 1
    return ("node", bounds, axis, _sah_split(box, order[:half], depth),
            _sah_split(box, order[half:], depth))


#: Nodes of at most this many boxes are split by :func:`_sah_split_small`.
_SMALL_NODE = 8


def _sah_split_small(box: np.ndarray, idx: list[int], depth: int | None):
    """:func:`_sah_split` of a few boxes in plain Python: the same float64
    arithmetic in the same order, so the same tree."""
    rows = box[idx].tolist()
    bounds = (min(r[0] for r in rows), max(r[1] for r in rows),
              min(r[2] for r in rows), max(r[3] for r in rows))
    n = len(idx)
    if n == 1:
        return ("leaf", idx[0], bounds)
    best = None
    for axis in (0, 1):
        perm = sorted(range(n), key=lambda i: rows[i][2 * axis] + rows[i][2 * axis + 1])  # stable
        b = [rows[i] for i in perm]
        pre = [b[0]]  # bounds of the first k + 1 boxes, of the last n - k
        suf = [b[-1]]
        for r, q in zip(b[1:], b[-2::-1], strict=True):
            p, s = pre[-1], suf[-1]
            pre.append((min(p[0], r[0]), max(p[1], r[1]), min(p[2], r[2]), max(p[3], r[3])))
            suf.append((min(s[0], q[0]), max(s[1], q[1]), min(s[2], q[2]), max(s[3], q[3])))
        suf.reverse()
        for k in range(n - 1):
            cost = _revolved_area(*pre[k]) * (k + 1) + _revolved_area(*suf[k + 1]) * (n - 1 - k)
            if best is None or cost < best[0]:
                best = (cost, axis, [idx[i] for i in perm], k + 1)
    _, axis, order, half = best
    if depth is not None:
        if max(half, n - half) > 1 << (depth - 1):
            half = n // 2
        depth -= 1
    return ("node", bounds, axis, _sah_split_small(box, order[:half], depth),
            _sah_split_small(box, order[half:], depth))


def _bounds(node: tuple) -> tuple:
    """The bounds of a node of :func:`_sah_split`'s tree."""
    return node[2] if node[0] == "leaf" else node[1]


def _store_copies(tree: tuple, inner_record: Callable, leaf_record: Callable,
                  link_to_second: bool) -> tuple[list, list]:
    """``(records, links)`` of the four pre-order copies of ``tree`` (see
    :func:`threaded_bvh`): ``inner_record(node, first, second)`` with the
    children in the copy's order, ``leaf_record(index, bounds)``; an inner
    node's link is the global index of its second child
    (``link_to_second``) or of the node after its subtree. Each record is
    made once per node and child order, and shared by the copies."""
    records: list = []
    links: list = []
    made: dict[tuple[int, bool], list] = {}  # (id(node), children swapped) -> record

    def store(node, z_up: bool, r_out: bool) -> None:
        if node[0] == "leaf":
            key = (id(node), False)
            if key not in made:
                made[key] = leaf_record(node[1], node[2])
            records.append(made[key])
            links.append(LEAF | node[1])
            return
        _, _, axis, first, second = node
        swap = (axis == 1 and not z_up) or (axis == 0 and r_out)
        if swap:
            first, second = second, first
        key = (id(node), swap)
        if key not in made:
            made[key] = inner_record(node, first, second)
        me = len(records)
        records.append(made[key])
        links.append(0)
        store(first, z_up, r_out)
        if link_to_second:
            links[me] = len(records)
        store(second, z_up, r_out)
        if not link_to_second:
            links[me] = len(records)  # miss link: next node after this subtree

    for z_up, r_out in [(True, True), (True, False), (False, True), (False, False)]:
        store(tree, z_up, r_out)
    return records, links


def threaded_bvh(
    box: np.ndarray,
    inner_record: Callable[[tuple], list],
    leaf_record: Callable[[int, tuple], list],
) -> tuple[list, list, int]:
    """A stackless BVH over annular boxes in the (r, z) plane.

    ``box`` is (n, 4) with rows ``(rmin, rmax, zmin, zmax)``. The surface-area-heuristic
    tree is stored four times in pre-order with miss links, so that a ray can
    walk it with one index: copy ``2 * (d_z < 0) + (moving away from the
    axis)`` visits the lower child of a z split first when the ray goes up,
    and the outer child of an r split first when it moves outward.

    Returns ``(records, links, n_nodes)``: ``records[k]`` is
    ``inner_record(bounds)`` or ``leaf_record(index, bounds)``; ``links[k]``
    is an inner node's miss link (global index of the next node after its
    subtree) or ``LEAF | index`` for a leaf; ``n_nodes`` per copy. The tree
    is :func:`sah_tree`'s (that of :func:`_threaded_bvh_recursive`).
    """
    tree = sah_tree(box)
    n_nodes = len(tree.axis)
    leaf = tree.leaf >= 0
    made = [inner_record(tuple(b)) if k < 0 else leaf_record(int(k), tuple(b))
            for k, b in zip(tree.leaf.tolist(), tree.bounds, strict=True)]
    records: list = [None] * (4 * n_nodes)
    links = np.empty(4 * n_nodes, dtype=np.int64)
    for copy, (z_up, r_out) in enumerate(_COPIES):
        pos, _, _ = tree.preorder(z_up, r_out)
        row = copy * n_nodes + pos
        for r, rec in zip(row.tolist(), made, strict=True):
            records[r] = rec
        links[row] = np.where(leaf, LEAF | tree.leaf, row + tree.size)
    assert n_nodes == 2 * len(box) - 1
    return records, links.tolist(), n_nodes


def _threaded_bvh_recursive(box, inner_record, leaf_record):
    """:func:`threaded_bvh` by the recursive builder (:func:`_sah_split`,
    :func:`_store_copies`): the reference its level-by-level build must
    equal (tests, scripts/bench_tree_build.py)."""
    tree = _sah_split(np.asarray(box, dtype=np.float64), np.arange(len(box)))
    records, links = _store_copies(tree, lambda node, first, second: inner_record(node[1]),
                                   leaf_record, False)
    return records, links, 2 * len(box) - 1


#: The four copies' child orders ``(z_up, r_out)``, in storage order.
_COPIES = ((True, True), (True, False), (False, True), (False, False))


#: Levels below the root of a :func:`child_box_bvh` at most: a kernel's
#: per-lane stack of children still to visit needs as many entries.
BVH_DEPTH = 32


def child_box_bvh(
    box: np.ndarray,
    child_record: Callable[[tuple], list],
    leaf_record: Callable[[int, tuple], list],
) -> tuple[list, list, int]:
    """A BVH over annular boxes in the (r, z) plane for a traversal with a
    stack, whose inner nodes hold their children's boxes.

    The tree (``box`` as in :func:`threaded_bvh`, at most
    :data:`BVH_DEPTH` levels) is stored four times in pre-order, each copy
    with the child order of :func:`threaded_bvh`'s copy. An inner node's
    record is ``child_record(bounds)`` of its first child followed by that
    of its second child, so that one visit tests both; its first child is
    the next node. Returns ``(records, links, n_nodes)``: ``links[k]`` is
    the global index of an inner node's second child, or ``LEAF | index``
    for a leaf; ``n_nodes`` per copy. A callback per node: for big trees
    use :func:`child_box_arrays`.
    """
    rows = child_box_arrays(box)
    made: dict = {}
    records = []
    for k, node, first, second in zip(rows.leaf.tolist(), rows.node.tolist(), rows.first.tolist(),
                                      rows.second.tolist(), strict=True):
        key = (node, first)
        if key not in made:
            made[key] = (leaf_record(k, tuple(rows.tree.bounds[node])) if k >= 0 else
                         [*child_record(tuple(rows.tree.bounds[first])),
                          *child_record(tuple(rows.tree.bounds[second]))])
        records.append(made[key])
    return records, rows.links.tolist(), rows.n_nodes


class ChildBoxRows:
    """:func:`child_box_bvh`'s four copies as arrays over their rows (the
    stored nodes, ``4 * n_nodes``): ``node`` (the :class:`BoxTree` node),
    ``first``/``second`` (its children in the copy's order, -1 at a leaf),
    ``leaf`` (box index, -1 at an inner node), ``links`` (uint32, as
    :func:`child_box_bvh`'s), with the ``tree`` and ``n_nodes``."""

    def __init__(self, tree, node, first, second, leaf, links, n_nodes) -> None:
        self.tree, self.node, self.first, self.second = tree, node, first, second
        self.leaf, self.links, self.n_nodes = leaf, links, n_nodes


#: Boxes above which :func:`child_box_arrays` builds :func:`clustered_tree`
#: instead of :func:`sah_tree`: the heuristic over every box costs about
#: 6 s at a million boxes, the clustered tree 0.3 s, and renders as fast
#: (scripts/bench_tree_build.py).
CLUSTERED_ABOVE = 1 << 17

#: Consecutive boxes per cluster of :func:`clustered_tree`.
CLUSTER_SIZE = 32


def child_box_arrays(box: np.ndarray) -> ChildBoxRows:
    """The rows of :func:`child_box_bvh` (same tree, same order) as arrays,
    without a callback per node. Above :data:`CLUSTERED_ABOVE` boxes the
    tree is :func:`clustered_tree`'s."""
    if len(box) > CLUSTERED_ABOVE:
        tree = clustered_tree(box, BVH_DEPTH)
    else:
        tree = sah_tree(box, BVH_DEPTH)
    n_nodes = len(tree.axis)
    # (int32 indices: half the memory traffic of the copies' gathers)
    node = np.empty(4 * n_nodes, dtype=np.int32)
    first = np.empty(4 * n_nodes, dtype=np.int32)
    second = np.empty(4 * n_nodes, dtype=np.int32)
    leaf = np.empty(4 * n_nodes, dtype=np.int32)
    links = np.empty(4 * n_nodes, dtype=np.uint32)
    for copy, (z_up, r_out) in enumerate(_COPIES):
        pos, f, s = tree.preorder(z_up, r_out)
        # The copy's rows in storage order: the node at each position
        at = np.empty(n_nodes, dtype=np.int32)
        at[pos] = np.arange(n_nodes, dtype=np.int32)
        rows = slice(copy * n_nodes, (copy + 1) * n_nodes)
        node[rows] = at
        first[rows] = f[at]
        second[rows] = s[at]
        leaf[rows] = tree.leaf[at]
        links[rows] = np.where(leaf[rows] >= 0, np.uint32(LEAF) | leaf[rows].astype(np.uint32),
                               (copy * n_nodes + pos[second[rows]]).astype(np.uint32))
    assert n_nodes == 2 * len(box) - 1
    return ChildBoxRows(tree, node, first, second, leaf, links, n_nodes)


def _child_box_bvh_recursive(box, child_record, leaf_record):
    """:func:`child_box_bvh` by the recursive builder (:func:`_sah_split`,
    :func:`_store_copies`): the reference its level-by-level build must
    equal (tests, scripts/bench_tree_build.py)."""
    tree = _sah_split(np.asarray(box, dtype=np.float64), np.arange(len(box)), BVH_DEPTH)
    records, links = _store_copies(
        tree, lambda node, first, second: [*child_record(_bounds(first)), *child_record(_bounds(second))],
        leaf_record, True)
    return records, links, 2 * len(box) - 1


# ---------------------------------------------------------------------------
# The same tree, built level by level over whole arrays
# ---------------------------------------------------------------------------

class BoxTree:
    """:func:`_sah_split`'s tree as arrays over its nodes, numbered level by
    level (root 0; the children of a level's nodes, lower then upper, in the
    order of their parents): ``bounds`` (M, 4) float64, ``axis`` (M,)
    (0: r, 1: z, -1: leaf), ``lower``/``upper`` (M,) child ids (-1 at a
    leaf), ``leaf`` (M,) box index (-1 at an inner node), ``size`` (M,)
    nodes in the subtree, and ``levels``: the node ids of each level."""

    def __init__(self, bounds, axis, lower, upper, leaf, size, levels) -> None:
        self.bounds, self.axis, self.lower, self.upper = bounds, axis, lower, upper
        self.leaf, self.size, self.levels = leaf, size, levels

    def preorder(self, z_up: bool, r_out: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(pos, first, second)``: every node's index in the pre-order copy
        ``(z_up, r_out)`` (see :func:`_store_copies`) and its children in
        that copy's order (-1 at a leaf)."""
        swap = ((self.axis == 1) & (not z_up)) | ((self.axis == 0) & r_out)
        first = np.where(swap, self.upper, self.lower)
        second = np.where(swap, self.lower, self.upper)
        pos = np.zeros(len(self.axis), dtype=np.int64)
        for ids in self.levels:
            ids = ids[self.axis[ids] >= 0]
            f, s = first[ids], second[ids]
            pos[f] = pos[ids] + 1
            pos[s] = pos[ids] + 1 + self.size[f]
        return pos, first, second


def _dense_rank(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sorted distinct values, rank of each value among them)``."""
    order = np.argsort(values, kind="stable")
    s = values[order]
    new = np.empty(len(s), dtype=bool)
    new[:1] = True
    np.not_equal(s[1:], s[:-1], out=new[1:])
    rank_sorted = np.cumsum(new) - 1
    rank = np.empty(len(values), dtype=np.int64)
    rank[order] = rank_sorted
    return s[new], rank


def _box_order(key: np.ndarray, other: np.ndarray | None) -> np.ndarray:
    """Box indices sorted by ``key``, ties by ``other`` (if given), then by
    index."""
    if other is None:
        return np.argsort(key, kind="stable")
    return np.lexsort((np.arange(len(key)), other, key))


def sah_tree(box: np.ndarray, depth: int | None = None) -> BoxTree:
    """:func:`_sah_split` of all boxes (``idx = arange(n)``), bit for bit
    the same tree, built level by level with whole-array numpy operations:
    the first render of a lathe of a million profile points waits for it.

    Why it is the same tree. A node's boxes, in the order the recursion
    hands them down, are sorted by the centre along the parent's split
    axis, ties by the grandparent's order, and so on up to the box index.
    A stable sort of them by the centre along ``b`` is therefore ordered
    by ``(centre_b, centre_other, index)`` once an ancestor split along the
    other axis, else by ``(centre_b, index)``: two orders fixed for the
    whole profile per axis. Each level keeps every node's boxes in both
    axes' orders (contiguous runs, one per node); a split partitions the
    runs stably, and a child whose ancestors first split along the other
    axis re-sorts its run of the first kind into the second. The prefix
    and suffix bounds of every run come from one cumulative min / max over
    the whole level, on dense ranks of the box coordinates offset per run
    (exact: no float arithmetic), and the surface area heuristic is then
    evaluated with :func:`_revolved_area` on the same float64 values in the
    same order as the recursion, its first minimum per run taken as it
    does (axis 0 first, ties to the smaller split)."""
    box = np.asarray(box, dtype=np.float64)
    n = len(box)
    ranks, values = [], []
    for c in range(4):
        v, r = _dense_rank(box[:, c])
        values.append(v)
        ranks.append(r)
    centre = [box[:, 0] + box[:, 1], box[:, 2] + box[:, 3]]
    # Per axis b: rank of each box in the order (centre_b, index) and, where
    # centres tie, in (centre_b, centre_other, index)
    plain, full = [], []
    for b in (0, 1):
        order = _box_order(centre[b], None)
        ties = bool(np.any(centre[b][order][1:] == centre[b][order][:-1]))
        plain.append(order)
        full.append(_box_order(centre[b], centre[1 - b]) if ties else None)
    full_rank = []
    for b in (0, 1):
        if full[b] is None:
            full_rank.append(None)
        else:
            r = np.empty(n, dtype=np.int64)
            r[full[b]] = np.arange(n)
            full_rank.append(r)
    bits = max(int(n).bit_length(), 1)
    mask = (1 << bits) - 1

    # Per node of the tree (filled level by level)
    out_id, out_bounds, out_axis, out_lower, out_upper, out_leaf, out_count = [], [], [], [], [], [], []
    levels = []
    next_id = 1
    if n == 1:
        return BoxTree(box[:1].copy(), np.array([-1], np.int8), np.array([-1]), np.array([-1]),
                       np.array([0]), np.array([1]), [np.array([0])])

    # The level's active (inner) nodes: ids, run starts and lengths, whether
    # an ancestor split along r / z; runs of their boxes in each axis' order
    ids = np.array([0])
    start = np.array([0])
    count = np.array([n])
    used = np.zeros((1, 2), dtype=bool)
    runs = [plain[0].astype(np.int64), plain[1].astype(np.int64)]
    level = 0
    levels.append(np.array([0]))
    while len(ids):
        m = len(ids)
        total = len(runs[0])
        seg = np.repeat(np.arange(m), count)
        pos_in = np.arange(total) - start[seg]
        off_a = (m - 1 - seg) << bits  # makes an earlier run's values larger
        off_b = seg << bits            # ... smaller
        last = start + count - 1
        best_cost, best_k, bounds = [], [], None
        for b in (0, 1):
            elems = runs[b]
            rk = [ranks[c][elems] for c in range(4)]
            pre_lo = [np.minimum.accumulate(rk[c] + off_a) & mask for c in (0, 2)]
            pre_hi = [np.maximum.accumulate(rk[c] + off_b) & mask for c in (1, 3)]
            suf_lo = [np.minimum.accumulate((rk[c] + off_b)[::-1])[::-1] & mask for c in (0, 2)]
            suf_hi = [np.maximum.accumulate((rk[c] + off_a)[::-1])[::-1] & mask for c in (1, 3)]
            p = [values[0][pre_lo[0]], values[1][pre_hi[0]], values[2][pre_lo[1]], values[3][pre_hi[1]]]
            s = [values[0][suf_lo[0]], values[1][suf_hi[0]], values[2][suf_lo[1]], values[3][suf_hi[1]]]
            if bounds is None:
                bounds = np.stack([p[c][last] for c in range(4)], axis=1)
            left = pos_in + 1
            cost = np.full(total, np.inf)
            cost[:-1] = (_revolved_area(p[0][:-1], p[1][:-1], p[2][:-1], p[3][:-1]) * left[:-1]
                         + _revolved_area(s[0][1:], s[1][1:], s[2][1:], s[3][1:]) * (count[seg] - left)[:-1])
            cost[last] = np.inf
            low = np.minimum.reduceat(cost, start)
            first = np.where(cost == low[seg], np.arange(total), total)
            best_cost.append(low)
            best_k.append(np.minimum.reduceat(first, start) - start)
        axis = (best_cost[1] < best_cost[0]).astype(np.int8)
        half = np.where(axis == 1, best_k[1], best_k[0]) + 1
        if depth is not None:
            limit = 1 << (depth - level - 1)
            half = np.where(np.maximum(half, count - half) > limit, count // 2, half)
        # This level's nodes
        lower = next_id + 2 * np.arange(m)
        out_id.append(ids)
        out_bounds.append(bounds)
        out_axis.append(axis)
        out_lower.append(lower)
        out_upper.append(lower + 1)
        out_leaf.append(np.full(m, -1))
        out_count.append(count)
        next_id += 2 * m
        # Partition both orders: the first ``half`` boxes of the split
        # axis' run go to the lower child
        upper_side = np.zeros(n, dtype=bool)
        for b in (0, 1):
            sel = (axis[seg] == b) & (pos_in >= half[seg])
            upper_side[runs[b][sel]] = True
        for b in (0, 1):
            side = upper_side[runs[b]]
            n_up = np.cumsum(side)
            n_low = np.arange(1, total + 1) - n_up
            before_up = np.where(start > 0, n_up[start - 1], 0)
            before_low = start - before_up
            dest = np.where(side, start[seg] + half[seg] + n_up - 1 - before_up[seg],
                            start[seg] + n_low - 1 - before_low[seg])
            moved = np.empty_like(runs[b])
            moved[dest] = runs[b]
            runs[b] = moved
        # Children (lower, upper per node), interleaved
        c_start = np.stack([start, start + half], axis=1).ravel()
        c_count = np.stack([half, count - half], axis=1).ravel()
        c_ids = np.stack([lower, lower + 1], axis=1).ravel()
        c_used = np.repeat(used, 2, axis=0)
        c_used[np.arange(2 * m), np.repeat(axis, 2)] = True
        levels.append(c_ids)
        # A child whose ancestors now first split along a re-sorts its run
        # in the other axis' order into (centre, other centre, index)
        for b in (0, 1):
            if full_rank[b] is None:
                continue
            newly = c_used[:, 1 - b] & ~np.repeat(used[:, 1 - b], 2) & (c_count > 1)
            if newly.any():
                where = np.flatnonzero(np.repeat(newly, c_count))
                child = np.repeat(np.arange(2 * m), c_count)[where]
                elems = runs[b][where]
                runs[b][where] = elems[np.argsort((child << bits) | full_rank[b][elems])]
        # Leaves: children of one box
        one = c_count == 1
        if one.any():
            k = runs[0][c_start[one]]
            out_id.append(c_ids[one])
            out_bounds.append(box[k])
            out_axis.append(np.full(len(k), -1, dtype=np.int8))
            out_lower.append(np.full(len(k), -1))
            out_upper.append(np.full(len(k), -1))
            out_leaf.append(k)
            out_count.append(np.ones(len(k), dtype=np.int64))
            keep_elem = np.repeat(~one, c_count)
            runs = [runs[0][keep_elem], runs[1][keep_elem]]
        inner = ~one
        ids = c_ids[inner]
        count = c_count[inner]
        start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
        used = c_used[inner]
        level += 1
    # Rows in id order
    row_id = np.concatenate(out_id)
    inv = np.empty(len(row_id), dtype=np.int64)
    inv[row_id] = np.arange(len(row_id))
    return BoxTree(np.concatenate(out_bounds)[inv], np.concatenate(out_axis)[inv],
                   np.concatenate(out_lower)[inv], np.concatenate(out_upper)[inv],
                   np.concatenate(out_leaf)[inv], 2 * np.concatenate(out_count)[inv] - 1, levels)


def clustered_tree(box: np.ndarray, depth: int = BVH_DEPTH, cluster: int = CLUSTER_SIZE) -> BoxTree:
    """A tree over ``box`` for profiles of a million segments: the boxes in
    their given order (a profile's segments follow its chain, so
    consecutive boxes lie together) are grouped into clusters of
    ``cluster``; :func:`sah_tree` splits the clusters' bounds, and below
    each cluster a balanced tree halves its run of boxes. Within ``depth``
    levels: the clusters' tree gets ``depth`` less the levels of a cluster.

    Costs whole-array passes over the boxes for the cluster levels only
    (log2 ``cluster`` of them), where :func:`sah_tree` makes one per level
    of the whole tree with sorts and cumulative bounds."""
    box = np.asarray(box, dtype=np.float64)
    n = len(box)
    sub_levels = max(int(cluster - 1).bit_length(), 0)
    starts = np.arange(0, n, cluster)
    counts = np.minimum(starts + cluster, n) - starts
    bounds_of = np.stack([np.minimum.reduceat(box[:, 0], starts), np.maximum.reduceat(box[:, 1], starts),
                          np.minimum.reduceat(box[:, 2], starts), np.maximum.reduceat(box[:, 3], starts)],
                         axis=1)
    top = sah_tree(bounds_of, depth - sub_levels)
    m_top = len(top.axis)
    total = m_top + 2 * (n - len(starts))
    bounds = np.empty((total, 4))
    axis = np.full(total, -1, dtype=np.int8)
    lower = np.full(total, -1, dtype=np.int64)
    upper = np.full(total, -1, dtype=np.int64)
    leaf = np.full(total, -1, dtype=np.int64)
    bounds[:m_top], axis[:m_top] = top.bounds, top.axis
    lower[:m_top], upper[:m_top] = top.lower, top.upper
    levels = [ids[top.axis[ids] >= 0] for ids in top.levels]
    # Split each cluster's run of boxes in halves, level by level (ids: the
    # runs' nodes; first, count: their runs)
    ids = np.flatnonzero(top.leaf >= 0)
    first, count = starts[top.leaf[ids]], counts[top.leaf[ids]]
    next_id = m_top
    below: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (parents, lower, upper) per level
    while len(ids):
        one = count == 1
        leaf[ids[one]] = first[one]
        bounds[ids[one]] = box[first[one]]
        ids, first, count = ids[~one], first[~one], count[~one]
        if not len(ids):
            break
        levels.append(ids)
        half = count // 2
        low = next_id + 2 * np.arange(len(ids))
        next_id += 2 * len(ids)
        below.append((ids, low, low + 1))
        ids = np.stack([low, low + 1], axis=1).ravel()
        first = np.stack([first, first + half], axis=1).ravel()
        count = np.stack([half, count - half], axis=1).ravel()
    assert next_id == total
    # Bounds bottom-up; each node's axis is the one its children's centres
    # differ most along, the child with the smaller centre there first
    for parents, low, high in reversed(below):
        lb, hb = bounds[low], bounds[high]
        bounds[parents] = np.stack([np.minimum(lb[:, 0], hb[:, 0]), np.maximum(lb[:, 1], hb[:, 1]),
                                    np.minimum(lb[:, 2], hb[:, 2]), np.maximum(lb[:, 3], hb[:, 3])], axis=1)
        gap_r = (hb[:, 0] + hb[:, 1]) - (lb[:, 0] + lb[:, 1])
        gap_z = (hb[:, 2] + hb[:, 3]) - (lb[:, 2] + lb[:, 3])
        along_z = np.abs(gap_z) > np.abs(gap_r)
        swap = np.where(along_z, gap_z, gap_r) < 0
        axis[parents] = along_z
        lower[parents] = np.where(swap, high, low)
        upper[parents] = np.where(swap, low, high)
    size = np.ones(total, dtype=np.int64)
    for ids in reversed(levels):
        size[ids] = 1 + size[lower[ids]] + size[upper[ids]]
    # (``levels``: the inner nodes, parents before children, as
    # :meth:`BoxTree.preorder` walks them)
    return BoxTree(bounds, axis, lower, upper, leaf, size, levels)


# ---------------------------------------------------------------------------
# Kernel data
# ---------------------------------------------------------------------------

def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised array whose memory starts on a 64-byte boundary
    (see :func:`_aligned`): big kernel data written into it directly is
    not copied again by :func:`opaque`."""
    dtype = np.dtype(dtype)
    nbytes = int(np.prod(shape)) * dtype.itemsize
    raw = np.empty(nbytes + 64, dtype=np.uint8)
    start = -raw.ctypes.data % 64
    return raw[start:start + nbytes].view(dtype).reshape(shape)


def _aligned(values: np.ndarray, dtype) -> np.ndarray:
    """A copy of ``values`` as ``dtype`` whose memory starts on a 64-byte
    boundary.

    Dr.Jit uses a numpy array's memory as it is (no copy), and turns a
    gather of adjacent values (a ``Vector4f`` from a Float buffer) into one
    packet load only when that memory is aligned: without this, the traced
    kernel (and its hash) would depend on where numpy happened to allocate
    the data."""
    values = np.asarray(values, dtype=dtype)
    if values.ctypes.data % 64 == 0 and values.flags.c_contiguous:
        return values
    out = aligned_empty(values.shape, values.dtype)
    out[...] = values
    return out


def after_t_with_ties(t: mi.Float, ties: mi.Bool) -> mi.Float:
    """The ``after_t`` to pass a lathe's ``next_crossing`` kernel (which
    returns its first crossing with ``t > after_t``, compared on the ``t``
    it returns) for the next crossing after another lathe's at ``t``:
    ``t`` itself, or where ``ties`` (the lathe comes after that one in the
    walk's order, eq. 31) the float just below a positive ``t``, so that a
    crossing at exactly ``t`` counts as after it."""
    bits = dr.reinterpret_array(mi.UInt32, t)
    below = dr.reinterpret_array(mi.Float, bits - 1)
    return dr.select(ties & (t > 0) & dr.isfinite(t), below, t)


def opaque(value, cls=None):
    """``cls(value)`` (default ``mi.Float``) marked opaque: its values are
    passed to kernels as parameters instead of being baked in as literals,
    so that a kernel traced once serves every profile (no recompilation on
    new data). Arrays are first copied to aligned memory (see
    :func:`_aligned`)."""
    cls = mi.Float if cls is None else cls
    if isinstance(value, np.ndarray) and value.ndim > 0:
        value = _aligned(value, np.uint32 if cls is mi.UInt32 else np.float32)
    result = cls(value)
    dr.make_opaque(result)
    return result


class LatheData:
    """Opaque Dr.Jit buffers of one lathe, for one kernel kind.

    Every kind has the attributes below; each adds its own (see
    ``PolylineData`` and ``BSplineData``). Keyword arguments become
    attributes.

    ``nodes``
        Float buffer of per-node records of the four BVH copies (layout
        chosen by the kind).
    ``links``
        UInt32 buffer: the link of an inner node (:func:`threaded_bvh`: its
        miss link; :func:`child_box_bvh`: its second child), or ``LEAF |
        index`` for a leaf.
    ``n_nodes``
        Opaque UInt32: nodes per copy.
    ``bound_r, bound_z_lo, bound_z_hi``
        Opaque Float scalars: the padded bounding cylinder that clips rays
        (unit frame).
    ``scale, inv_scale, z_shift``
        Opaque Float scalars of the unit frame (see :func:`unit_frame`):
        ``S``, ``1 / S`` and ``-z_c / S``; a local point ``p`` maps to
        ``(p_x / S, p_y / S, p_z / S - z_c / S)``.
    ``node_base``
        ``None`` for one lathe's own data. In a view of several profiles'
        concatenated data (kernels/top_level.py) the scalars above are
        per-lane arrays, and this UInt32 is where the profile's nodes start
        (its links and leaf indices are already global there).
    """

    node_base = None

    def __init__(self, **kwargs) -> None:
        for key, value in kwargs.items():
            setattr(self, key, value)


def unit_frame(who: str, r_max: float, z_min: float, z_max: float) -> tuple[float, float, dict]:
    """``(S, z_c, frame)`` of a profile with radii up to ``r_max`` and heights
    in ``[z_min, z_max]``: its size ``S = max(r_max, z_max - z_min)``, the
    centre ``z_c`` of its z range, and the opaque :class:`LatheData` fields
    ``scale``, ``inv_scale`` and ``z_shift`` of that frame. The kind divides
    its data by ``S`` after subtracting ``z_c``. A ValueError names ``who``
    when float32 cannot represent the profile's size."""
    size = float(max(r_max, z_max - z_min))
    tiny = float(np.finfo(np.float32).tiny)
    if not (np.isfinite(size) and 1e6 * tiny < size < 1e-6 / tiny):
        raise ValueError(f"{who}: the profile's size {size:g} is outside what float32 "
                         f"kernels can represent (about 1e-32 .. 1e32)")
    z_c = 0.5 * (z_min + z_max)
    frame = {"scale": opaque(size), "inv_scale": opaque(1.0 / size), "z_shift": opaque(-z_c / size)}
    return size, z_c, frame


def to_unit_frame(data: LatheData, p: mi.Point3f) -> mi.Point3f:
    """A local point in the unit frame of ``data`` (one multiply-add per
    component)."""
    s = data.inv_scale
    return mi.Point3f(p.x * s, p.y * s, dr.fma(p.z, s, data.z_shift))


# ---------------------------------------------------------------------------
# Ray set-up (Dr.Jit, traced)
# ---------------------------------------------------------------------------

def radial_interval(a_xy, b_xy, c_xy, cross, rmax):
    """Interval of ``s`` where ``r(s) <= rmax`` (empty: ``lo > hi``) for
    ``r(s)^2 = a s^2 + 2 b s + c`` and ``cross = o_x d_y - o_y d_x``.

    The discriminant ``b^2 - a (c - rmax^2) = a rmax^2 - cross^2`` is
    evaluated factored (no cancellation for far origins) and the roots in
    the stable form ``q = -(b + sign(b) sqrt(disc))``, ``s = q / a, c' / q``.
    """
    sa = dr.sqrt(a_xy)
    ac = dr.abs(cross)
    disc = (sa * rmax - ac) * (sa * rmax + ac)
    q = -(b_xy + dr.copysign(dr.sqrt(dr.maximum(disc, 0)), b_xy))
    s1 = q / a_xy
    s2 = (c_xy - rmax * rmax) / q
    lo = dr.minimum(s1, s2)
    hi = dr.maximum(s1, s2)
    # Rays parallel to the axis: inside for all s or never
    inside = c_xy <= rmax * rmax
    lo = dr.select(a_xy == 0, dr.select(inside, -dr.inf, dr.inf), lo)
    hi = dr.select(a_xy == 0, dr.select(inside, dr.inf, -dr.inf), hi)
    miss = (a_xy != 0) & (disc < 0)
    return dr.select(miss, dr.inf, lo), dr.select(miss, -dr.inf, hi)


class LatheRay:
    """Per-ray constants of one traversal, in the unit frame, origin moved
    into place.

    The local ray ``o + t d`` (any ``|d| > 0``) is mapped to the unit frame
    of ``data`` with a unit direction; ray parameters there are lengths in
    that frame, ``t = s_frame * t_scale``. The ray is then clipped against
    the padded bounding cylinder of ``data``; its origin is moved to the
    entry point ``s_frame = s_enter`` (see the module docstring) and from
    then on ``s = s_frame - s_enter`` is the ray parameter. Attributes:

    ``o, d``: moved origin and unit direction (unit frame); ``t_scale``;
    ``tmax``: ``tmax`` in the unit frame; ``active``: lanes with a finite
    origin and direction that meet the cylinder before ``tmax``;
    ``s_enter``; ``s_lo = -s_enter`` (hits need ``t > 0``), ``s_max =
    tmax - s_enter`` and ``s_hi`` (also before the cylinder exit); ``a, b,
    c``: ``r(s)^2 = a s^2 + 2 b s + c``; ``cross``: ``o_x d_y - o_y d_x``;
    ``inv_dz``: ``1 / d_z`` (nudged); ``first, end``: the node range of this
    ray's BVH copy.
    """

    def __init__(self, data: LatheData, o: mi.Point3f, d: mi.Vector3f,
                 tmax: mi.Float, active: mi.Bool) -> None:
        o, d, tmax, active = self._unit_frame(data, o, d, tmax, active)
        a_xy = dr.fma(d.x, d.x, d.y * d.y)
        # z slab of the bounding cylinder (d_z = 0 nudged to avoid 0 * inf;
        # |d| = 1 and the frame is unit sized, so the nudge is negligible)
        dz = dr.select(d.z == 0, 1e-30, d.z)
        inv_dz = dr.rcp(dz)
        zl = (data.bound_z_lo - o.z) * inv_dz
        zh = (data.bound_z_hi - o.z) * inv_dz
        # Radial interval of the (far) original origin: r(s) <= bound_r
        r_lo, r_hi = radial_interval(a_xy, dr.fma(o.x, d.x, o.y * d.y),
                                     dr.fma(o.x, o.x, o.y * o.y),
                                     dr.fma(o.x, d.y, -o.y * d.x), data.bound_r)
        lo = dr.maximum(dr.minimum(zl, zh), r_lo)
        hi = dr.minimum(dr.maximum(zl, zh), r_hi)

        # Move the origin to the cylinder entry
        s_enter = dr.maximum(lo, 0)
        self.active = active & (lo <= hi) & (hi > 0) & (s_enter < tmax)
        s_enter = dr.select(self.active, s_enter, 0)
        self.s_enter = s_enter
        self.o = mi.Point3f(dr.fma(d.x, s_enter, o.x),
                            dr.fma(d.y, s_enter, o.y),
                            dr.fma(d.z, s_enter, o.z))
        self.d = d
        self.tmax = tmax
        self.s_lo = -s_enter
        self.s_max = tmax - s_enter
        self.s_hi = dr.minimum(self.s_max, hi - s_enter)

        # The radial quadratic in the moved frame
        ox, oy = self.o.x, self.o.y
        self.a = a_xy
        self.b = dr.fma(ox, d.x, oy * d.y)
        self.c = dr.fma(ox, ox, oy * oy)
        self.cross = dr.fma(ox, d.y, -oy * d.x)
        self.inv_dz = inv_dz
        self.oz_inv_dz = self.o.z * inv_dz
        # The same quadratic as r(s)^2 = (sqrt(a) s - x_axis)^2 + r2_axis
        # (a sum of squares: no cancellation; see enter_child_box), r2_axis
        # the line's smallest r^2, reached at s_axis = x_axis / sqrt(a). A
        # ray parallel to the axis has r^2 = c, and its cylinder intervals
        # are (nearly) infinite: 1 / sqrt(a) is taken as 1e30.
        self.sqrt_a = dr.sqrt(a_xy)
        inv_sqrt_a = dr.select(a_xy > 0, dr.rcp(self.sqrt_a), 0)
        self.x_axis = -self.b * inv_sqrt_a
        self.r2_axis = dr.select(a_xy > 0, dr.square(self.cross * inv_sqrt_a), self.c)
        self.s_axis = self.x_axis * inv_sqrt_a
        self.inv_sqrt_a = dr.select(a_xy > 0, inv_sqrt_a, 1e30)
        # BVH copy (see threaded_bvh): lower child first when going up,
        # outer child first when moving towards the axis
        copy = dr.select(d.z >= 0, 0, 2) + dr.select(self.b <= 0, 0, 1)
        self.first = mi.UInt32(copy) * data.n_nodes
        if data.node_base is not None:
            self.first += data.node_base
        self.end = self.first + data.n_nodes

    def _unit_frame(self, data: LatheData, o, d, tmax, active):
        """The ray in the unit frame: ``(o, unit d, tmax, active)``; sets
        ``t_scale``. ``d`` is first divided by its largest component, so
        that ``|d|^2`` cannot over- or underflow."""
        big = dr.maximum(dr.maximum(dr.abs(d.x), dr.abs(d.y)), dr.abs(d.z))
        d = d * dr.rcp(big)
        norm = dr.norm(d)
        d = d * dr.rcp(norm)
        # Frame lengths per unit of t: |d| / S
        per_t = big * norm * data.inv_scale
        self.t_scale = dr.rcp(per_t)
        o = to_unit_frame(data, o)
        # A non-finite origin or direction never hits (and must not be
        # clipped into the cylinder by inf - inf arithmetic)
        finite = dr.isfinite(o.x + o.y + o.z) & dr.isfinite(per_t) & (per_t > 0)
        return o, d, tmax * per_t, mi.Bool(active) & finite

    def reaches(self, lo: mi.Float, hi: mi.Float, r2: mi.Float) -> mi.Bool:
        """Whether ``r(s)^2`` reaches ``r2`` somewhere on ``[lo, hi]``: it is
        convex, so its largest value there is at one of the ends. (Two
        comparisons rather than one of the larger value: that form is the
        faster one in the polyline kernel's LLVM code.)"""
        r2_lo = dr.fma(dr.fma(self.a, lo, 2 * self.b), lo, self.c)
        r2_hi = dr.fma(dr.fma(self.a, hi, 2 * self.b), hi, self.c)
        return (r2_lo >= r2) | (r2_hi >= r2)


# ---------------------------------------------------------------------------
# One traversal step (Dr.Jit, traced)
# ---------------------------------------------------------------------------

def box_rmin2(rmin: float) -> float:
    """The ``rmin2`` that :func:`enter_annular_box` takes for a box's inner
    radius: ``rmin^2``, or -1 for a box reaching the axis. On a ray through
    the axis, ``r(s)^2`` rounds to slightly below 0 there; a box that is
    thin in z (an annulus's) could then be skipped although it is hit."""
    return rmin * rmin if rmin > 0 else -1.0


def enter_annular_box(ray: LatheRay, zmin, zmax, r_lo, r_hi, rmin2, s_best):
    """Whether the ray meets the annular box ``[rmin, rmax] x [zmin, zmax]``
    at some ``s`` in ``(ray.s_lo, s_best)``.

    ``(r_lo, r_hi)`` is the kind's interval where ``r(s) <= rmax``; ``rmin2``
    is ``rmin^2``. The box is entered when the largest ``r(s)^2`` over the
    part of the ray within the slab and that interval reaches ``rmin^2``.
    """
    zl = (zmin - ray.o.z) * ray.inv_dz
    zh = (zmax - ray.o.z) * ray.inv_dz
    lo = dr.maximum(dr.maximum(dr.minimum(zl, zh), r_lo), ray.s_lo)
    hi = dr.minimum(dr.minimum(dr.maximum(zl, zh), r_hi), s_best)
    return (lo <= hi) & ray.reaches(lo, hi, rmin2)


def enter_child_box(ray: LatheRay, box: mi.Vector4f, s_best: mi.Float) -> tuple[mi.Bool, mi.Float]:
    """Whether the ray meets the annular box ``box = (rmax^2, rmin2, zmin,
    zmax)`` (``rmin2`` as :func:`box_rmin2`) at some ``s`` in ``(ray.s_lo,
    s_best)``, and where it enters the box's slab and cylinder ``r <= rmax``
    (a lower bound of where it enters the box).

    With ``r(s)^2 = (sqrt(a) s - x_axis)^2 + r2_axis`` the cylinder's
    interval is ``s_axis -+ sqrt(rmax^2 - r2_axis) / sqrt(a)`` (no
    quadratic to solve, no cancellation: ``r2_axis`` is the line's own
    smallest ``r^2``); on its part in the slab the convex ``r(s)^2`` is
    largest at an end, which must reach ``rmin^2``."""
    zl = dr.fma(box.z, ray.inv_dz, -ray.oz_inv_dz)
    zh = dr.fma(box.w, ray.inv_dz, -ray.oz_inv_dz)
    half = dr.sqrt(dr.maximum(box.x - ray.r2_axis, 0)) * ray.inv_sqrt_a
    lo = dr.maximum(dr.maximum(dr.minimum(zl, zh), ray.s_lo), ray.s_axis - half)
    hi = dr.minimum(dr.minimum(dr.maximum(zl, zh), s_best), ray.s_axis + half)
    x_lo = dr.fma(ray.sqrt_a, lo, -ray.x_axis)
    x_hi = dr.fma(ray.sqrt_a, hi, -ray.x_axis)
    below_max = ray.r2_axis <= box.x
    above_min = (dr.fma(x_lo, x_lo, ray.r2_axis) >= box.y) | (dr.fma(x_hi, x_hi, ray.r2_axis) >= box.y)
    return (lo <= hi) & below_max & above_min, lo


def bvh_link(links: mi.UInt32, node: mi.UInt32, active: mi.Bool):
    """``(link, is_leaf, index)`` of a node of a threaded BVH: its link
    word, whether it is a leaf and, for a leaf, the leaf's index."""
    link = dr.gather(mi.UInt32, links, node, active)
    return link, (link & LEAF) != 0, link & (LEAF - 1)


def bvh_next(node: mi.UInt32, link: mi.UInt32, is_leaf: mi.Bool, entered: mi.Bool) -> mi.UInt32:
    """The next node in pre-order: the first child of an entered inner node
    (or the node after a leaf), else the miss link past the subtree."""
    return dr.select(is_leaf | entered, node + 1, link)
