"""Ray intersection kernel for a polyline profile revolved about the local z axis.

All functions work in the lathe's *local* frame: the axis of revolution is the
local +z axis and a profile point ``(r, z)`` lies at distance ``r >= 0`` from
it. The profile is a list of segments ``(r0, z0) -> (r1, z1)`` oriented
clockwise in the (r right, z up) plane, so that the solid's interior is on the
right of every segment and the outward normal is the left-hand normal
``(-(z1 - z0), r1 - r0) / L`` (docs/method.md, eqs. 8-9).

Every segment is handled through one formula. Writing its supporting line as
``n_r r + n_z z = c`` (``(n_r, n_z)`` the unit outward normal), the swept
surface is ``n_r sqrt(x^2 + y^2) = c - n_z z``. Squaring gives

    n_r^2 (x^2 + y^2) = (c - n_z z)^2,

which is the paper's cone frustum ``x^2 + y^2 = (A z + B)^2`` (eq. 1) scaled by
``n_r^2`` when ``z0 != z1``, and degenerates to the plane of the annulus
``z = z0`` (eqs. 6-7, a double root) when ``n_r = 0``. Substituting the ray
gives one quadratic (eq. 1 with eq. 3) for frusta, cylinders and annuli alike.

The ray set-up and the BVH over annular boxes in the (r, z) plane are those
of every lathe kernel (kernels/common.py); this module supplies the segment
(leaf) test, the local geometry and the traversal: each inner node holds
its two children's boxes (``child_box_bvh``), tested without solving a
quadratic (``enter_child_box``); a ray visits the child it enters first and
keeps the other on a small per-lane stack, dropped once the ray's best hit
lies before it. Only leaves solve the segment's quadratic.

Float32 precision. Beyond moving the origin to the bounding cylinder (see
kernels/common.py), three things keep the quadratic accurate: its roots are
taken in the stable form ``q = -(b + sign(b) sqrt(disc))``, ``s = q / a,
c / q``, which avoids subtracting two nearly equal numbers; the discriminant
and the constant term are evaluated as products of differences
(``(u - v)(u + v)``) rather than as differences of squares, which would
cancel for rays that graze a segment or start near it; and joints are
half-open, decided once for both segments that meet there.

Joints. A ray aimed at a joint between two segments may, after float32
rounding, land just outside both, or just inside both. Each segment
therefore first fixes the parity of its crossings: odd exactly when its two
end points lie on different sides of the ray's surface of revolution (the
hyperboloid swept by the ray about the axis), a test evaluated bit for bit
alike by both segments of a joint, so that the parities of all segments add
up to an even number of crossings for every line: a ray that enters leaves.
The roots only say where those crossings are: an odd segment reports the one
root nearest to it, an even one both roots (when both lie on it within a
small tolerance) or none; an odd segment's root that float32 puts off the
segment (a ray nearly along its cone) is moved back to the segment's
heights. Where float32 cannot tell a joint's side, the side of the joint
moved slightly into the solid decides, so that a ray grazing a corner
reports no crossing there rather than two coincident ones. Every segment
whose cone the line meets evaluates the sides (a few multiply-adds; the
moved joints only in packets with a lane that needs them).

Walking a ray through its crossings. Restarting a ray past a hit (Mitsuba's
``spawn_ray`` offsets the origin along the normal) makes a new line and can
skip a second crossing closer than the offset, at a corner.
:func:`next_crossing_polyline` instead keeps the ray's origin and asks for
the crossing after the one just taken, ordered by ray parameter, then
segment and root: each crossing of the line is found exactly once.

The functions need an active JIT Mitsuba variant (``llvm_*`` or ``cuda_*``)
when called; importing the module needs none.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..memory import available_memory, format_bytes
from ..profiles.polyline import Profile
from .common import (
    BVH_DEPTH,
    NO_CROSSING,
    LatheData,
    LatheGeometry,
    LatheHit,
    LatheRay,
    aligned_empty,
    bvh_link,
    child_box_arrays,
    enter_child_box,
    opaque,
    to_unit_frame,
    unit_frame,
)

__all__ = [
    "PolylineData",
    "PolylineHit",
    "PolylineGeometry",
    "build_polyline_data",
    "profile_polyline_data",
    "intersect_polyline",
    "occluded_polyline",
    "count_crossings_polyline",
    "next_crossing_polyline",
    "polyline_geometry",
    "walk_and_test_polyline",
]

#: Peak memory of building the kernel data per profile segment (bytes):
#: measured 2.7 GB above the process for 1,000,000 points (the tree is built
#: node by node in Python), with margin (issue 24, item 7).
BYTES_PER_SEGMENT = 3000

#: Share of the available memory that building the kernel data may take.
MEMORY_SHARE = 0.5

#: Joint tolerance relative to the profile size (max of r extent, z extent:
#: the kernel works in the unit frame of kernels/common.py, where it is 1).
TOL_REL = 1e-5

#: Padding of the BVH boxes and of the bounding cylinder, in units of the
#: joint tolerance (boxes must contain every hit that a segment accepts).
_BOX_PAD = 8.0

#: Shift of a joint into the solid for its side test, in units of the joint
#: tolerance (see _side_points): about float32 rounding of the unit frame.
#: It decides on which side of a corner a grazing ray passes, which matters
#: to rays restarted past a hit: in the spawn-ray walk of scripts/leak_test.py
#: (9e5 rays) odd counts are 571 without a shift, 439 at 0.001, 113 at 0.01
#: and 157 at 0.1 (the offset-free walk has none at any of them).
_SIDE_SHIFT = 0.01


class PolylineData(LatheData):
    """Opaque Dr.Jit buffers describing one polyline profile.

    Built by :func:`build_polyline_data`. Besides the attributes of
    :class:`~lathe_shape.kernels.common.LatheData` (``links``, ``n_nodes``,
    the padded bounding cylinder ``bound_r``, ``bound_z_lo``, ``bound_z_hi``
    and the unit frame ``scale``, ``inv_scale``, ``z_shift``); all lengths
    below are in the unit frame:

    ``nodes``
        Float buffer, 8 floats per node of the four BVH copies
        (``child_box_bvh``). Inner node: ``(rmax^2, rmin^2, zmin, zmax)`` of
        its first child's box, then of its second's (rmin^2 as
        ``box_rmin2``); leaf:
        ``(n_r, n_z, c, r0, z0, dr / L^2, dz / L^2, tol / L)``.
    ``seg_geo``
        Float buffer, ``(n_r, n_z, dr * total / L, dz * total / L)`` per
        segment (geometric normal and profile tangent scaled for ``dp_dv``).
    ``seg_sh``
        Float buffer, ``(nr0, nz0, nr1, nz1)`` per segment (shading normals).
    ``seg_arc``
        Float buffer, ``(arc start / total, L / total)`` per segment.
    ``seg_side``
        Float buffer, 8 floats per segment: its end points as its joint side
        tests see them, ``(r0, z0, r1, z1)`` and the same moved into the
        solid (see ``_side_points``).
    ``tol``
        Opaque Float scalar: the joint tolerance (unit frame).
    ``total_length``
        Python float: total profile arclength (the user's units).
    ``n_seg``
        Python int: number of segments.
    """


#: Result types (shared with the B-spline kernel).
PolylineHit = LatheHit
PolylineGeometry = LatheGeometry


# ---------------------------------------------------------------------------
# Building the data (numpy, once per profile)
# ---------------------------------------------------------------------------

def _points(name: str, value, m: int | None) -> np.ndarray:
    """``value`` as a float64 (m, 2) array; a ValueError names ``name``."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 2 or (m is not None and len(a) != m):
        rows = "m" if m is None else str(m)
        raise ValueError(f"build_polyline_data(): '{name}' must have shape ({rows}, 2), "
                         f"got {a.shape}")
    return a


def _segments(start, end) -> tuple[np.ndarray, np.ndarray]:
    """The segments' start and end points as float64 ``(m, 2)`` arrays; a
    ValueError names the problem (shape, empty, negative radius, zero
    length)."""
    p0 = _points("start", start, None)
    p1 = _points("end", end, len(p0))
    if len(p0) == 0:
        raise ValueError("build_polyline_data(): 'start' is empty (a profile needs segments)")
    if np.any(p0[:, 0] < 0) or np.any(p1[:, 0] < 0):
        raise ValueError("build_polyline_data(): negative radius in 'start' or 'end'")
    length = np.hypot(*(p1 - p0).T)
    if np.any(length <= 0):
        k = int(np.argmin(length))
        raise ValueError(f"build_polyline_data(): segment {k} has zero length "
                         f"('start' equals 'end' at {p0[k].tolist()})")
    return p0, p1


def check_build_memory(segments: int, who: str, available: int | None = None) -> None:
    """Refuse, before building anything, kernel data for ``segments``
    segments whose estimated peak (:data:`BYTES_PER_SEGMENT` each) exceeds
    :data:`MEMORY_SHARE` of the available memory; the ValueError names
    ``who``, the estimate and what is available."""
    available = available_memory() if available is None else available
    need = segments * BYTES_PER_SEGMENT
    if available is not None and need > MEMORY_SHARE * available:
        raise ValueError(f"{who}: the exact kernel's data for {segments:,} profile segments would take "
                         f"about {format_bytes(need)} to build, more than half the memory available "
                         f"({format_bytes(available)}); use fewer profile points")


def build_polyline_data(start, end, normal_start=None, normal_end=None,
                        who: str = "build_polyline_data()") -> PolylineData:
    """Pack a polyline profile into opaque Dr.Jit buffers.

    ``start`` and ``end`` are ``(m, 2)`` arrays of the segments' ``(r, z)``
    end points (clockwise profile, interior on the right, closed, no segment
    on the axis). ``normal_start`` and ``normal_end`` are the ``(m, 2)``
    unit shading normals ``(n_r, n_z)`` at the start and at the end of every
    segment (eq. 10); ``None`` means the segment's own geometric normal
    (eqs. 8-9: flat shading).
    """
    p0, p1 = _segments(start, end)
    check_build_memory(len(p0), who)
    r0, z0 = p0.T
    r1, z1 = p1.T
    dr_ = r1 - r0
    dz_ = z1 - z0
    length = np.hypot(dr_, dz_)
    # Supporting line n_r r + n_z z = c with the outward (left-hand) normal
    n_r = -dz_ / length
    n_z = dr_ / length
    flat = np.stack([n_r, n_z], axis=1)
    sh0 = flat if normal_start is None else _points("normal_start", normal_start, len(p0))
    sh1 = flat if normal_end is None else _points("normal_end", normal_end, len(p0))

    # Everything below in the unit frame (kernels/common.py)
    size, z_c, frame = unit_frame("build_polyline_data()", float(max(r0.max(), r1.max())),
                                  float(min(z0.min(), z1.min())), float(max(z0.max(), z1.max())))
    r0, r1, dr_, length = r0 / size, r1 / size, dr_ / size, length / size
    z0, z1, dz_ = (z0 - z_c) / size, (z1 - z_c) / size, dz_ / size
    r_max = float(max(r0.max(), r1.max()))
    z_min = float(min(z0.min(), z1.min()))
    z_max = float(max(z0.max(), z1.max()))
    tol = TOL_REL * max(r_max, z_max - z_min)
    pad = _BOX_PAD * tol
    c = n_r * r0 + n_z * z0
    leaf_rec = np.stack([n_r, n_z, c, r0, z0, dr_ / length**2,
                         dz_ / length**2, tol / length], axis=1)

    # Segment boxes in the (r, z) plane, padded for the joint tolerance
    lo_r = np.maximum(np.minimum(r0, r1) - pad, 0.0)
    rows = child_box_arrays(np.stack([lo_r, np.maximum(r0, r1) + pad, np.minimum(z0, z1) - pad,
                                      np.maximum(z0, z1) + pad], axis=1))
    recs = _node_records(rows, leaf_rec)

    arc = np.concatenate([[0.0], np.cumsum(length)])
    total = float(arc[-1])
    seg_geo = np.stack([n_r, n_z, dr_ * total / length, dz_ * total / length], axis=1)
    seg_sh = np.concatenate([sh0, sh1], axis=1)
    seg_arc = np.stack([arc[:-1] / total, length / total], axis=1)

    def buffer(a):
        return opaque(np.asarray(a, dtype=np.float32).ravel())

    return PolylineData(
        nodes=buffer(recs),
        links=opaque(rows.links, mi.UInt32),
        n_nodes=opaque(rows.n_nodes, mi.UInt32),
        seg_geo=buffer(seg_geo),
        seg_sh=buffer(seg_sh),
        seg_arc=buffer(seg_arc),
        seg_side=buffer(_side_points(r0, z0, r1, z1, flat, _SIDE_SHIFT * tol)),
        bound_r=opaque(r_max + 2 * pad),
        bound_z_lo=opaque(z_min - 2 * pad),
        bound_z_hi=opaque(z_max + 2 * pad),
        tol=opaque(tol),
        total_length=total * size,
        **frame,
        n_seg=len(p0),
    )


def _child_records(b: np.ndarray) -> np.ndarray:
    """``(rmax^2, rmin^2, zmin, zmax)`` of boxes ``b`` (rows ``(rmin, rmax,
    zmin, zmax)``), rmin^2 as :func:`~.common.box_rmin2` (-1 at the axis)."""
    return np.stack([b[:, 1] * b[:, 1], np.where(b[:, 0] > 0, b[:, 0] * b[:, 0], -1.0), b[:, 2], b[:, 3]],
                    axis=1)


def _node_records(rows, leaf_rec: np.ndarray) -> np.ndarray:
    """float32 ``(4 * n_nodes, 8)``: the record of every stored node of
    :func:`~.common.child_box_arrays`' copies (see :class:`PolylineData`'s
    ``nodes``); float64 arithmetic, then one rounding, as per node."""
    inner = rows.leaf < 0
    # Each node's record once (the same float64 arithmetic and rounding
    # per node), then gathered for the four copies' first and second child
    per_node = _child_records(rows.tree.bounds).astype(np.float32)
    recs = aligned_empty((len(rows.first), 8), np.float32)
    recs[:, :4] = per_node[rows.first]
    recs[:, 4:] = per_node[rows.second]
    at_leaf = np.flatnonzero(~inner)
    recs[at_leaf] = leaf_rec[rows.leaf[at_leaf]]
    return recs


def _side_points(r0, z0, r1, z1, normal: np.ndarray, shift: float) -> np.ndarray:
    """``(m, 8)``: per segment, its start and end point as the joint side
    tests of the kernel see them (``_joint_sides``): ``(r0, z0, r1, z1)``
    and the same moved into the solid, a joint shared by two segments moved
    ``shift`` along the bisector of their outward normals, the same value
    for both; an end on the axis unchanged.

    Why: only where float32 cannot tell the side of the joint itself, the
    moved joint decides. A ray passing that close to a joint without
    crossing the profile there (grazing a corner) then finds the joint on
    the same side as the segments next to it, so neither segment reports a
    crossing at the joint (two coincident crossings, of which a ray
    restarted past the first would miss the second); a ray crossing at the
    joint still crosses exactly one of the two segments."""
    start = np.stack([r0, z0], axis=1)
    end = np.stack([r1, z1], axis=1)
    side = np.concatenate([start, end, start, end], axis=1)
    k, j = _joints(start, end)
    bisector = normal[k] + normal[j]
    norm = np.sqrt(bisector[:, 0] * bisector[:, 0] + bisector[:, 1] * bisector[:, 1])
    moved = norm > 1e-6
    k, j, bisector, norm = k[moved], j[moved], bisector[moved], norm[moved]
    q = end[k] - shift * bisector / norm[:, None]
    q[:, 0] = np.maximum(q[:, 0], 0.0)
    side[k, 6:] = q
    side[j, 4:6] = q
    return side


def _joints(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(k, j)``: the segments ``k`` whose end is the start of a segment
    ``j`` (the last such ``j`` where starts repeat). A chain's segment
    usually ends where the next one starts: that is checked for all at
    once; the rest are looked up by value."""
    m = len(start)
    nxt = np.roll(np.arange(m), -1)
    chained = (end == start[nxt]).all(axis=1)
    order = np.lexsort((start[:, 1], start[:, 0]))
    s = start[order]
    if not np.any((s[1:] == s[:-1]).all(axis=1)):
        # Starts are distinct: the chained segments' joints, and a search
        # for the few others (a closed chain's first and last segment)
        k, j = np.flatnonzero(chained), nxt[chained]
        other = np.flatnonzero(~chained)
        if len(other) <= 64:
            found = [(i, np.flatnonzero((start == end[i]).all(axis=1))) for i in other]
            k = np.concatenate([k, [i for i, f in found if len(f)]]).astype(np.int64)
            j = np.concatenate([j, [f[0] for _, f in found if len(f)]]).astype(np.int64)
            return k, j
    starting_at = {tuple(p): i for i, p in enumerate(start.tolist())}
    pairs = [(i, starting_at[p]) for i, p in enumerate(map(tuple, end.tolist())) if p in starting_at]
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return pairs[:, 0], pairs[:, 1]


def profile_polyline_data(profile: Profile, smooth: bool = True) -> PolylineData:
    """:func:`build_polyline_data` of a validated profile: its interpolated
    shading normals when ``smooth``, else flat (geometric) normals."""
    start, end = profile.segment_points()
    if smooth:
        return build_polyline_data(start, end, profile.normal_start, profile.normal_end, who=profile.source)
    return build_polyline_data(start, end, who=profile.source)


# ---------------------------------------------------------------------------
# One traversal step (Dr.Jit, traced)
# ---------------------------------------------------------------------------

class _Key:
    """A crossing's place along its ray: ``s`` (moved frame), then ``key =
    2 segment + root`` (``root`` 0 for ``s1``, 1 for ``s2`` of
    :func:`_roots`) among crossings at the same ``s``. A ray walked through
    its crossings from one origin (:func:`next_crossing_polyline`) finds
    every crossing once, in this order, even where float32 puts several at
    the same ``s``. ``key=None`` (the plain queries) compares ``s`` alone:
    no extra work on the hot path."""

    def __init__(self, s: mi.Float, key: mi.UInt32 | None = None) -> None:
        self.s = s
        self.key = key

    def before(self, s, key) -> mi.Bool:
        """Whether this key comes before ``(s, key)``."""
        if self.key is None:
            return self.s < s
        return (self.s < s) | ((self.s == s) & (self.key < key))

    def after(self, s, key) -> mi.Bool:
        """Whether this key comes after ``(s, key)``."""
        if self.key is None:
            return self.s > s
        return (self.s > s) | ((self.s == s) & (self.key > key))


class _Ray(LatheRay):
    """The common ray set-up plus the per-ray constants of the segment test."""

    def __init__(self, data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                 tmax: mi.Float, active: mi.Bool) -> None:
        super().__init__(data, o, d, tmax, active)
        self.r_o = dr.sqrt(self.c)   # distance of the moved origin from the axis
        self.parallel = self.a == 0  # parallel to the axis
        # Tolerance on |w| - |n_r cross| (units of length times |d| = 1)
        self.tol_d = data.tol
        # d_z o_xy, for the sides of the segments' end points (_side_terms)
        self.dz_ox = self.d.z * self.o.x
        self.dz_oy = self.d.z * self.o.y
        # Crossings count after this key (t > 0: every one past s_lo)
        self.after = _Key(self.s_lo)
        # ... and, walking after another lathe's crossing, only those with
        # t > t_after (None: no such test)
        self.t_after = None
        # Exactly horizontal (unit frame): every point of the ray at height o_z
        self.level = self.d.z == 0


def _roots(ray: _Ray, n_r, n_z, c):
    """Roots ``(s1, s2)`` of the quadratic of eqs. 1 and 3 for ``n_r^2 r(s)^2
    = (c - n_z z(s))^2``, its discriminant (up to a positive factor) and
    whether the roots are real within the tolerance."""
    o, d = ray.o, ray.d
    nr2 = n_r * n_r
    h0 = dr.fma(-n_z, o.z, c)
    h1 = -n_z * d.z
    qa = dr.fma(nr2, ray.a, -h1 * h1)
    qb = dr.fma(nr2, ray.b, -h0 * h1)
    qc = (n_r * ray.r_o - h0) * (n_r * ray.r_o + h0)
    # qb^2 - qa qc = n_r^2 (|h0 d_xy - h1 o_xy|^2 - n_r^2 cross^2), factored
    wx = dr.fma(h0, d.x, -h1 * o.x)
    wy = dr.fma(h0, d.y, -h1 * o.y)
    wl = dr.sqrt(dr.fma(wx, wx, wy * wy))
    cr = dr.abs(n_r * ray.cross)
    disc = (wl - cr) * (wl + cr)
    has_root = wl - cr >= -ray.tol_d
    root = dr.abs(n_r) * dr.sqrt(dr.maximum(disc, 0))
    q = -(qb + dr.copysign(root, qb))
    return q / qa, qc / q, disc, has_root


class _Stack:
    """Per-lane stack of the children still to visit, with where the ray
    enters them (local memory). A leaf has at most
    :data:`~lathe_shape.kernels.common.BVH_DEPTH` inner ancestors, each of
    whose visits pushes at most one child: so up to ``BVH_DEPTH`` entries
    are on the stack when a leaf is visited, and that visit writes its (not
    pushed) child to the slot above them: ``BVH_DEPTH + 1`` slots."""

    def __init__(self) -> None:
        self.node = dr.alloc_local(mi.UInt32, BVH_DEPTH + 1)
        self.s = dr.alloc_local(mi.Float, BVH_DEPTH + 1)

    @dr.syntax
    def advance(self, depth, s_best, go, near, near_s, push, far, far_s):
        """After a visit: ``(node, node_s, depth, more)``, the node to visit
        next (``near`` where ``go``, else the top of the stack that the ray
        enters before ``s_best``), where the ray enters it, the new stack
        depth (``far`` pushed where ``push``) and whether a node is left.
        ``depth`` must start as an array of the rays' width: from a scalar
        0, Dr.Jit 1.5 read back wrong entries."""
        slot = dr.minimum(depth, BVH_DEPTH)
        self.node[slot] = far   # kept only where pushed (the slot is free)
        self.s[slot] = far_s
        node = mi.UInt32(near)                     # node to visit next
        node_s = mi.Float(near_s)                  # where the ray enters it
        more = mi.Bool(go)                         # whether there is one
        depth = dr.select(push, depth + 1, depth)  # entries on the stack
        pop = ~go & (depth > 0)                    # whether to pop one
        # Entries that the ray enters after the best hit so far are dropped
        while pop:
            depth -= 1
            node = self.node[depth]
            node_s = self.s[depth]
            more = node_s <= s_best
            pop = ~more & (depth > 0)
        return node, node_s, depth, more


def _children(ray: _Ray, node, link, box0, box1, s_best, inner):
    """An inner node's two children (boxes ``box0``, ``box1``, see
    ``PolylineData.nodes``): ``(go, near, near_s, push, far, far_s)``: visit
    ``near`` next (where ``go``), entering it at ``near_s``, and later
    ``far`` (where ``push``); the child that the ray enters first (its slab
    and cylinder, :func:`enter_child_box`) is the near one, ties go to the
    first child (the copy's order)."""
    in0, s0 = enter_child_box(ray, box0, s_best)
    in1, s1 = enter_child_box(ray, box1, s_best)
    in0 &= inner
    in1 &= inner
    swap = in1 & (~in0 | (s1 < s0))
    first, second = node + 1, link
    return (in0 | in1, dr.select(swap, second, first), dr.select(swap, s1, s0), in0 & in1,
            dr.select(swap, first, second), dr.select(swap, s0, s1))


@dr.syntax
def _visit(data: PolylineData, ray: _Ray, node: mi.UInt32, best: _Key, active: mi.Bool):
    """Visit one node whose box the ray enters: box tests of an inner node's
    children, the segment test of a leaf.

    Returns ``(children, s_hit, u_hit, seg, hit, key, count)``:
    ``children`` as :func:`_children` returns them (none for a leaf);
    ``hit`` marks a leaf whose segment is crossed after ``ray.after`` and
    before ``best`` (key order, :class:`_Key`), at ``s_hit`` with key
    ``key``, ``count`` its number of crossings there. The segment test is a
    symbolic ``if``: a packet without a lane at a leaf skips it.
    """
    rec0 = dr.gather(mi.Vector4f, data.nodes, node * 2, active)
    rec1 = dr.gather(mi.Vector4f, data.nodes, node * 2 + 1, active)
    link, is_leaf, seg = bvh_link(data.links, node, active)
    leaf = active & is_leaf
    children = _children(ray, node, link, rec0, rec1, best.s, active & ~is_leaf)

    s_hit = mi.Float(0.0)     # leaf: the nearer root on the segment
    u_hit = mi.Float(0.0)     # ... its fraction along the segment
    hit = mi.Bool(False)      # ... and whether it is a hit before s_best
    key = mi.UInt32(0)        # ... its crossing key (_Key)
    count = mi.UInt32(0)      # ... its number of crossings before s_best
    if leaf:
        # Half-open joints, see _segment_roots
        s1, s2, disc, has_root = _roots(ray, rec0.x, rec0.y, rec0.z)
        s_hit, u_hit, ok, key, count = _segment_hit(data, ray, seg, rec0, rec1, s1, s2, disc >= 0,
                                                    has_root, best, leaf)
        hit = leaf & ok
    return children, s_hit, u_hit, seg, hit, key, count


def _side_terms(ray: _Ray, r, z):
    """``(|d_z| r)^2`` and ``|d_z o_xy + (z - o_z) d_xy|^2``: the profile point
    ``(r, z)`` lies outside the ray's surface of revolution when the first
    exceeds the second (the ray's radius at height ``z``, times ``|d_z|``:
    eq. 15 substituted into eq. 1)."""
    w = z - ray.o.z
    vx = dr.fma(w, ray.d.x, ray.dz_ox)
    vy = dr.fma(w, ray.d.y, ray.dz_oy)
    zr = ray.d.z * r
    return zr * zr, dr.fma(vx, vx, vy * vy)


def _joint_sides(data: PolylineData, ray: _Ray, seg: mi.UInt32, active: mi.Bool):
    """Whether the start and the end of segment ``seg`` lie outside the ray's
    surface of revolution (:func:`_side_terms`).

    A segment's surface is crossed an odd number of times exactly when its
    two end points lie on different sides. The test is evaluated identically
    (bit-equal data, same operations) for the end of one segment and the
    start of the next, so both agree on which of them a crossing at their
    joint belongs to. Where float32 cannot tell a joint's side (within 16
    ulps of the terms) the side of the joint moved into the solid decides
    (see ``_side_points``). Points on the axis, and every point for a
    horizontal ray, are never outside (strict comparison), so the profile's
    ends on the axis agree."""
    # Scalar gathers: packet gathers of another buffer would let its memory
    # layout select among more traced kernels
    ends = [dr.gather(mi.Float, data.seg_side, seg * 8 + k, active) for k in range(4)]
    outside = [mi.Bool(False), mi.Bool(False)]  # start, end outside
    unsure = [mi.Bool(False), mi.Bool(False)]   # ... float32 cannot tell
    for k in range(2):
        radius2, ray2 = _side_terms(ray, ends[2 * k], ends[2 * k + 1])
        outside[k] = radius2 > ray2
        unsure[k] = dr.abs(radius2 - ray2) <= 16 * dr.epsilon(mi.Float) * (radius2 + ray2)
    # Rare: packets without an unsure lane skip the moved points
    moved_start, moved_end = _moved_sides(data, ray, seg, active & (unsure[0] | unsure[1]))
    return (dr.select(unsure[0], moved_start, outside[0]),
            dr.select(unsure[1], moved_end, outside[1]))


@dr.syntax
def _moved_sides(data: PolylineData, ray: _Ray, seg: mi.UInt32, active: mi.Bool):
    """Whether the start and the end of segment ``seg``, moved into the solid
    (``_side_points``), lie outside the ray's surface of revolution."""
    moved_start = mi.Bool(False)  # the moved start is outside
    moved_end = mi.Bool(False)    # the moved end is outside
    if active:
        moved = [dr.gather(mi.Float, data.seg_side, seg * 8 + k, active) for k in range(4, 8)]
        radius2, ray2 = _side_terms(ray, moved[0], moved[1])
        moved_start = radius2 > ray2
        radius2, ray2 = _side_terms(ray, moved[2], moved[3])
        moved_end = radius2 > ray2
    return moved_start, moved_end


@dr.syntax
def _crossing_parity(data: PolylineData, ray: _Ray, seg, has_root, active):
    """Whether the ray crosses segment ``seg`` an odd number of times: its
    end points lie on different sides of the ray's surface of revolution
    (:func:`_joint_sides`). Every segment decides so, never from its roots:
    the sides of a joint are evaluated bit for bit alike by both segments
    that meet there, so the parities of all segments add up to an even
    number of crossings for every line. A ray whose line misses the
    segment's cone (``has_root`` false, with the tolerance of ``_roots``)
    crosses it an even number of times; packets without a lane that meets
    the cone skip the side tests."""
    odd = mi.Bool(False)
    test = active & has_root
    if test:
        side_start, side_end = _joint_sides(data, ray, seg, test)
        odd = side_start != side_end
    return odd


def _segment_roots(data: PolylineData, ray: _Ray, seg, rec0, rec1, s1, s2, real, has_root, active):
    """The crossings of the ray's line with segment ``seg`` (leaf record
    ``(rec0, rec1)``) among the roots ``s1``, ``s2``: ``(take1, take2, s1,
    s2, u1, u2)``, ``u`` the fraction along the segment (unclipped);
    ``real``: the roots are real (``disc >= 0``).

    Joints are half-open by construction: the parity of the segment's
    crossings is fixed first (:func:`_crossing_parity`), and the roots only
    say which crossings those are. Odd: exactly one root, the one nearest
    the segment. Even: both roots when both lie on the segment up to the
    joint tolerance (an annulus, ``n_r = 0``, has a double root: no pair),
    else none (a grazing ray that float32 cannot resolve touches
    nothing). A crossing at a joint thus counts once, on the segment that
    the shared end point's side gives it, and every line crosses the
    profile an even number of times."""
    n_r, n_z, c = rec0.x, rec0.y, rec0.z
    r0, z0, er, ez, tol_u = rec0.w, rec1.x, rec1.y, rec1.z, rec1.w
    tol_n = data.tol * n_r * n_r
    o, d = ray.o, ray.d

    def off_segment(s):
        px = dr.fma(d.x, s, o.x)
        py = dr.fma(d.y, s, o.y)
        pz = dr.fma(d.z, s, o.z)
        # Fraction along the segment from the measured (r, z) of the point
        u = dr.fma(dr.sqrt(dr.fma(px, px, py * py)) - r0, er, (pz - z0) * ez)
        # The mirror nappe (n_r (c - n_z z) = n_r^2 r < 0) is never on it
        nappe = n_r * dr.fma(-n_z, pz, c) >= -tol_n
        return u, dr.select(nappe, dr.maximum(-u, u - 1), dr.inf)

    u1, off1 = off_segment(s1)
    u2, off2 = off_segment(s2)
    odd = _crossing_parity(data, ray, seg, has_root, active)
    pair = real & (n_r != 0) & (off1 <= tol_u) & (off2 <= tol_u)
    # A horizontal ray's pair lies at its own height: the heights of the end
    # points decide it exactly (the tolerance would give a joint's pair to
    # both of its segments)
    pair &= _level_straddles(data, ray, seg, active & pair & ray.level)
    first = off1 <= off2  # odd: s1 is the root nearer to the segment
    take1, take2 = dr.select(odd, first, pair), dr.select(odd, ~first, pair)
    # An odd segment's root off it (ill conditioned: a ray nearly along the
    # segment's cone, through its joint) is moved to the segment's heights,
    # where its crossing lies: else it could fall past the bounding cylinder.
    move1, move2 = take1 & (off1 > tol_u), take2 & (off2 > tol_u)
    s1, s2 = _to_heights(data, ray, z0, rec1.z, tol_u, s1, s2, move1, move2, active & (move1 | move2))
    return take1, take2, s1, s2, u1, u2


@dr.syntax
def _level_straddles(data: PolylineData, ray: _Ray, seg, active):
    """Where ``active`` (horizontal rays, ``d_z = 0``): whether segment
    ``seg``'s end points lie on different sides of the ray's plane ``z =
    o_z``; elsewhere true.

    A horizontal line crosses a slanted segment's surface twice (or not at
    all), both times at its own height, so the pair belongs to the segment
    exactly when its heights straddle the ray's. The end points' heights
    are those of the joint side tests (``seg_side``: bit-equal for both
    segments of a joint); an end exactly at the ray's height takes the side
    of the joint moved into the solid (``_side_points``), and below when
    that too is level. So a joint at the ray's height gives its pair to one
    of two segments that go on up or down, and none at a convex corner
    (a grazing ray) (issue 24, item 13). Rare: packets without an active
    lane skip it."""
    straddles = mi.Bool(True)
    if active:
        z = [dr.gather(mi.Float, data.seg_side, seg * 8 + k, active) for k in (1, 3, 5, 7)]
        above = [dr.select(z[k] == ray.o.z, z[k + 2] > ray.o.z, z[k] > ray.o.z) for k in (0, 1)]
        straddles = above[0] != above[1]
    return straddles


@dr.syntax
def _to_heights(data: PolylineData, ray: _Ray, z0, ez, tol_u, s1, s2, move1, move2, active):
    """``s1``, ``s2`` clipped (where ``move1``, ``move2``) to the interval of
    ``s`` over which the ray passes the segment's heights, from ``z0`` to
    ``z0 + ez L^2`` (``L = tol / tol_u``). Rare: packets without an active
    lane skip it."""
    if active:
        z1 = dr.fma(ez, dr.square(data.tol / tol_u), z0)
        s_z0 = (z0 - ray.o.z) * ray.inv_dz
        s_z1 = (z1 - ray.o.z) * ray.inv_dz
        lo, hi = dr.minimum(s_z0, s_z1), dr.maximum(s_z0, s_z1)
        s1 = dr.select(move1, dr.clip(s1, lo, hi), s1)
        s2 = dr.select(move2, dr.clip(s2, lo, hi), s2)
    return s1, s2


def _segment_hit(data: PolylineData, ray: _Ray, seg, rec0, rec1, s1, s2, real, has_root,
                 best: _Key, active):
    """The first crossing of segment ``seg`` (:func:`_segment_roots`) after
    ``ray.after`` and before ``best`` in key order (:class:`_Key`): ``(s, u,
    found, key, count)``, ``count`` the number of its crossings there."""
    take1, take2, s1, s2, u1, u2 = _segment_roots(data, ray, seg, rec0, rec1, s1, s2, real,
                                                  has_root, active)
    key1, key2 = 2 * seg, 2 * seg + 1
    ok1 = take1 & ray.after.before(s1, key1) & best.after(s1, key1)
    ok2 = take2 & ray.after.before(s2, key2) & best.after(s2, key2)
    if ray.t_after is not None:
        # After another lathe's crossing: decided on this crossing's own t,
        # the value returned (eq. 31; _walk_ray)
        ok1 &= (ray.s_enter + s1) * ray.t_scale > ray.t_after
        ok2 &= (ray.s_enter + s2) * ray.t_scale > ray.t_after
    pick2 = ok2 & (~ok1 | (s2 < s1))
    ok = ok1 | ok2
    return (dr.select(pick2, s2, s1), dr.select(pick2, u2, u1), ok,
            dr.select(pick2, key2, key1), mi.UInt32(ok1) + mi.UInt32(ok2))


# ---------------------------------------------------------------------------
# Public kernels
# ---------------------------------------------------------------------------

@dr.syntax
def _first_crossing(data: PolylineData, ray: _Ray, keyed: bool):
    """The first crossing of ``ray`` after ``ray.after``, before its exit
    from the bounding cylinder and ``tmax``: ``(hit, s, key)``; ``keyed``:
    ties in ``s`` are broken by the key (:class:`_Key`), else by the order
    of the traversal."""
    stack = _Stack()
    node = mi.UInt32(ray.first)          # node to visit (the root: the ray is clipped to its box)
    node_s = mi.Float(ray.s_lo)          # where the ray enters it (read nowhere; without it, Dr.Jit 1.5
    #                                      once emitted a callable twice in a later lathe_prb kernel)
    depth = dr.zeros(mi.UInt32, dr.width(node_s))  # nodes on the stack
    more = mi.Bool(ray.active)           # whether a node is left to visit
    s_best = mi.Float(ray.s_hi)          # first crossing so far (moved frame)
    key = dr.zeros(mi.UInt32, dr.width(s_best))  # its key (_Key)
    seg = dr.zeros(mi.UInt32, dr.width(s_best))  # its segment
    u = dr.zeros(mi.Float, dr.width(s_best))     # its fraction along seg
    found = dr.zeros(mi.Bool, dr.width(s_best))  # whether a hit was found
    while more:
        children, s_hit, u_hit, seg_hit, hit, key_hit, _ = _visit(
            data, ray, node, _Key(s_best, key if keyed else None), more)
        s_best = dr.select(hit, s_hit, s_best)
        key = dr.select(hit, key_hit, key)
        u = dr.select(hit, u_hit, u)
        seg = dr.select(hit, seg_hit, seg)
        found |= hit
        node, node_s, depth, more = stack.advance(depth, s_best, *children)

    t = ray.s_enter + s_best
    valid = found & (t > 0) & (t < ray.tmax)
    hit = PolylineHit(t=dr.select(valid, t * ray.t_scale, dr.inf), seg=seg,
                      u=dr.clip(u, 0, 1), valid=valid)
    return hit, s_best, key


def intersect_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                       tmax: mi.Float, active: mi.Bool) -> PolylineHit:
    """Nearest intersection with ``0 < t < tmax`` of the ray ``o + t d``.

    ``o`` and ``d`` are in the lathe's local frame; ``d`` need not be unit
    length and ``t`` is measured in units of ``d``. Traceable inside an outer
    symbolic loop (no evaluation happens here).
    """
    return _first_crossing(data, _Ray(data, o, d, tmax, active), False)[0]


def _walk_ray(data: PolylineData, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float, active: mi.Bool,
              after_s: mi.Float | None, after_key: mi.UInt32 | None, after_t: mi.Float | None) -> _Ray:
    """The ray of :func:`next_crossing_polyline` (its arguments), set to
    visit the crossings after ``(after_s, after_key)`` or ``after_t``."""
    ray = _Ray(data, o, d, tmax, active)
    s_from = ray.s_lo
    keyed = mi.Bool(False) if after_s is None else after_key != NO_CROSSING
    if after_t is not None:
        # t = (s_enter + s) t_scale (kernels/common.py, LatheRay). Where the
        # last crossing was another lathe's, the one after it is the first
        # with t > after_t, compared on the t this kernel returns (the walk's
        # order of eq. 31: the rounding of t -> s decides nothing); s_from
        # only prunes, so it is lowered past that rounding
        s_t = after_t * dr.rcp(ray.t_scale)
        s_from = dr.maximum(s_from, s_t - ray.s_enter - 1e-5 * (dr.abs(s_t) + dr.abs(ray.s_enter)))
        ray.t_after = dr.select(keyed, -dr.inf, after_t)
    if after_s is not None:
        after_s = dr.select(keyed, after_s, s_from)
        later = after_s > ray.s_lo
        ray.after = _Key(dr.select(later, after_s, ray.s_lo),
                         dr.select(later & keyed, after_key, NO_CROSSING))
    else:
        ray.after = _Key(s_from, mi.UInt32(NO_CROSSING))
    ray.s_lo = ray.after.s  # boxes before it need no visit
    return ray


def next_crossing_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float,
                           active: mi.Bool, after_s: mi.Float | None = None,
                           after_key: mi.UInt32 | None = None, after_t: mi.Float | None = None
                           ) -> tuple[PolylineHit, mi.Float, mi.UInt32]:
    """The next crossing of the ray ``o + t d`` (``0 < t < tmax``) after the
    one that a previous call with the same ``o``, ``d`` returned as
    ``(after_s, after_key)`` (``None``: the first crossing, as
    :func:`intersect_polyline`): ``(hit, s, key)``, ``(s, key)`` this
    crossing's place to pass to the next call. Lanes whose ``after_key`` is
    :data:`NO_CROSSING` ask instead for the first crossing with ``t >
    after_t`` (``None``: 0), e.g. after another shape's hit on the line.

    Walking a ray through its crossings this way, from its first origin and
    without offsets, finds each crossing exactly once, also where two of
    them are closer together than any offset or rounded to the same ``t``
    (a corner): with the joint rule of :func:`_segment_roots` a ray from
    outside the lathe then crosses it an even number of times.
    """
    ray = _walk_ray(data, o, d, tmax, active, after_s, after_key, after_t)
    return _first_crossing(data, ray, True)


