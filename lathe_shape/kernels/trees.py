"""The kernels' trees, built with numpy: BVHs over annular boxes in the
(r, z) plane.

* :func:`sah_tree` (surface area heuristic) and :func:`clustered_tree`
  (big profiles: clusters of consecutive boxes) build a :class:`BoxTree`
  level by level over whole arrays; :func:`_sah_split` is the recursive
  reference they must equal;
* :func:`threaded_bvh`: the stackless tree, stored four times with different
  child orders (B-splines);
* :func:`child_box_bvh` and :func:`child_box_arrays`: the same tree for a
  traversal with a stack, each inner node holding its children's boxes
  (polylines).

No Dr.Jit here: :mod:`.common` turns the records into the kernels' opaque
buffers (and re-exports these names).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = [
    "BVH_DEPTH",
    "BoxTree",
    "CLUSTERED_ABOVE",
    "CLUSTER_SIZE",
    "ChildBoxRows",
    "LEAF",
    "child_box_arrays",
    "child_box_bvh",
    "clustered_tree",
    "sah_tree",
    "threaded_bvh",
]

#: Flag bit in a threaded-BVH link word marking a leaf (low bits: its index).
LEAF = 0x80000000


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


def child_box_arrays(box: np.ndarray, clustered_above: int | None = None) -> ChildBoxRows:
    """The rows of :func:`child_box_bvh` (same tree, same order) as arrays,
    without a callback per node. Above ``clustered_above`` boxes (default
    :data:`CLUSTERED_ABOVE`) the tree is :func:`clustered_tree`'s."""
    if clustered_above is None:
        clustered_above = CLUSTERED_ABOVE
    if len(box) > clustered_above:
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
