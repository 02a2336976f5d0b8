"""Ray intersection kernel for a polyline profile revolved about the local z axis.

All functions work in the lathe's *local* frame: the axis of revolution is the
local +z axis and a profile point ``(r, z)`` lies at distance ``r >= 0`` from
it. The profile is a list of segments ``(r0, z0) -> (r1, z1)`` oriented
clockwise in the (r right, z up) plane, so that the solid's interior is on the
right of every segment and the outward normal is the left-hand normal
``(-(z1 - z0), r1 - r0) / L`` (``/work/shared/docs/method.md``).

Every segment is handled through one formula. Writing its supporting line as
``n_r r + n_z z = c`` (``(n_r, n_z)`` the unit outward normal), the swept
surface is ``n_r sqrt(x^2 + y^2) = c - n_z z``. Squaring gives

    n_r^2 (x^2 + y^2) = (c - n_z z)^2,

which is the paper's cone frustum ``x^2 + y^2 = (A z + B)^2`` (eq. 1) scaled by
``n_r^2`` when ``z0 != z1``, and degenerates to the plane of the annulus
``z = z0`` (eqs. 4-5, a double root) when ``n_r = 0``. Substituting the ray
gives one quadratic (eqs. 2-3) for frusta, cylinders and annuli alike.

Culling uses a small bounding volume hierarchy over the segments in the
(r, z) plane. A node is an annular box ``[rmin, rmax] x [zmin, zmax]``; the
ray enters it where ``z(s)`` lies in the slab and ``r(s) <= rmax`` (the same
quadratic with the cylinder ``r = rmax``), and since ``r(s)^2`` is convex in
``s`` the largest radius over that interval is at one of its ends (the
``rmin`` test). The tree is stored four times as a *threaded* array (pre-order
with miss links) so that traversal needs no stack; the four copies differ
only in the child order (lower or upper child first for a z split, outer or
inner child first for an r split), and every ray picks the copy matching the
sign of its ``d_z`` and of its radial velocity, which visits nearby nodes
first and lets the nearest-hit search shrink its interval early.

Precision (``/work/shared/docs/traps.md``): the ray origin is first moved to
its entry into the profile's bounding cylinder, roots use the stable form
``q = -(b + sign(b) sqrt(disc))``, the discriminant and constant term are
evaluated in factored forms that do not cancel, and a hit is accepted on a
segment when its profile position lies within an absolute tolerance (scaled
to the profile size) of the segment, so that rays aimed exactly at joints
still find a surface.

The functions need an active JIT Mitsuba variant (``llvm_*`` or ``cuda_*``)
when called; importing the module needs none.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from .common import LEAF, LatheGeometry, LatheHit, threaded_bvh

#: Joint tolerance relative to the profile size (max of r extent, z extent).
TOL_REL = 1e-5

#: Padding of the BVH boxes and of the bounding cylinder, in units of the
#: joint tolerance (boxes must contain every hit that a segment accepts).
_BOX_PAD = 8.0

#: Floats per node record (two Vector4f gathers).
_REC = 8


class PolylineData:
    """Opaque Dr.Jit buffers describing one polyline profile.

    Built by :func:`build_polyline_data`. Attributes:

    ``nodes``
        Float buffer, 8 floats per node of the four threaded BVH copies.
        Inner node: ``(1, 0, rmax, rmin^2, zmin, zmax, 0, 0)``; leaf:
        ``(n_r, n_z, c, r0, z0, dr / L^2, dz / L^2, tol / L)``.
    ``links``
        UInt32 buffer: the miss link of an inner node, or
        ``LEAF | segment index`` for a leaf.
    ``n_nodes``
        Opaque UInt32: nodes per copy.
    ``seg_geo``
        Float buffer, ``(n_r, n_z, dr * total / L, dz * total / L)`` per
        segment (geometric normal and profile tangent scaled for ``dp_dv``).
    ``seg_sh``
        Float buffer, ``(nr0, nz0, nr1, nz1)`` per segment (shading normals).
    ``seg_arc``
        Float buffer, ``(arc start / total, L / total)`` per segment.
    ``r_max, z_min, z_max``
        Opaque Float scalars: the profile's bounding cylinder (unpadded).
    ``r_bound, z_lo, z_hi``
        Opaque Float scalars: the padded bounding cylinder used for culling.
    ``tol``
        Opaque Float scalar: the absolute joint tolerance.
    ``total_length``
        Python float: total profile arclength.
    ``n_seg``
        Python int: number of segments.
    """

    def __init__(self, **kwargs) -> None:
        for key, value in kwargs.items():
            setattr(self, key, value)


#: Result types (shared with the B-spline kernel).
PolylineHit = LatheHit
PolylineGeometry = LatheGeometry


# ---------------------------------------------------------------------------
# Building the data (numpy, once per profile)
# ---------------------------------------------------------------------------

def build_polyline_data(r0, z0, r1, z1, nr0, nz0, nr1, nz1) -> PolylineData:
    """Pack a polyline profile into opaque Dr.Jit buffers.

    Parameters are numpy float64 arrays of length ``n_seg``: segment end
    points ``(r0, z0) -> (r1, z1)`` (clockwise profile, interior on the right,
    closed, no segment on the axis) and unit shading normals ``(nr0, nz0)``
    at the start and ``(nr1, nz1)`` at the end of every segment.
    """
    r0, z0, r1, z1, nr0, nz0, nr1, nz1 = (
        np.asarray(a, dtype=np.float64).ravel()
        for a in (r0, z0, r1, z1, nr0, nz0, nr1, nz1))
    n_seg = len(r0)
    if n_seg == 0:
        raise ValueError('build_polyline_data(): empty profile')
    if np.any(r0 < 0) or np.any(r1 < 0):
        raise ValueError('build_polyline_data(): negative radius')
    dr_ = r1 - r0
    dz_ = z1 - z0
    length = np.hypot(dr_, dz_)
    if np.any(length <= 0):
        raise ValueError('build_polyline_data(): zero-length segment')

    r_max = float(max(r0.max(), r1.max()))
    z_min = float(min(z0.min(), z1.min()))
    z_max = float(max(z0.max(), z1.max()))
    scale = max(r_max, z_max - z_min)
    tol = TOL_REL * scale
    pad = _BOX_PAD * tol

    # Supporting line n_r r + n_z z = c with the outward (left-hand) normal
    n_r = -dz_ / length
    n_z = dr_ / length
    c = n_r * r0 + n_z * z0
    leaf_rec = np.stack([n_r, n_z, c, r0, z0, dr_ / length**2,
                         dz_ / length**2, tol / length], axis=1)

    # Segment boxes in the (r, z) plane, padded for the joint tolerance
    lo_r = np.maximum(np.minimum(r0, r1) - pad, 0.0)
    hi_r = np.maximum(r0, r1) + pad
    lo_z = np.minimum(z0, z1) - pad
    hi_z = np.maximum(z0, z1) + pad
    recs, links, n_nodes = threaded_bvh(
        np.stack([lo_r, hi_r, lo_z, hi_z], axis=1),
        # Inner node: the "cylinder" line (1, 0, rmax) and the box (see _visit).
        lambda b: [1.0, 0.0, b[1], b[0] * b[0], b[2], b[3], 0.0, 0.0],
        lambda k, b: leaf_rec[k],
    )

    arc = np.concatenate([[0.0], np.cumsum(length)])
    total = float(arc[-1])
    seg_geo = np.stack([n_r, n_z, dr_ * total / length,
                        dz_ * total / length], axis=1)
    seg_sh = np.stack([nr0, nz0, nr1, nz1], axis=1)
    seg_arc = np.stack([arc[:-1] / total, length / total], axis=1)

    def opaque(value):
        dr.make_opaque(value)
        return value

    return PolylineData(
        nodes=opaque(mi.Float(np.asarray(recs, dtype=np.float32).ravel())),
        links=opaque(mi.UInt32(np.asarray(links, dtype=np.uint32))),
        n_nodes=opaque(mi.UInt32(n_nodes)),
        seg_geo=opaque(mi.Float(seg_geo.astype(np.float32).ravel())),
        seg_sh=opaque(mi.Float(seg_sh.astype(np.float32).ravel())),
        seg_arc=opaque(mi.Float(seg_arc.astype(np.float32).ravel())),
        r_max=opaque(mi.Float(r_max)),
        z_min=opaque(mi.Float(z_min)),
        z_max=opaque(mi.Float(z_max)),
        r_bound=opaque(mi.Float(r_max + 2 * pad)),
        z_lo=opaque(mi.Float(z_min - 2 * pad)),
        z_hi=opaque(mi.Float(z_max + 2 * pad)),
        tol=opaque(mi.Float(tol)),
        total_length=total,
        n_seg=n_seg,
    )


# ---------------------------------------------------------------------------
# Ray set-up and one traversal step (Dr.Jit, traced)
# ---------------------------------------------------------------------------

class _Ray:
    """Per-ray constants of a traversal, with the origin moved into place."""

    def __init__(self, data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                 tmax: mi.Float, active: mi.Bool) -> None:
        a_xy = dr.fma(d.x, d.x, d.y * d.y)
        # z slab of the bounding cylinder (d_z = 0 nudged to avoid 0 * inf)
        dz = dr.select(d.z == 0, 1e-30, d.z)
        inv_dz = dr.rcp(dz)
        zl = (data.z_lo - o.z) * inv_dz
        zh = (data.z_hi - o.z) * inv_dz
        # Radial interval of the (far) original origin: r(s) <= r_bound
        b_xy = dr.fma(o.x, d.x, o.y * d.y)
        c_xy = dr.fma(o.x, o.x, o.y * o.y)
        cross = dr.fma(o.x, d.y, -o.y * d.x)
        r_lo, r_hi = _radial_interval(a_xy, b_xy, c_xy, cross, data.r_bound)
        lo = dr.maximum(dr.minimum(zl, zh), r_lo)
        hi = dr.minimum(dr.maximum(zl, zh), r_hi)

        # Move the origin to the bounding cylinder entry (traps.md: a far
        # origin cancels catastrophically in the quadratic's constant term)
        s_enter = dr.maximum(lo, 0)
        self.active = active & (lo <= hi) & (hi > 0) & (s_enter < tmax)
        s_enter = dr.select(self.active, s_enter, 0)
        self.s_enter = s_enter
        self.o = mi.Point3f(dr.fma(d.x, s_enter, o.x),
                            dr.fma(d.y, s_enter, o.y),
                            dr.fma(d.z, s_enter, o.z))
        self.d = mi.Vector3f(d)
        # Hits need t = s_enter + s in (0, tmax); the padded cylinder also
        # bounds s from above (exit point)
        self.s_lo = -s_enter
        self.s_hi = dr.minimum(tmax - s_enter, hi - s_enter)
        self.tmax = tmax

        # Quadratic pieces in the moved frame: r(s)^2 = a s^2 + 2 b s + c
        ox, oy = self.o.x, self.o.y
        self.a_xy = a_xy
        self.b_xy = dr.fma(ox, d.x, oy * d.y)
        self.c_xy = dr.fma(ox, ox, oy * oy)
        self.r_o = dr.sqrt(self.c_xy)
        self.cross = dr.fma(ox, d.y, -oy * d.x)
        self.inv_dz = inv_dz
        self.parallel = a_xy == 0
        # Tolerance on |w| - |n_r cross| (units of length times |d|)
        self.tol_d = data.tol * dr.norm(d)
        # Traversal copy: lower child first when going up, outer child first
        # when moving towards the axis
        copy = dr.select(d.z >= 0, 0, 2) + dr.select(self.b_xy <= 0, 0, 1)
        self.first = mi.UInt32(copy) * data.n_nodes
        self.end = self.first + data.n_nodes


def _radial_interval(a_xy, b_xy, c_xy, cross, rmax):
    """Interval of ``s`` where ``r(s) <= rmax`` (empty: ``lo > hi``).

    ``a s^2 + 2 b s + c - rmax^2 <= 0``; the discriminant
    ``b^2 - a (c - rmax^2) = a rmax^2 - cross^2`` is evaluated factored.
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