#: Turns of :func:`walk_and_test_polyline`'s loop, per variant (opaque, made
#: on first use: a literal trip count would let LLVM unroll the loop,
#: copying the traversal that it is there to compile once).
_JOBS: dict[str, mi.UInt32] = {}


@dr.syntax
def walk_and_test_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f, tmax: mi.Float,
                           active: mi.Bool, after_s: mi.Float, after_key: mi.UInt32, after_t: mi.Float,
                           shadow_o: mi.Point3f, shadow_d: mi.Vector3f, shadow_tmax: mi.Float,
                           shadow_active: mi.Bool) -> tuple[PolylineHit, mi.Float, mi.UInt32, mi.Bool]:
    """:func:`next_crossing_polyline` of the ray ``o + t d`` (``after_s``,
    ``after_key``, ``after_t`` as there) and :func:`occluded_polyline` of
    the shadow ray ``shadow_o + t shadow_d`` (``0 < t < shadow_tmax``):
    ``(hit, s, key, occluded)`` (``s``, ``key`` as there where ``active``;
    elsewhere ``hit`` is a miss).

    The two queries are two turns of a symbolic loop around one traversal:
    its code, most of the kernel, is traced and compiled once instead of
    twice (a render's first, uncached compilation is dominated by LLVM's
    time on such code). The shadow ray's turn asks for its first crossing
    from ``t = 0``, which is valid exactly where some crossing lies in
    ``0 < t < shadow_tmax`` (``t`` grows with ``s``), i.e. where
    :func:`occluded_polyline` finds one. (Stopping that turn at the first
    crossing found, as :func:`occluded_polyline` does, made the renders
    slower.)"""
    jobs = _JOBS.get(mi.variant())
    if jobs is None:
        jobs = _JOBS[mi.variant()] = opaque(2, mi.UInt32)
    width = dr.width(o, after_s, shadow_o)
    # Turns: 0 the shadow ray, 1 the ray; each lane takes only those it
    # needs (a packet without a shadow ray skips turn 0's set-up: camera
    # rays, and the renders stay as fast as with two queries)
    job = dr.select(shadow_active, dr.zeros(mi.UInt32, width), 1)  # this lane's turn
    hit = PolylineHit(t=dr.full(mi.Float, dr.inf, width), seg=dr.zeros(mi.UInt32, width),
                      u=dr.zeros(mi.Float, width), valid=dr.zeros(mi.Bool, width))  # the ray's crossing
    s = dr.zeros(mi.Float, width)        # ... its place (s, key)
    key = dr.zeros(mi.UInt32, width)
    occluded = dr.zeros(mi.Bool, width)  # whether the shadow ray meets the lathe
    while (job < jobs) & ((job == 0) | active):
        test = job == 0
        ray = _walk_ray(data, dr.select(test, shadow_o, o), dr.select(test, shadow_d, d),
                        dr.select(test, shadow_tmax, tmax), dr.select(test, shadow_active, active),
                        dr.select(test, 0.0, after_s), dr.select(test, NO_CROSSING, after_key),
                        dr.select(test, 0.0, after_t))
        hit_job, s_job, key_job = _first_crossing(data, ray, True)
        occluded |= test & hit_job.valid
        hit = dr.select(test, hit, hit_job)
        s = dr.select(test, s, s_job)
        key = dr.select(test, key, key_job)
        job += 1
    return hit, s, key, occluded


