"""Caustics seen through glass: the light tracer's camera connection through
a chain of Dirac-delta vertices, found by Newton's method (eqs. 37-40 of
docs/method.md; used by :mod:`~lathe_shape.plugin.caustic_paths` and
``lathe_path``).

A caustic on the floor behind a bottle reaches the camera through the
bottle's walls: ``camera -> S'_1 ... S'_m -> D -> S_1 ... S_k -> light``. A
particle that lands on ``D`` cannot be joined to the pinhole by a straight
shadow ray; instead :func:`solve_camera_chain` looks for the camera
direction whose ray, refracted (or reflected) through the chain, lands on
``D``: manifold next-event estimation towards the camera (Hanika et al.
2015), with the chain parametrised by the camera direction (eq. 37), so
that every iterate is a valid specular chain traced by the exact kernels,
and only its end is off ``D``.

The solution is a function of ``D`` alone (eq. 38): the branch at every
vertex is fixed (:data:`POLICY_SAMPLE`: transmission wherever the BSDF has
one, reflection where it has none, as under total internal reflection), the
seed is the straight line from the camera to ``D`` and the iteration is
deterministic. Path tracing, which samples the same paths, runs the same
solver from its own ``D`` and weighs its path against the light tracer's
only where the solver finds that very path (eq. 40): paths the solver
misses (other branches, another solution, no convergence) stay path traced
with weight 1, so nothing is lost and nothing is counted twice.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.top_level import NO_LATHE
from .integrator_base import contradicts
from .line_walk import start_walk
from .media_segments import segment_transmittance

__all__ = ["NEWTON_STEPS", "POLICY_SAMPLE", "ChainSolution", "camera_ray", "chain_vertex", "policy_branch",
           "solve_camera_chain"]

#: Newton steps at most (a chord step traces one chain, a step with a new
#: Jacobian three; the seed is usually within four steps of the solution).
NEWTON_STEPS = 6

#: The branch sample of every chain vertex: the largest float32 below 1,
#: so that a dielectric transmits unless its Fresnel reflectance is 1
#: (total internal reflection) and a mirror reflects.
POLICY_SAMPLE = 0.99999994

#: Finite-difference step in the camera's gnomonic coordinates (eq. 37;
#: about 1/20 of a pixel of a 256-pixel, 30 degree film).
FD_STEP = 1e-4

#: Convergence: distance to ``D`` on its tangent plane, relative to the
#: camera's distance.
TOLERANCE = 1e-4

#: Largest Newton step in gnomonic coordinates.
MAX_STEP = 0.3

#: Two camera directions closer than this (radians) are the same solution.
SAME_SOLUTION = 1e-3


def policy_branch(bs: mi.BSDFSample3f) -> mi.Bool:
    """Whether a Dirac-delta sample took the branch :data:`POLICY_SAMPLE`
    takes: a transmission, or a reflection with nothing else possible."""
    return mi.has_flag(bs.sampled_type, mi.BSDFFlags.Transmission) | (bs.pdf >= 1.0 - 1e-6)


def chain_vertex(si: mi.SurfaceInteraction3f, cos_in_geo: mi.Float, bs: mi.BSDFSample3f,
                 wo: mi.Vector3f) -> mi.Bool:
    """Whether a Dirac-delta vertex can be a vertex of a camera chain (eq.
    40): eq. 11 holds on the incident side (``cos_in_geo``, the cosine of
    the incident direction with the geometric normal) and on the outgoing
    side (``wo``, world), and the sample ``bs`` has a probability and took
    the fixed branch (:func:`policy_branch`). The solver and path tracing's
    weights use this one rule: eq. 40 stays unbiased only where both agree
    exactly."""
    return ((cos_in_geo * mi.Frame3f.cos_theta(si.wi) > 0.0) & (bs.pdf > 0.0) & policy_branch(bs)
            & ~contradicts(si, cos_in_geo, bs, wo))


class ChainSolution:
    """What :func:`solve_camera_chain` found, per lane: ``found``; the camera
    direction ``d`` (world, unit); ``vertices`` (the chain's length);
    ``area_per_solid_angle``, the area on ``D``'s tangent plane swept per
    unit solid angle at the camera (eq. 39); ``branch``, the product of
    the chain's branch probabilities (as path tracing samples them);
    ``throughput``, the product of its BSDF values (radiance mode); and
    ``wo``, the direction at ``D`` towards the chain (world)."""

    def __init__(self, found, d, vertices, area_per_solid_angle, branch, throughput, wo) -> None:
        self.found = found
        self.d = d
        self.vertices = vertices
        self.area_per_solid_angle = area_per_solid_angle
        self.branch = branch
        self.throughput = throughput
        self.wo = wo


def camera_ray(camera: mi.Point3f, d: mi.Vector3f, clip: tuple | None) -> mi.Ray3f:
    """The camera ray from ``camera`` along ``d`` (unit), clipped as
    Mitsuba's perspective camera clips its rays: ``clip`` = (viewing
    direction, near clip, far clip) starts it at depth (along the viewing
    direction) ``near`` and ends it at depth ``far``; ``None``: unclipped."""
    if clip is None:
        return mi.Ray3f(camera, d)
    forward, near, far = clip
    cos_camera = dr.dot(d, forward)
    inv_z = dr.rcp(cos_camera)
    near_t, far_t = near * inv_z, far * inv_z
    ray = mi.Ray3f(camera + d * near_t, d)
    # (no ray behind the camera: it meets nothing)
    ray.maxt = dr.select(cos_camera > 0.0, far_t - near_t, 0.0)
    return ray


@dr.syntax
def solve_camera_chain(geometry, camera: mi.Point3f, p: mi.Point3f, n: mi.Normal3f, shape: mi.ShapePtr,
                       max_vertices: mi.UInt32, active: mi.Bool, media: bool = False,
                       clip: tuple | None = None) -> ChainSolution:
    """Eqs. 37-39: the camera direction whose ray goes through 1 to
    ``max_vertices`` Dirac-delta vertices (branches by
    :data:`POLICY_SAMPLE`, none contradicting eq. 11) and lands on ``D``
    (point ``p``, geometric normal ``n``, on ``shape``), by Newton's method
    from the straight line with forward-difference Jacobians (eq. 38; kept
    for chord steps while the residual halves), and eq. 39's area from the
    Jacobian at the solution. With ``media`` the throughput holds the
    transmittance (eq. 44) of the homogeneous media along the chain (the camera in
    none). ``clip``: the camera's (viewing direction, near clip, far clip),
    which clip every chain's first segment as the camera's rays are clipped
    (:func:`camera_ray`: the first vertex must lie in the clip range, and
    nothing nearer the camera occludes); ``None``: unclipped. ``geometry``: the scene's
    :class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry`. One
    query per loop iteration: the lathe traversal is compiled once."""
    width = dr.width(p)
    ctx = mi.BSDFContext()
    to_d = p - camera
    distance = dr.norm(to_d)
    forward = to_d / distance
    e1, e2 = mi.coordinate_system(forward)   # camera-side directions of the gnomonic plane
    t1, t2 = mi.coordinate_system(n)         # D's tangent plane
    tolerance = TOLERANCE * distance
    h = FD_STEP

    a = mi.Float(0.0)                        # Gnomonic coordinates of the current direction (eq. 37)
    b = mi.Float(0.0)
    trace = mi.UInt32(0)                     # Which chain is traced: 0 at (a, b), 1 at +a, 2 at +b
    steps = mi.UInt32(0)                     # Newton steps taken
    going = mi.Bool(active)                  # Lanes still solving
    ray = camera_ray(camera, forward, clip)  # Current ray of the chain being traced
    walk = start_walk(width)                 # Its line and last lathe crossing
    m = mi.UInt32(0)                         # Vertices of the chain being traced
    branch = mi.Float(1.0)                   # Its branch probabilities' product
    throughput = mi.Spectrum(1.0)            # ... and BSDF values' product (and transmittances)
    medium = dr.zeros(mi.MediumPtr, width)   # ... medium of its current segment (with media)
    q0 = mi.Point3f(0.0)                     # Landing points on D's tangent plane: trace 0
    q1 = mi.Point3f(0.0)                     # ... trace 1
    m0 = mi.UInt32(0)                        # Trace 0's vertex count
    converged = mi.Bool(False)               # Trace 0 landed on D: traces 1-2 for eq. 39 follow
    j11 = mi.Float(0.0)                      # Jacobian of eq. 38 (kept for chord steps)
    j12 = mi.Float(0.0)
    j21 = mi.Float(0.0)
    j22 = mi.Float(0.0)
    have_jacobian = mi.Bool(False)           # ... once traces 0-2 made one
    last_residual = mi.Float(dr.inf)         # Residual at the last step
    found = mi.Bool(False)                   # Solved
    d_found = mi.Vector3f(0.0)               # The solution's camera direction,
    area = mi.Float(0.0)                     # ... eq. 39's area per solid angle,
    branch_found = mi.Float(0.0)             # ... branch probabilities,
    throughput_found = mi.Spectrum(0.0)      # ... BSDF values
    wo_found = mi.Vector3f(0.0)              # ... and direction at D towards the chain
    while going:
        si, walk, _ = geometry.walk_and_test(ray, going, walk)
        valid = si.is_valid()
        if dr.hint(media, mode="scalar"):
            # Eq. 44: the segment's transmittance
            throughput[going & valid] *= segment_transmittance(medium, ray.o, si.t, going & valid)
        bsdf = si.bsdf(ray)
        delta = valid & ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        through = going & delta & (m < max_vertices)
        cos_in_geo = dr.dot(si.n, -ray.d)
        bs, weight = bsdf.sample(ctx, si, POLICY_SAMPLE, mi.Point2f(0.5), through)
        wo = si.to_world(bs.wo)
        bad = through & ~chain_vertex(si, cos_in_geo, bs, wo)
        branch[through] *= bs.pdf
        throughput[through] *= weight * bs.pdf
        m[through] += 1
        if dr.hint(media, mode="scalar"):
            medium[through & si.is_medium_transition()] = si.target_medium(wo)
        next_ray = si.spawn_ray(wo)

        # ---- A chain ends: its landing point on D's tangent plane ----
        ends = going & ~through
        along = dr.dot(ray.d, n)
        landing = ray(dr.dot(p - ray.o, n) / along)
        lands = ends & ~bad & (m >= 1) & (dr.abs(along) > 1e-6) & (dr.dot(landing - ray.o, ray.d) > 0.0)
        # Trace 0 must end on D's own surface; the others only on the plane,
        # with as many vertices
        lands &= dr.select(trace == 0, valid & ~delta & (si.shape == shape), m == m0)
        failed = (going & bad) | (ends & ~lands)
        q0[ends & (trace == 0)] = landing
        q1[ends & (trace == 1)] = landing
        m0[ends & (trace == 0)] = m
        wo_found[ends & (trace == 0)] = -ray.d
        branch_found[ends & (trace == 0)] = branch
        throughput_found[ends & (trace == 0)] = throughput
        r = landing - p
        close = ends & (trace == 0) & lands & (dr.norm(r) < tolerance) & (dr.norm(si.p - p) < tolerance)
        converged |= close

        # ---- Eq. 38: a Newton step, with a Jacobian from traces 0-2 kept
        # while the residual at least halves at each step (a chord step:
        # one trace instead of three) ----
        r1, r2 = dr.dot(q0 - p, t1), dr.dot(q0 - p, t2)
        residual = dr.sqrt(r1 * r1 + r2 * r2)
        after_0 = ends & lands & (trace == 0) & ~converged
        chord = after_0 & have_jacobian & (residual < 0.5 * last_residual)
        fresh = ends & lands & (trace == 2) & ~converged
        j11[fresh] = dr.dot(q1 - q0, t1) / h
        j21[fresh] = dr.dot(q1 - q0, t2) / h
        j12[fresh] = dr.dot(landing - q0, t1) / h
        j22[fresh] = dr.dot(landing - q0, t2) / h
        have_jacobian |= fresh
        newton = chord | fresh
        det = j11 * j22 - j12 * j21
        da = (j22 * r1 - j12 * r2) / det
        db = (j11 * r2 - j21 * r1) / det
        length = dr.sqrt(da * da + db * db)
        shrink = dr.select(length > MAX_STEP, MAX_STEP / length, 1.0)
        usable = dr.isfinite(length) & (dr.abs(det) > 0.0)
        # (a residual that grew since the last step: not converging)
        failed |= newton & (~usable | (steps + 1 >= NEWTON_STEPS) | (residual > last_residual))
        a[newton] -= da * shrink
        b[newton] -= db * shrink
        last_residual[newton] = residual
        steps[newton] += 1

        # ---- Eq. 39 after traces 1-2 at the solution (forward differences:
        # central ones, two traces more, differ by 0.5% on average and
        # 0.03% in the mean on the brandy bottle's floor) ----
        done = ends & lands & (trace == 2) & converged
        gnomonic = 1.0 + a * a + b * b       # solid angle = da db / gnomonic^1.5
        f11, f21 = dr.dot(q1 - q0, t1) / h, dr.dot(q1 - q0, t2) / h
        f12, f22 = dr.dot(landing - q0, t1) / h, dr.dot(landing - q0, t2) / h
        area[done] = dr.abs(f11 * f22 - f12 * f21) * gnomonic * dr.sqrt(gnomonic)
        d_found[done] = dr.normalize(forward + a * e1 + b * e2)
        found |= done & (area > 0.0) & dr.isfinite(area)

        # ---- Next chain: which trace, from the camera ----
        # (0 -> 0 after a chord step, 0 -> 1 -> 2 -> 0 for a fresh Jacobian,
        # 0 -> 1 -> 2 -> done once trace 0 converged)
        trace[ends] = dr.select(trace == 2, 0, dr.select(chord, 0, trace + 1))
        going &= ~failed & ~done
        da_next = dr.select(trace == 1, h, 0.0)
        db_next = dr.select(trace == 2, h, 0.0)
        direction = dr.normalize(forward + (a + da_next) * e1 + (b + db_next) * e2)
        restart = ends & going
        ray = dr.select(restart, camera_ray(camera, direction, clip), next_ray)
        walk.lathe = dr.select(restart, NO_LATHE, walk.lathe)
        m[restart] = 0
        branch[restart] = 1.0
        throughput[restart] = 1.0
        if dr.hint(media, mode="scalar"):
            medium[restart] = dr.zeros(mi.MediumPtr, width)
    return ChainSolution(found, d_found, m0, area, branch_found, throughput_found, wo_found)