def _visit(data: PolylineData, ray: _Ray, node: mi.UInt32, s_best: mi.Float,
           active: mi.Bool):
    """Process one node: box test for inner nodes, segment test for leaves.

    Returns ``(next_node, s_hit, u_hit, seg, hit)``; ``hit`` marks a leaf
    whose segment is hit at ``s_hit < s_best``.
    """
    rec0 = dr.gather(mi.Vector4f, data.nodes, node * 2, active)
    rec1 = dr.gather(mi.Vector4f, data.nodes, node * 2 + 1, active)
    link = dr.gather(mi.UInt32, data.links, node, active)
    is_leaf = (link & LEAF) != 0
    n_r, n_z, c = rec0.x, rec0.y, rec0.z
    o, d = ray.o, ray.d

    # Quadratic of eqs. 2-3 for n_r^2 r(s)^2 = (h0 + h1 s)^2 (inner nodes use
    # the cylinder r = rmax: n_r = 1, n_z = 0, c = rmax)
    nr2 = n_r * n_r
    h0 = dr.fma(-n_z, o.z, c)
    h1 = -n_z * d.z
    qa = dr.fma(nr2, ray.a_xy, -h1 * h1)
    qb = dr.fma(nr2, ray.b_xy, -h0 * h1)
    qc = (n_r * ray.r_o - h0) * (n_r * ray.r_o + h0)
    # qb^2 - qa qc = n_r^2 (|h0 d_xy - h1 o_xy|^2 - n_r^2 cross^2), factored
    wx = dr.fma(h0, d.x, -h1 * o.x)
    wy = dr.fma(h0, d.y, -h1 * o.y)
    wl = dr.sqrt(dr.fma(wx, wx, wy * wy))
    cr = dr.abs(n_r * ray.cross)
    disc = (wl - cr) * (wl + cr)
    # Near-tangent rays (within the joint tolerance, e.g. through a cone apex
    # on the axis, where the roots are double) keep their double root
    has_root = wl - cr >= -ray.tol_d
    root = dr.abs(n_r) * dr.sqrt(dr.maximum(disc, 0))
    # Stable roots: q = -(b + sign(b) sqrt(disc)), s = q / a and c / q
    q = -(qb + dr.copysign(root, qb))
    s1 = q / qa
    s2 = qc / q

    # --- Inner node: annular box [rmin, rmax] x [zmin, zmax]
    zl = (rec1.x - o.z) * ray.inv_dz
    zh = (rec1.y - o.z) * ray.inv_dz
    inside = ray.c_xy <= c * c
    r_lo = dr.select(ray.parallel, dr.select(inside, -dr.inf, dr.inf),
                     dr.select(has_root, dr.minimum(s1, s2), dr.inf))
    r_hi = dr.select(ray.parallel, dr.inf, dr.maximum(s1, s2))
    lo = dr.maximum(dr.maximum(dr.minimum(zl, zh), r_lo), ray.s_lo)
    hi = dr.minimum(dr.minimum(dr.maximum(zl, zh), r_hi), s_best)
    # r(s)^2 is convex: its maximum over [lo, hi] is at an end point
    r2_lo = dr.fma(dr.fma(ray.a_xy, lo, 2 * ray.b_xy), lo, ray.c_xy)
    r2_hi = dr.fma(dr.fma(ray.a_xy, hi, 2 * ray.b_xy), hi, ray.c_xy)
    box_hit = (lo <= hi) & ((r2_lo >= rec0.w) | (r2_hi >= rec0.w))

    # --- Leaf: accept a root whose point projects into the segment
    r0, z0, er, ez, tol_u = rec0.w, rec1.x, rec1.y, rec1.z, rec1.w
    tol_n = data.tol * nr2

    def accept(s):
        px = dr.fma(d.x, s, o.x)
        py = dr.fma(d.y, s, o.y)
        pz = dr.fma(d.z, s, o.z)
        # Fraction along the segment from the measured (r, z) of the point
        u = dr.fma(dr.sqrt(dr.fma(px, px, py * py)) - r0, er, (pz - z0) * ez)
        # Reject the mirror nappe: n_r (c - n_z z) = n_r^2 r must be >= 0
        nappe = n_r * dr.fma(-n_z, pz, c) >= -tol_n
        ok = (has_root & (s > ray.s_lo) & (s < s_best) & (u >= -tol_u)
              & (u <= 1 + tol_u) & nappe)
        return ok, u

    ok1, u1 = accept(s1)
    ok2, u2 = accept(s2)
    take2 = ok2 & (~ok1 | (s2 < s1))
    s_hit = dr.select(take2, s2, s1)
    u_hit = dr.select(take2, u2, u1)
    hit = active & is_leaf & (ok1 | ok2)

    next_node = dr.select(~is_leaf & ~box_hit, link, node + 1)
    return next_node, s_hit, u_hit, link & ~mi.UInt32(LEAF), hit