@dr.syntax
def occluded_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                      tmax: mi.Float, active: mi.Bool) -> mi.Bool:
    """Whether the ray ``o + t d`` hits the lathe for some ``0 < t < tmax``.

    Same conventions as :func:`intersect_polyline`; stops at the first hit.
    """
    ray = _Ray(data, o, d, tmax, active)
    stack = _Stack()
    node = mi.UInt32(ray.first)          # node to visit (the root)
    depth = dr.zeros(mi.UInt32, dr.width(node))  # nodes on the stack
    more = mi.Bool(ray.active)           # whether a node is left to visit
    found = dr.zeros(mi.Bool, dr.width(node))  # whether any hit was found
    while more & ~found:
        children, s_hit, _, _, hit, _, _ = _visit(data, ray, node, _Key(ray.s_hi), more)
        t = ray.s_enter + s_hit
        found |= hit & (t > 0) & (t < ray.tmax)
        node, _, depth, more = stack.advance(depth, ray.s_hi, *children)
    return found


@dr.syntax
def count_crossings_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                             active: mi.Bool) -> mi.UInt32:
    """Number of crossings of the ray ``o + t d`` (``t > 0``) with the lathe,
    every one that :func:`intersect_polyline` can report. For a ray that
    starts outside the lathe's bounding cylinder that is the whole line, and
    the number is even for every ray (the joint rule of
    :func:`_segment_roots`): the watertightness tests count it."""
    ray = _Ray(data, o, d, dr.full(mi.Float, dr.inf, dr.width(o)), active)
    stack = _Stack()
    node = mi.UInt32(ray.first)          # node to visit (the root)
    depth = dr.zeros(mi.UInt32, dr.width(node))  # nodes on the stack
    more = mi.Bool(ray.active)           # whether a node is left to visit
    total = dr.zeros(mi.UInt32, dr.width(node))  # crossings so far
    while more:
        children, _, _, _, _, _, count = _visit(data, ray, node, _Key(ray.s_hi), more)
        total += count
        node, _, depth, more = stack.advance(depth, ray.s_hi, *children)
    return total


