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
  inner node holding its children's boxes (polylines): built with numpy in
  :mod:`.trees`, and importable from here;
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

import drjit as dr
import mitsuba as mi
import numpy as np

from . import trees
from .trees import (  # noqa: F401 (the tree builders, importable from here as before)
    BVH_DEPTH,
    CLUSTER_SIZE,
    LEAF,
    BoxTree,
    ChildBoxRows,
    _bounds,
    _box_order,
    _child_box_bvh_recursive,
    _dense_rank,
    _revolved_area,
    _sah_split,
    _sah_split_small,
    _store_copies,
    _threaded_bvh_recursive,
    child_box_bvh,
    clustered_tree,
    sah_tree,
    threaded_bvh,
)

__all__ = [
    "BVH_DEPTH",
    "BoxTree",
    "CLUSTERED_ABOVE",
    "CLUSTER_SIZE",
    "ChildBoxRows",
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
    "child_box_arrays",
    "child_box_bvh",
    "enter_annular_box",
    "enter_child_box",
    "opaque",
    "radial_interval",
    "sah_tree",
    "threaded_bvh",
    "to_unit_frame",
    "unit_frame",
]

#: The crossing key of a place along a ray that is no crossing of the lathe
#: at hand (the kernels' ``next_crossing_*``: continue after a ray parameter).
NO_CROSSING = 0xFFFFFFFF

#: Boxes above which the kernels' child-box trees are
#: :func:`~.trees.clustered_tree`'s (see :data:`.trees.CLUSTERED_ABOVE`);
#: read here at every build, so that setting it on this module takes effect.
CLUSTERED_ABOVE = trees.CLUSTERED_ABOVE


def child_box_arrays(box: np.ndarray) -> ChildBoxRows:
    """:func:`.trees.child_box_arrays` with this module's
    :data:`CLUSTERED_ABOVE`."""
    return trees.child_box_arrays(box, CLUSTERED_ABOVE)


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
