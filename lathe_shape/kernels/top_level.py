"""Many lathes of one kind in one traversal: the top level of a two-level
hierarchy.

A scene of many lathes is intersected by one kernel whose size does not
depend on how many lathes there are:

* Bottom level: the kernel data of every distinct profile of a kind
  (kernels/polyline.py or kernels/bspline.py) concatenated into one set of
  buffers (:class:`ProfileTable`): the BVH nodes, their links and the
  segment (and leaf) buffers one after the other, the links rewritten to
  global indices, and the per-profile scalars of :class:`LatheData` (node
  count, bounding cylinder, unit frame) as arrays indexed by profile.
  Lathes with the same profile share its data (instancing): a shelf of a
  thousand identical glasses holds one profile.
* Top level (:class:`LatheSet`): the lathes' world-to-local transforms as
  arrays and a BVH over their world-space bounding boxes (built in numpy,
  rebuilt when a lathe moves: opaque arrays of the same layout, so no
  recompilation), stored stackless (pre-order with miss links) eight times,
  once per octant of ray directions, so that a ray visits the nearer child
  of every split first.

A ray walks the top-level tree to the next lathe whose box it enters before
its nearest hit so far, maps itself into that lathe's local frame (the
local ray keeps the world ray's parameter ``t``) and runs the kind's own
kernel on a *view* of the profile table: a :class:`LatheData` whose buffers
are the concatenated ones and whose scalars are gathered per lane
(:meth:`ProfileTable.view`). The kernels need no change for this beyond
the node base of :class:`~lathe_shape.kernels.common.LatheRay`; a hit
reports the lathe (``LatheSet`` index), the segment local to its profile
and ``u``.

No Mitsuba scene objects here (the plugin's plumbing is in
plugin/scene_geometry.py); the functions are traceable inside an outer
symbolic loop.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from . import bspline, polyline
from .common import (
    LEAF,
    NO_CROSSING,
    LatheData,
    LatheGeometry,
    LatheHit,
    VariantStruct,
    after_t_with_ties,
    bvh_link,
    bvh_next,
    opaque,
)

#: The ``lathe`` of a :class:`CrossingPlace` that is no lathe's crossing.
NO_LATHE = 0xFFFFFFFF

__all__ = ["BSPLINE_LAYOUT", "LAYOUTS", "NO_LATHE", "POLYLINE_LAYOUT",
           "CrossingPlace", "KindLayout", "LatheSet", "ProfileTable", "SetHit",
           "octant_bvh"]


# ---------------------------------------------------------------------------
# Bottom level: the kinds' buffers, concatenated
# ---------------------------------------------------------------------------

def _polyline_geometry(view: LatheData, p, seg, local_seg, u, smooth) -> LatheGeometry:
    """Polyline geometry with per-lane smooth shading (flat: the geometric
    normal, as ``polyline_geometry(..., smooth=False)`` gives)."""
    geo = polyline.polyline_geometry(view, p, seg, u, True)
    geo.sh_n = dr.select(smooth, geo.sh_n, geo.n)
    return geo


def _bspline_geometry(view: LatheData, p, seg, local_seg, u, smooth) -> LatheGeometry:
    """B-spline geometry; ``uv.y = (segment + u) / segments`` counts the
    profile's own segments (the table's index ``seg`` is global)."""
    geo = bspline.bspline_geometry(view, p, seg, u)
    geo.uv = mi.Point2f(geo.uv.x, (mi.Float(local_seg) + u) / mi.Float(view.n_seg))
    return geo


@dataclass(frozen=True)
class KindLayout:
    """How the :class:`LatheData` of one kind is laid out and used.

    ``node_floats``: floats per BVH node in ``nodes``. ``seg_buffers`` and
    ``leaf_buffers``: the Float buffers indexed by profile segment and by
    BVH leaf, with their floats per entry. ``leaves_are_segments``: a leaf
    index in ``links`` is a segment index (polylines), else a leaf of
    ``leaf_buffers`` whose column ``leaf_seg_column`` holds its segment
    (B-splines). ``scalars``: the per-profile opaque scalars.
    ``intersect``, ``occluded``: the kernels; ``next_crossing``: the
    kernel that walks a ray through its crossings without offsets
    (``next_crossing_polyline``'s contract);
    ``geometry(view, p, seg, local_seg, u, smooth)``: the local
    differential geometry."""

    node_floats: int
    seg_buffers: dict
    leaf_buffers: dict
    leaves_are_segments: bool
    leaf_seg_column: int | None
    scalars: tuple
    intersect: Callable
    occluded: Callable
    geometry: Callable
    next_crossing: Callable


_FRAME = ("n_nodes", "bound_r", "bound_z_lo", "bound_z_hi", "scale", "inv_scale", "z_shift")

#: The layout of the polyline kernel (paper Method 1).
POLYLINE_LAYOUT = KindLayout(8, {"seg_geo": 4, "seg_sh": 4, "seg_arc": 2, "seg_side": 8}, {}, True, None,
                             _FRAME + ("tol",), polyline.intersect_polyline, polyline.occluded_polyline,
                             _polyline_geometry, polyline.next_crossing_polyline)

#: The layout of the B-spline kernel (paper Method 2), which every cubic
#: profile kind runs. A leaf record ends with (t0, h, segment, r_squared):
#: see kernels/bspline.py. The per-profile r_squared_flag lets one kernel
#: serve R and R^2 (sor) profiles.
BSPLINE_LAYOUT = KindLayout(4, {"seg": bspline.STRIDE}, {"leaf": bspline.LEAF_STRIDE}, False,
                            bspline.LEAF_STRIDE - 2, _FRAME + ("n_seg", "r_squared_flag"),
                            bspline.intersect_bspline, bspline.occluded_bspline, _bspline_geometry,
                            bspline.next_crossing_bspline)

#: The kernels' layouts by kernel name. Which profile kind runs which kernel
#: is the profile kinds' registry's business (``lathe_shape.surfaces.KINDS``:
#: each kind's record carries its layout).
LAYOUTS = {"polyline": POLYLINE_LAYOUT, "bspline": BSPLINE_LAYOUT}


def _host(value) -> np.ndarray:
    return np.asarray(value.numpy())


class ProfileTable:
    """The kernel data of several profiles of one kernel layout (``layout``:
    a :class:`KindLayout`, or its name in :data:`LAYOUTS`), concatenated.

    ``buffers``: the concatenated node, link, segment and leaf buffers;
    ``bases``: per profile, opaque UInt32 arrays ``node_base`` and
    ``seg_base`` (where its nodes and segments start); ``scalars``: per
    profile, the opaque arrays of the kind's scalars; ``smooth``: per
    profile, whether shading normals are interpolated; ``boxes``: (n, 6)
    float64 local bounding boxes (the padded bounding cylinders)."""

    def __init__(self, layout: KindLayout | str, datas: Sequence[LatheData], smooth: Sequence[bool]) -> None:
        layout = self.layout = LAYOUTS[layout] if isinstance(layout, str) else layout
        count = {"node": [len(_host(d.links)) // 4 for d in datas]}
        for unit, buffers in (("seg", layout.seg_buffers), ("leaf", layout.leaf_buffers)):
            name, floats = next(iter(buffers.items()), (None, 1))
            count[unit] = [len(_host(getattr(d, name))) // floats if name else 0 for d in datas]
        base = {unit: np.concatenate([[0], np.cumsum(n)[:-1]]).astype(np.int64) for unit, n in count.items()}
        links = []
        leaf_unit = "seg" if layout.leaves_are_segments else "leaf"
        for k, d in enumerate(datas):
            link = _host(d.links).astype(np.int64)
            leaf = (link & LEAF) != 0
            # A copy's nodes are numbered from 0 per profile: offset both kinds
            # of link, 4 copies of count["node"] nodes each.
            link = np.where(leaf, LEAF | ((link & (LEAF - 1)) + base[leaf_unit][k]),
                            link + 4 * base["node"][k])
            links.append(link)
        self.buffers = {"links": opaque(np.concatenate(links).astype(np.uint32), mi.UInt32),
                        "nodes": opaque(np.concatenate([_host(d.nodes) for d in datas]))}
        for name in (*layout.seg_buffers, *layout.leaf_buffers):
            parts = [_host(getattr(d, name)) for d in datas]
            if name in layout.leaf_buffers and layout.leaf_seg_column is not None:
                floats = layout.leaf_buffers[name]
                parts = [_offset_column(p, floats, layout.leaf_seg_column, base["seg"][k])
                         for k, p in enumerate(parts)]
            self.buffers[name] = opaque(np.concatenate(parts))
        self.bases = {"node_base": opaque((4 * base["node"]).astype(np.uint32), mi.UInt32),
                      "seg_base": opaque(base["seg"].astype(np.uint32), mi.UInt32)}
        self.scalars = {name: _profile_array([getattr(d, name) for d in datas]) for name in layout.scalars}
        self.smooth = opaque(np.asarray(smooth, dtype=np.uint32), mi.UInt32)
        self.boxes = np.array([_local_box(d) for d in datas])
        self.count = len(datas)

    def view(self, profile: mi.UInt32, active: mi.Bool) -> LatheData:
        """The data of profile ``profile`` (per lane), as the kernels take it:
        the concatenated buffers and the profile's scalars and node base."""
        fields = dict(self.buffers)
        for name, values in self.scalars.items():
            fields[name] = dr.gather(type(values), values, profile, active)
        fields["node_base"] = dr.gather(mi.UInt32, self.bases["node_base"], profile, active)
        return LatheData(**fields)


def _offset_column(values: np.ndarray, floats: int, column: int, offset: int) -> np.ndarray:
    """A flat record buffer with ``offset`` added to one column (exact in
    float32 below 2^24)."""
    records = values.reshape(-1, floats).copy()
    records[:, column] += offset
    return records.ravel()


def _profile_array(values: list):
    """The per-profile array of one opaque scalar of :class:`LatheData`."""
    cls = type(values[0])
    return opaque(np.concatenate([_host(v) for v in values]).astype(_host(values[0]).dtype), cls)


def _local_box(data: LatheData) -> np.ndarray:
    """The padded bounding cylinder of ``data`` as a local-frame box
    ``(x0, y0, z0, x1, y1, z1)`` (float64)."""
    size = float(_host(data.scale)[0])
    shift = float(_host(data.z_shift)[0])
    r = float(_host(data.bound_r)[0]) * size
    z_lo = (float(_host(data.bound_z_lo)[0]) - shift) * size
    z_hi = (float(_host(data.bound_z_hi)[0]) - shift) * size
    return np.array([-r, -r, z_lo, r, r, z_hi])


# ---------------------------------------------------------------------------
# Top level: a BVH over world boxes, one stackless copy per ray octant
# ---------------------------------------------------------------------------

def _half_area(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Half the surface area of boxes ``(lo, hi)`` (rows): the chance that
    a random ray meets one is proportional to it."""
    e = np.maximum(hi - lo, 0.0)
    return e[..., 0] * e[..., 1] + e[..., 1] * e[..., 2] + e[..., 2] * e[..., 0]


def _sah_tree(lo: np.ndarray, hi: np.ndarray, idx: np.ndarray):
    """Tree over the boxes ``idx``: ``(index, bounds)`` for a leaf, else
    ``(axis, bounds, lower, upper)``. The split, along any axis between
    boxes sorted by centre, minimises the surface area heuristic (each
    side's area times its box count), so that lathes far apart (say a
    shelf and a row elsewhere) part near the root."""
    bounds = np.concatenate([lo[idx].min(axis=0), hi[idx].max(axis=0)])
    if len(idx) == 1:
        return int(idx[0]), bounds
    count = np.arange(1, len(idx))
    best = None
    for axis in range(3):
        order = idx[np.argsort(lo[idx, axis] + hi[idx, axis], kind="stable")]
        a, b = lo[order], hi[order]
        left = _half_area(np.minimum.accumulate(a)[:-1], np.maximum.accumulate(b)[:-1])
        right = _half_area(np.minimum.accumulate(a[::-1])[::-1][1:], np.maximum.accumulate(b[::-1])[::-1][1:])
        cost = left * count + right * count[::-1]
        k = int(np.argmin(cost))
        if best is None or cost[k] < best[0]:
            best = (cost[k], axis, order, k + 1)
    _, axis, order, half = best
    return axis, bounds, _sah_tree(lo, hi, order[:half]), _sah_tree(lo, hi, order[half:])


def octant_bvh(boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """A stackless BVH over the world boxes ``boxes`` ((n, 6) rows ``(x0, y0,
    z0, x1, y1, z1)``), stored once per octant of ray directions.

    Returns ``(records, links, n_nodes)``: per node the float32 box ``(x0,
    y0, z0, 0, x1, y1, z1, 0)`` (rounded outward); its link: the miss link
    (global index of the node after its subtree) of an inner node, ``LEAF |
    box index`` of a leaf; ``n_nodes`` per copy. Copy ``c`` visits the upper
    child of a split along axis ``k`` first when bit ``k`` of ``c`` is set
    (the ray goes towards -k)."""
    boxes = np.asarray(boxes, dtype=np.float64)
    tree = _sah_tree(boxes[:, :3], boxes[:, 3:], np.arange(len(boxes)))
    records: list = []
    links: list = []
    for copy in range(8):
        stack = [(tree, None)]
        while stack:
            node, owner = stack.pop()
            if owner is not None:        # the end of an inner node's subtree
                links[owner] = len(records)
                continue
            records.append(node[1])
            if len(node) == 2:
                links.append(LEAF | node[0])
                continue
            axis, _, lower, upper = node
            first, second = (upper, lower) if copy >> axis & 1 else (lower, upper)
            links.append(0)
            stack += [(None, len(records) - 1), (second, None), (first, None)]
    n_nodes = 2 * len(boxes) - 1
    box = np.array(records)
    lo = np.nextafter(box[:, :3].astype(np.float32), np.float32(-np.inf))
    hi = np.nextafter(box[:, 3:].astype(np.float32), np.float32(np.inf))
    zero = np.zeros((len(box), 1), np.float32)
    return np.concatenate([lo, zero, hi, zero], axis=1), np.asarray(links, dtype=np.uint32), n_nodes


def world_boxes(local: np.ndarray, to_world: np.ndarray) -> np.ndarray:
    """World boxes ``(n, 6)`` of local boxes ``(n, 6)`` under ``(n, 4, 4)``
    transforms: the 8 corners mapped, padded by 1e-5 of their extent (float32
    rounding of the traversal)."""
    corners = np.stack([np.stack([local[:, 3 * (k >> 2 & 1)], local[:, 1 + 3 * (k >> 1 & 1)],
                                  local[:, 2 + 3 * (k & 1)]], axis=1) for k in range(8)], axis=1)
    world = np.einsum("nij,nkj->nki", to_world[:, :3, :3], corners) + to_world[:, None, :3, 3]
    lo, hi = world.min(axis=1), world.max(axis=1)
    pad = 1e-5 * np.max(hi - lo, axis=1, keepdims=True)
    return np.concatenate([lo - pad, hi + pad], axis=1)


# ---------------------------------------------------------------------------
# The lathes of one kind (Dr.Jit, traced)
# ---------------------------------------------------------------------------

def _rows(buffer: mi.Float, lathe: mi.UInt32, active: mi.Bool) -> list:
    """The three rows of lathe ``lathe``'s 3x4 affine matrix in ``buffer``."""
    return [dr.gather(mi.Vector4f, buffer, lathe * 3 + k, active) for k in range(3)]


def _point(rows: list, p) -> mi.Point3f:
    return mi.Point3f(*(dr.fma(r.x, p.x, dr.fma(r.y, p.y, dr.fma(r.z, p.z, r.w))) for r in rows))


def _vector(rows: list, v) -> mi.Vector3f:
    return mi.Vector3f(*(dr.fma(r.x, v.x, dr.fma(r.y, v.y, r.z * v.z)) for r in rows))


def _normal(inverse_rows: list, n) -> mi.Vector3f:
    """A normal mapped by the inverse transpose of the matrix whose inverse
    has the rows ``inverse_rows``, normalised."""
    r0, r1, r2 = inverse_rows
    return dr.normalize(mi.Vector3f(*(dr.fma(r0[k], n.x, dr.fma(r1[k], n.y, r2[k] * n.z)) for k in range(3))))


class LatheSet:
    """The lathes of one kind: their profiles (a :class:`ProfileTable`),
    each lathe's profile and transform, and the top-level BVH over their
    world boxes.

    ``profile_of[i]`` is lathe ``i``'s profile in ``table``; ``to_world``
    the ``(n, 4, 4)`` local-to-world matrices (float64; see
    :meth:`set_transforms`)."""

    def __init__(self, table: ProfileTable, profile_of: Sequence[int], to_world: np.ndarray) -> None:
        self.table = table
        self.layout = table.layout
        self._profile_of = np.asarray(profile_of, dtype=np.int64)
        self.profile_of = opaque(self._profile_of.astype(np.uint32), mi.UInt32)
        self.set_transforms(to_world)

    def set_transforms(self, to_world: np.ndarray) -> None:
        """New local-to-world matrices for all lathes: the transforms and the
        top-level BVH are rebuilt (numpy) as opaque arrays of the same
        layout, so kernels traced before serve on (no recompilation)."""
        to_world = np.asarray(to_world, dtype=np.float64).reshape(-1, 4, 4)
        to_local = np.linalg.inv(to_world)
        self.to_world = opaque(to_world[:, :3, :].astype(np.float32).ravel())
        self.to_local = opaque(to_local[:, :3, :].astype(np.float32).ravel())
        boxes = world_boxes(self.table.boxes[self._profile_of], to_world)
        records, links, n_nodes = octant_bvh(boxes)
        self.nodes = opaque(records.ravel())
        self.links = opaque(links, mi.UInt32)
        self.n_nodes = opaque(n_nodes, mi.UInt32)
        #: World bounds of all lathes, ``(6,)`` float64.
        self.bounds = np.concatenate([boxes[:, :3].min(axis=0), boxes[:, 3:].max(axis=0)])

    def intersect(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> SetHit:
        """Nearest hit with ``0 < t < tmax`` of the world rays ``o + t d``
        with any lathe of the set."""
        return self._trace(o, d, mi.Float(tmax), mi.Bool(active), False)

    def next_crossing(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
                      after: CrossingPlace, ties_from: mi.UInt32 | None = None
                      ) -> tuple[SetHit, CrossingPlace]:
        """The next crossing of the world rays ``o + t d`` (``0 < t <
        tmax``) with any lathe of the set after ``after``, the place that a
        previous call with the same ``o``, ``d`` returned (or a place
        without lathe: the first crossing after ``after.t``); and this
        crossing's place. Crossings are ordered by ``t``, then lathe, then
        within a lathe by its kernel's key (eq. 31): walking a ray this way
        finds each crossing once (see ``next_crossing_polyline``), also
        where two lathes' walls coincide. ``ties_from`` (per lane; default:
        past the last lathe): the first lathe of the set that comes after
        ``after``'s lathe when that is no lathe of this set (another set's,
        or a single lathe's, see ``ExactSceneGeometry``): from it on, a
        crossing at exactly ``after.t`` is after ``after``."""
        if ties_from is None:
            ties_from = dr.full(mi.UInt32, NO_LATHE, dr.width(tmax))
        return self._trace(o, d, mi.Float(tmax), mi.Bool(active), False, after, ties_from)

    def occluded(self, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool) -> mi.Bool:
        """Whether the world rays hit a lathe of the set at some ``0 < t <
        tmax`` (stops at the first hit found)."""
        return self._trace(o, d, mi.Float(tmax), mi.Bool(active), True).valid

    def _visit(self, node, o, inv_d, t_min, t_max, active):
        """One step of the top-level walk: ``(candidate, next node)``, a
        candidate being a leaf (lathe) whose box the ray enters within
        ``[t_min, t_max]``."""
        lo = dr.gather(mi.Vector4f, self.nodes, node * 2, active)
        hi = dr.gather(mi.Vector4f, self.nodes, node * 2 + 1, active)
        link, is_leaf, _ = bvh_link(self.links, node, active)
        near, far = mi.Float(t_min), mi.Float(t_max)
        for k in range(3):
            t0 = (lo[k] - o[k]) * inv_d[k]
            t1 = (hi[k] - o[k]) * inv_d[k]
            near = dr.maximum(near, dr.minimum(t0, t1))
            far = dr.minimum(far, dr.maximum(t0, t1))
        # Slack for the rounding of the slab distances
        entered = active & (near <= far * (1.0 + 1e-6))
        cand = entered & is_leaf
        return cand, dr.select(cand, node, bvh_next(node, link, is_leaf, entered))

    def _lathe_hit(self, lathe, o, d, t_max, active, shadow: bool,
                   after: CrossingPlace | None, ties_from=None) -> tuple[LatheHit, CrossingPlace | None]:
        """The kind's kernel on lathe ``lathe`` (per lane), the ray mapped to
        its local frame (same ``t``); walking (``after`` given), also the
        crossing's place: the lathe's first crossing after ``after`` in the
        walk's order (eq. 31; ``ties_from`` as in :meth:`next_crossing`)."""
        rows = _rows(self.to_local, lathe, active)
        o_local, d_local = _point(rows, o), _vector(rows, d)
        view = self.table.view(dr.gather(mi.UInt32, self.profile_of, lathe, active), active)
        if shadow:
            found = self.layout.occluded(view, o_local, d_local, t_max, active)
            return LatheHit(t=mi.Float(0.0), valid=found), None
        if after is None:
            return self.layout.intersect(view, o_local, d_local, t_max, active), None
        # The lathe crossed last continues after that crossing (its kernel's
        # key), the others after its t, a later lathe also at it (eq. 31)
        same = after.lathe == lathe
        later = dr.select(after.lathe == NO_LATHE, lathe >= ties_from, lathe > after.lathe)
        hit, s, key = self.layout.next_crossing(
            view, o_local, d_local, t_max, active, dr.select(same, after.s, 0.0),
            dr.select(same, after.key, NO_CROSSING), after_t_with_ties(after.t, later))
        return hit, CrossingPlace(lathe, s, key, hit.t)

    @dr.syntax
    def _trace(self, o, d, tmax, active, shadow: bool, after: CrossingPlace | None = None,
               ties_from: mi.UInt32 | None = None):
        # Slab tests: a zero direction component nudged (no 0 * inf)
        big = dr.maximum(dr.maximum(dr.abs(d.x), dr.abs(d.y)), dr.abs(d.z))
        tiny = big * 1e-20
        inv_d = [dr.rcp(dr.select(dr.abs(d[k]) < tiny, dr.copysign(tiny, d[k]), d[k])) for k in range(3)]
        copy = dr.select(d.x < 0, 1, 0) + dr.select(d.y < 0, 2, 0) + dr.select(d.z < 0, 4, 0)
        node = mi.UInt32(copy) * self.n_nodes  # current node of this ray's copy
        end = node + self.n_nodes              # one past the copy's last node
        best = LatheHit(t=mi.Float(tmax))      # nearest hit so far (t: its bound)
        lathe = mi.UInt32(0)                   # its lathe
        # ... and its crossing's place (walks only)
        place = None if after is None else dr.zeros(CrossingPlace, dr.width(tmax))
        cand = mi.Bool(False)                  # node is a lathe to intersect
        active = active & (tmax > 0)           # lanes still walking
        # A walk goes on from its last crossing: lathes wholly behind it
        # need no visit (slack for the rounding of the slab distances)
        t_min = 0.0 if after is None else after.t * (1.0 - 1e-6)
        while active & (node < end) & ~(best.valid & shadow):
            cand = mi.Bool(False)
            while active & (node < end) & ~cand:
                cand, node = self._visit(node, o, inv_d, t_min, best.t, active & (node < end))
            index = bvh_link(self.links, node, cand)[2]
            # (a walk asks a little past the best: at equal t the smaller
            # lathe index is the nearer, eq. 31)
            reach = best.t
            if dr.hint(after is not None, mode="scalar"):
                reach = dr.select(best.valid, best.t * (1.0 + 1e-6), best.t)
            hit, hit_place = self._lathe_hit(index, o, d, reach, cand, shadow, after, ties_from)
            if dr.hint(after is not None, mode="scalar"):
                tie = (hit.t == best.t) & best.valid & (index < lathe)
                take = cand & hit.valid & ((hit.t < best.t) | tie)
            else:
                take = cand & hit.valid & (hit.t <= best.t)
            best = dr.select(take, hit, best)
            lathe = dr.select(take, index, lathe)
            if dr.hint(after is not None, mode="scalar"):
                place = dr.select(take, hit_place, place)
            node = dr.select(cand, node + 1, node)
        best.t = dr.select(best.valid, best.t, dr.inf)
        return SetHit(best, lathe) if after is None else (SetHit(best, lathe), place)

    def geometry(self, hit: SetHit, o: mi.Point3f, d: mi.Vector3f) -> tuple[LatheGeometry, mi.UInt32]:
        """World-space differential geometry at ``hit`` of the world rays
        ``o + t d`` (normals by the inverse transpose of the lathe's
        transform) and the segment index within the hit lathe's profile.
        Misses are evaluated at the local origin (finite fields)."""
        valid = hit.valid
        # Unmasked gathers: a miss reads lathe 0's data (its indices are 0),
        # not zeros, which would make its normals NaN.
        every = mi.Bool(True)
        profile = dr.gather(mi.UInt32, self.profile_of, hit.lathe, every)
        to_local = _rows(self.to_local, hit.lathe, every)
        to_world = _rows(self.to_world, hit.lathe, every)
        t = dr.select(valid, hit.t, 0.0)
        p = dr.select(valid, _point(to_local, o) + t * _vector(to_local, d), 0.0)
        table = self.table
        local_seg = hit.seg - dr.gather(mi.UInt32, table.bases["seg_base"], profile, every)
        smooth = dr.gather(mi.UInt32, table.smooth, profile, every) != 0
        geo = self.layout.geometry(table.view(profile, every), p, hit.seg, local_seg, hit.u, smooth)
        world = LatheGeometry(n=_normal(to_local, geo.n), sh_n=_normal(to_local, geo.sh_n), uv=geo.uv,
                              dp_du=_vector(to_world, geo.dp_du), dp_dv=_vector(to_world, geo.dp_dv))
        return world, local_seg


class CrossingPlace(metaclass=VariantStruct):
    """Where a walk along a line stands: the last crossing's ``lathe`` (a
    :class:`LatheSet` index; :data:`NO_LATHE` for none), its place ``(s,
    key)`` in that lathe's kernel and its ray parameter ``t`` (units of the
    line's direction). A walk continues after it."""

    _FIELDS = {"lathe": "UInt32", "s": "Float", "key": "UInt32", "t": "Float"}

    def __init__(self, lathe=None, s=None, key=None, t=None) -> None:
        self.lathe = mi.UInt32(NO_LATHE) if lathe is None else lathe
        self.s = mi.Float(0.0) if s is None else s
        self.key = mi.UInt32(NO_CROSSING) if key is None else key
        self.t = mi.Float(0.0) if t is None else t


class SetHit(LatheHit):
    """A :class:`LatheHit` of a :class:`LatheSet`, plus ``lathe``: the index
    of the hit lathe in the set (``seg`` is the table's global segment)."""

    _FIELDS = {**LatheHit._FIELDS, "lathe": "UInt32"}

    def __init__(self, hit: LatheHit | None = None, lathe=None) -> None:
        hit = LatheHit() if hit is None else hit
        super().__init__(hit.t, hit.seg, hit.u, hit.valid)
        self.lathe = mi.UInt32(0) if lathe is None else lathe