def polyline_geometry(data: PolylineData, p: mi.Point3f, seg: mi.UInt32,
                      u: mi.Float, smooth: bool) -> PolylineGeometry:
    """Differential geometry at the local point ``p`` on segment ``seg``.

    ``u`` is the fraction along the segment returned by
    :func:`intersect_polyline`. Returns the geometric outward unit normal
    ``n`` (eqs. 8-9), the shading normal ``sh_n`` (eq. 10: the endpoint
    normals interpolated along the segment, normalised and rotated to the
    azimuth of ``p``; equal to ``n`` when ``smooth`` is False), texture
    coordinates ``uv = (azimuth / 2 pi, arclength / total arclength)`` and
    the partial derivatives ``dp_du``, ``dp_dv`` of ``p`` with respect to
    them. On the axis the azimuth ``(cos, sin) = (1, 0)`` is used and
    ``dp_du`` vanishes.
    """
    geo = dr.gather(mi.Vector4f, data.seg_geo, seg)
    arc = dr.gather(mi.Vector2f, data.seg_arc, seg)

    # Azimuth of the hit point (on the axis any azimuth will do: take phi =
    # 0), from the point in the unit frame (no over- or underflow)
    q = to_unit_frame(data, p)
    r = dr.sqrt(dr.fma(q.x, q.x, q.y * q.y))
    on_axis = r == 0
    inv_r = dr.select(on_axis, 0, dr.rcp(r))
    cos_phi = dr.select(on_axis, 1, q.x * inv_r)
    sin_phi = dr.select(on_axis, 0, q.y * inv_r)

    # Eqs. 8-9: the 2D left-hand normal rotated to the hit azimuth
    n = mi.Vector3f(geo.x * cos_phi, geo.x * sin_phi, geo.y)

    if smooth:
        # Eq. 10: N* = (1 - u) N_i + u N_(i+1), normalised, then rotated
        sh = dr.gather(mi.Vector4f, data.seg_sh, seg)
        nr = dr.lerp(sh.x, sh.z, u)
        nz = dr.lerp(sh.y, sh.w, u)
        inv = dr.rsqrt(dr.fma(nr, nr, nz * nz))
        sh_n = mi.Vector3f(nr * inv * cos_phi, nr * inv * sin_phi, nz * inv)
    else:
        sh_n = mi.Vector3f(n)

    phi = dr.atan2(sin_phi, cos_phi)
    uv_x = dr.select(phi < 0, phi + 2 * dr.pi, phi) * dr.inv_two_pi
    uv_x = dr.select(uv_x >= 1, 0, uv_x)
    uv = mi.Point2f(uv_x, dr.fma(u, arc.y, arc.x))

    # p = (r cos(2 pi u), r sin(2 pi u), z(v))
    dp_du = mi.Vector3f(-2 * dr.pi * p.y, 2 * dr.pi * p.x, 0)
    dp_dv = mi.Vector3f(geo.z * cos_phi, geo.z * sin_phi, geo.w) * data.scale
    return PolylineGeometry(n=n, sh_n=sh_n, uv=uv, dp_du=dp_du, dp_dv=dp_dv)