# ---------------------------------------------------------------------------
# Public kernels
# ---------------------------------------------------------------------------

@dr.syntax
def intersect_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                       tmax: mi.Float, active: mi.Bool) -> PolylineHit:
    """Nearest intersection with ``0 < t < tmax`` of the ray ``o + t d``.

    ``o`` and ``d`` are in the lathe's local frame; ``d`` need not be unit
    length and ``t`` is measured in units of ``d``. Traceable inside an outer
    symbolic loop (no evaluation happens here).
    """
    ray = _Ray(data, o, d, tmax, active)
    node = mi.UInt32(ray.first)          # current node of the threaded BVH
    s_best = mi.Float(ray.s_hi)          # nearest hit so far (moved frame)
    seg = dr.zeros(mi.UInt32, dr.width(s_best))  # its segment
    u = dr.zeros(mi.Float, dr.width(s_best))     # its fraction along seg
    found = dr.zeros(mi.Bool, dr.width(s_best))  # whether a hit was found
    while ray.active & (node < ray.end):
        node_next, s_hit, u_hit, seg_hit, hit = _visit(
            data, ray, node, s_best, ray.active & (node < ray.end))
        s_best = dr.select(hit, s_hit, s_best)
        u = dr.select(hit, u_hit, u)
        seg = dr.select(hit, seg_hit, seg)
        found |= hit
        node = node_next

    t = ray.s_enter + s_best
    valid = found & (t > 0) & (t < tmax)
    return PolylineHit(t=dr.select(valid, t, dr.inf), seg=seg,
                       u=dr.clip(u, 0, 1), valid=valid)


