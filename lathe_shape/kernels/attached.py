"""Hits on a lathe that carry derivatives with respect to its profile points.

The exact kernels (polyline.py, bspline.py) find the hit ``(t, seg, u)``
detached, in float32, in their unit frame. This module re-derives the hit's
distance, position and normals from that solution and from the profile
points as a differentiable Dr.Jit array, by implicit differentiation of the
root (docs/method.md, eqs. 21-25): one Newton-type correction whose value is
zero (so every primal value stays the kernel's) and whose derivative is the
root's. The functions work in the lathe's local frame and in the user's
units; ``points`` is the flat ``(r, z)`` array of the ``points`` scene
parameter, gathered through the index maps of
:class:`lathe_shape.plugin.profile_param.ProfileIndex`.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["AttachedHit", "attached_polyline", "attached_bspline", "profile_point"]


class AttachedHit:
    """Local-frame hit: distance ``t`` along the ray, position ``p``,
    geometric unit normal ``n`` and shading unit normal ``sh_n``."""

    def __init__(self, t, p, n, sh_n) -> None:
        self.t, self.p, self.n, self.sh_n = t, p, n, sh_n


def _point(points: mi.Float, index: mi.UInt32, active, held: mi.Bool | None = None) -> mi.Point2f:
    """User point ``index`` as ``(r, z)``. Where ``held`` (per user point)
    is set, the point lies on the axis and stays there: its ``r`` is 0 with
    no derivative (a profile's ends on the axis are a constraint, not a
    free coordinate; an optimiser that moved one off the axis by its
    rounding-sized or B-spline-sized derivative made an open profile, which
    the next update refused)."""
    r = dr.gather(mi.Float, points, 2 * index, active)
    if held is not None:
        r = dr.select(dr.gather(mi.Bool, held, index, active), 0.0, r)
    return mi.Point2f(r, dr.gather(mi.Float, points, 2 * index + 1, active))


def _controls(points: mi.Float, index, seg: mi.UInt32, active) -> list[mi.Point2f]:
    """The 4 B-spline control points of segment ``seg``: user points, or
    for the kinds converted to B-splines weighted sums of ``index.width``
    user points each (eq. 18)."""
    width = index.width
    controls = []
    for k in range(4):
        if index.weights is None:
            controls.append(_point(points, dr.gather(mi.UInt32, index.controls, 4 * seg + k, active), active,
                                   index.held))
            continue
        control = mi.Point2f(0.0)
        for j in range(width):
            slot = (4 * seg + k) * width + j
            weight = dr.gather(mi.Float, index.weights, slot, active)
            control += weight * _point(points, dr.gather(mi.UInt32, index.controls, slot, active), active,
                                       index.held)
        controls.append(control)
    return controls


def _segment(points: mi.Float, index, seg: mi.UInt32, active):
    """Start point, direction and outward unit normal (eqs. 8-9) of segment
    ``seg`` (``index``: the lathe's ``ProfileIndex``)."""
    p0 = _point(points, dr.gather(mi.UInt32, index.ends, 2 * seg, active), active, index.held)
    p1 = _point(points, dr.gather(mi.UInt32, index.ends, 2 * seg + 1, active), active, index.held)
    delta = p1 - p0
    normal = mi.Vector2f(-delta.y, delta.x) * dr.rsqrt(dr.squared_norm(delta))
    return p0, delta, normal


def _azimuth(p: mi.Point3f):
    """``(rho, cos, sin)`` of a local point (``cos = 1`` on the axis)."""
    rho = dr.sqrt(dr.fma(p.x, p.x, p.y * p.y))
    on_axis = rho == 0
    inv = dr.select(on_axis, 0.0, dr.rcp(rho))
    return rho, dr.select(on_axis, 1.0, p.x * inv), dr.select(on_axis, 0.0, p.y * inv)


def _revolve(v: mi.Vector2f, cos_phi, sin_phi) -> mi.Vector3f:
    """The profile-plane vector ``(r, z)`` turned to the azimuth."""
    return mi.Vector3f(v.x * cos_phi, v.x * sin_phi, v.y)


def _corrected(value, residual, slope, ok):
    """Eq. 21: ``value - (residual - detach(residual)) / slope``: the value
    unchanged, the derivative that of the root of ``residual = 0``."""
    step = (residual - dr.detach(residual)) / slope
    return dr.select(ok, value - step, value)


def _end_normal(points, index, own, seg, end, active) -> mi.Vector2f:
    """Eq. 10's vertex normal at one end (0: start, 1: end) of ``seg``:
    ``normalize(w_own n_seg + w_nb n_neighbour + c)``, whose weights say
    whether the vertex is averaged, a crease, or a smooth cap's axial end
    (see ``ProfileIndex``); the choice itself is fixed (not differentiated)."""
    k = 2 * seg + end
    w = dr.gather(mi.Vector4f, index.blend, k, active)
    nb = dr.gather(mi.UInt32, index.neighbour, k, active)
    _, _, nb_normal = _segment(points, index, nb, active & (w.y != 0))
    v = w.x * own + mi.Vector2f(dr.select(w.y != 0, nb_normal, 0.0)) + mi.Vector2f(w.z, w.w)
    return dr.normalize(v)


def attached_polyline(points: mi.Float, index, o: mi.Point3f, d: mi.Vector3f, t: mi.Float,
                      seg: mi.UInt32, smooth: bool, active: mi.Bool) -> AttachedHit:
    """Attached hit on polyline segment ``seg`` of the detached root ``t`` of
    the local ray ``o + t d`` (``index``: the lathe's ``ProfileIndex``).

    The segment's line ``n_r r + n_z z = c`` gives the implicit function
    ``F = n_r rho(t) + n_z z(t) - c`` (eq. 22), whose root moves by
    ``dt = -dF / (dF/dt)`` with ``dF/dt = n . d`` (eq. 23); ``p`` follows
    eq. 3, ``n`` eqs. 8-9 and ``sh_n`` eq. 10 at the attached point."""
    p0, delta, normal = _segment(points, index, seg, active)
    x = o + dr.detach(t) * d  # the detached root on the (possibly moving) ray
    rho, cos_phi, sin_phi = _azimuth(x)
    residual = normal.x * rho + normal.y * x.z - dr.dot(normal, p0)
    slope = dr.detach(dr.dot(_revolve(normal, cos_phi, sin_phi), d))
    t_att = _corrected(t, residual, slope, active & (slope != 0))
    p = o + t_att * d
    rho, cos_phi, sin_phi = _azimuth(p)
    n = _revolve(normal, cos_phi, sin_phi)
    if not smooth:
        return AttachedHit(t_att, p, n, mi.Vector3f(n))
    # Eq. 10: the end normals interpolated at the attached fraction u
    u = dr.dot(mi.Point2f(rho, p.z) - p0, delta) / dr.squared_norm(delta)
    n0 = _end_normal(points, index, normal, seg, 0, active)
    n1 = _end_normal(points, index, normal, seg, 1, active)
    sh = dr.normalize(dr.lerp(n0, n1, u))
    return AttachedHit(t_att, p, n, _revolve(sh, cos_phi, sin_phi))


def _cubic_basis(u):
    """Uniform cubic B-spline basis functions at ``u`` (eq. 12) and their
    derivatives."""
    v = 1.0 - u
    u2, u3 = u * u, u * u * u
    b = [v * v * v / 6, (3 * u3 - 6 * u2 + 4) / 6, (-3 * u3 + 3 * u2 + 3 * u + 1) / 6, u3 / 6]
    db = [-v * v / 2, (3 * u2 - 4 * u) / 2, (-3 * u2 + 2 * u + 1) / 2, u2 / 2]
    return b, db


def _curve(controls, u):
    """``(R, Z)`` and ``(R', Z')`` of the segment with the 4 control points
    ``controls`` at parameter ``u``."""
    b, db = _cubic_basis(u)
    value = b[0] * controls[0] + b[1] * controls[1] + b[2] * controls[2] + b[3] * controls[3]
    tangent = db[0] * controls[0] + db[1] * controls[1] + db[2] * controls[2] + db[3] * controls[3]
    return value, tangent


def attached_bspline(points: mi.Float, index, o: mi.Point3f, d: mi.Vector3f, t: mi.Float,
                     seg: mi.UInt32, u: mi.Float, active: mi.Bool) -> AttachedHit:
    """Attached hit on B-spline segment ``seg`` of the detached solution
    ``(t, u)`` of the local ray ``o + t d``.

    The hit solves ``G = (z(t) - Z(u), rho(t) - R(u)) = 0`` (eqs. 13-15,
    unsquared); one Newton step with the detached Jacobian moves ``(t, u)``
    by ``-J^-1 dG`` (eq. 24), and the normal follows eq. 16 at the attached
    ``u`` (the segment's chord where the tangent vanishes, as the kernel)."""
    controls = _controls(points, index, seg, active)
    x = o + dr.detach(t) * d  # the detached root on the (possibly moving) ray
    rho, cos_phi, sin_phi = _azimuth(x)
    curve, tangent = _curve(controls, u)
    g_z = x.z - curve.y
    g_r = rho - curve.x
    # Jacobian of G in (t, u), detached: [[d_z, -Z'], [drho/dt, -R']]
    drho = dr.detach((x.x * d.x + x.y * d.y) * dr.select(rho > 0, dr.rcp(rho), 0.0))
    tr, tz = dr.detach(tangent.x), dr.detach(tangent.y)
    det = -d.z * tr + tz * drho
    ok = active & (dr.abs(det) > 1e-12 * (dr.abs(d.z) + dr.abs(drho)) * (dr.abs(tr) + dr.abs(tz)))
    # Eq. 24: (t, u) - J^-1 (G - detach(G)), by Cramer's rule
    t_att = _corrected(t, -tr * g_z + tz * g_r, det, ok)
    u_att = _corrected(u, -drho * g_z + d.z * g_r, det, ok)
    p = o + t_att * d
    _, cos_phi, sin_phi = _azimuth(p)
    _, tangent = _curve(controls, u_att)
    chord = controls[3] + 3 * controls[2] - 3 * controls[1] - controls[0]  # 6 (C(1) - C(0))
    speed2 = dr.squared_norm(tangent)
    degenerate = speed2 <= 1e-24 * dr.squared_norm(chord)
    tangent = dr.select(degenerate, chord, tangent)
    normal = dr.normalize(mi.Vector2f(-tangent.y, tangent.x))
    n = _revolve(normal, cos_phi, sin_phi)
    return AttachedHit(t_att, p, n, mi.Vector3f(n))


def profile_point(points: mi.Float, index, kernel: str, seg: mi.UInt32,
                  u: mi.Float) -> tuple[mi.Float, mi.Float]:
    """``(R, Z)`` of the profile at ``(seg, u)``, attached to ``points``
    (``kernel``: the kind's kernel, ``"polyline"``, whose segment is
    ``p0 + u (p1 - p0)``, or ``"bspline"``, eq. 12)."""
    active = mi.Bool(True)
    if kernel == "bspline":
        controls = _controls(points, index, seg, active)
        value, _ = _curve(controls, u)
        return value.x, value.y
    p0, delta, _ = _segment(points, index, seg, active)
    return p0.x + u * delta.x, p0.y + u * delta.y