@dr.syntax
def occluded_polyline(data: PolylineData, o: mi.Point3f, d: mi.Vector3f,
                      tmax: mi.Float, active: mi.Bool) -> mi.Bool:
    """Whether the ray ``o + t d`` hits the lathe for some ``0 < t < tmax``.

    Same conventions as :func:`intersect_polyline`; stops at the first hit.
    """
    ray = _Ray(data, o, d, tmax, active)
    node = mi.UInt32(ray.first)          # current node of the threaded BVH
    found = dr.zeros(mi.Bool, dr.width(node))  # whether any hit was found
    while ray.active & (node < ray.end) & ~found:
        node_next, s_hit, _, _, hit = _visit(
            data, ray, node, ray.s_hi, ray.active & (node < ray.end))
        t = ray.s_enter + s_hit
        found |= hit & (t > 0) & (t < tmax)
        node = node_next
    return found


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

    # Azimuth of the hit point (any azimuth on the axis, traps.md)
    r = dr.sqrt(dr.fma(p.x, p.x, p.y * p.y))
    on_axis = r == 0
    inv_r = dr.select(on_axis, 0, dr.rcp(r))
    cos_phi = dr.select(on_axis, 1, p.x * inv_r)
    sin_phi = dr.select(on_axis, 0, p.y * inv_r)

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
    dp_dv = mi.Vector3f(geo.z * cos_phi, geo.z * sin_phi, geo.w)
    return PolylineGeometry(n=n, sh_n=sh_n, uv=uv, dp_du=dp_du, dp_dv=dp_dv)
