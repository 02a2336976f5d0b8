"""Caustic paths traced from the lights (``lathe_path``'s ``caustics``).

A caustic on a floor is light that reached the floor through glass:
light -> one or more specular vertices -> a diffuse vertex ``D`` -> camera.
Path tracing meets such a path only when the BSDF sample at ``D`` happens to
leave through the glass towards the light, which makes the speckles of a
low-spp frame. Traced from the light instead, the same path is found every
time the light's particle goes through the glass: it lands on ``D`` and is
connected to the camera there (a light tracer's ``t = 1`` connection).

Both techniques sample the same paths, so they are combined by multiple
importance sampling (the power heuristic) and nothing is counted twice:

* The **caustic class** is every path ``camera -> D -> S_1 ... S_k -> light``
  with ``D`` the camera ray's first hit, a surface that is neither an exact
  lathe nor a pure Dirac delta and sampled with its smooth lobes; ``S_1 ...
  S_k`` (``1 <= k <= max_chain``) surfaces whose BSDF is pure Dirac
  delta (``dielectric``, ``thindielectric``, ``conductor``, ``null``), at
  least one of them a vertex that path tracing's shadow rays cannot cross
  (:func:`blocks_shadow_rays`: in ``lathe_volpath`` not every one a null
  crossing, which emitter sampling samples); and the
  light an area emitter, a point, spot or directional light or the
  environment. Also ``camera -> S'_1 ... S'_m -> D -> ...``: ``D`` seen
  through Dirac deltas, joined to the camera along the chain that
  :mod:`~lathe_shape.plugin.camera_chain` solves for (eqs. 37-40).
* Every other path is path traced alone, as before.
* On a caustic path, the two techniques' densities share the chain's
  generalized geometry term, which cancels in their ratio: eq. 32 of
  docs/method.md needs only the camera's and the BSDF's densities at
  ``D`` and the light's at ``L``. Path tracing cannot sample a point or
  spot light's caustic at all: there the light tracer's weight is 1. (Its
  emitter sampling cannot sample a caustic path either: the chain holds a
  vertex its shadow rays do not cross.)

The light tracer aims its particles at the lathes: directions are drawn
uniformly in the cone from the light point around one of a few spheres that
cover every exact lathe (eq. 33), and the same density enters the weights,
so directions outside the cones belong to path tracing alone. The estimator
stays unbiased for any spheres.

A directional light's particles come from far back through a point drawn
uniformly on the disk of one of those spheres that faces the light (eq. 34);
path tracing cannot hit a directional light either. (They start just outside
a sphere around all the spheres, where a shadow ray from there towards the
light finds nothing: the light then reaches that start as it would from far
back, and float32 keeps the line at the glass's scale in a scene of any
size; where it finds something they start from beyond the scene.) An environment map's
come the same way along a direction of its own sampling (eq. 35); a uniform
``constant`` sky sends none (path tracing meets it in every direction).
Each light sends particles in proportion to its power into the cones
(eq. 36).

The camera connection is the camera rays' (:class:`PinholeCamera`): only
points (or a chain's first vertex) at a depth within the sensor's
``near_clip`` .. ``far_clip`` are seen, only what lies in that range
occludes, and a ``principal_point_offset`` shifts the film.

Limits (each falls back to path tracing alone, unbiased): RGB variants,
a pinhole ``perspective`` sensor, not with ``hide_emitters``.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.top_level import NO_LATHE
from .camera_chain import solve_camera_chain
from .integrator_base import contradicts, sample_with_fallback, with_geometric_frame
from .line_walk import start_walk
from .media_segments import segment_transmittance

__all__ = ["CausticTracer", "aim_pdf", "aim_spheres", "blocks_shadow_rays", "caustic_weight", "disk_pdf",
           "on_lathe", "pure_delta"]

#: Margin of the aiming spheres over the lathes' tessellated profiles (a
#: B-spline's curve may bulge past its points between them).
SPHERE_MARGIN = 1.02

#: Particles traced in one kernel launch at most (memory of a wavefront).
PASS_SIZE = 1 << 22

#: Most spheres the particles aim at (beyond: one around every lathe).
MAX_SPHERES = 16


def jit_array(kind: type, values) -> object:
    """A Dr.Jit array of ``kind`` holding ``values``, copied from a Python
    list: an array made from a NumPy buffer may keep its alignment, which
    Dr.Jit writes into the kernel (a new kernel hash, a recompilation, from
    one render to the next)."""
    return kind([value.item() if hasattr(value, "item") else value for value in values])


def pure_delta(bsdf: mi.BSDFPtr) -> mi.Bool:
    """Whether ``bsdf`` has Dirac delta lobes only (a chain vertex)."""
    return ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)


def blocks_shadow_rays(sampled_type: mi.UInt32, nee_through_null: bool) -> mi.Bool:
    """Whether a chain vertex sampled as ``sampled_type`` is one that the
    path tracer's shadow rays cannot cross (eq. 32: a caustic path needs
    one between ``D`` and the light, else emitter sampling samples it too).
    In ``lathe_path`` (``nee_through_null`` false) every vertex: its shadow
    rays stop at every surface, as Mitsuba's ``path``'s. In
    ``lathe_volpath`` every vertex but a null crossing (sampled type
    ``Null``: a ``null`` BSDF, a ``thindielectric``'s transmission), which
    its shadow rays cross, weighted by ``eval_null_transmission``, as
    Mitsuba's ``volpath``'s."""
    if not nee_through_null:
        return mi.Bool(True)
    return ~mi.has_flag(sampled_type, mi.BSDFFlags.Null)


def on_lathe(lathes: list, si: mi.SurfaceInteraction3f) -> mi.Bool:
    """Whether ``si`` lies on one of the exact ``lathes``."""
    hit = mi.Bool(False)
    for lathe in lathes:
        hit |= si.shape == mi.ShapePtr(lathe)
    return hit


def aim_spheres(lathes: list) -> list[tuple[tuple[float, float, float], float]]:
    """Spheres (centre, radius) whose union holds every lathe in ``lathes``:
    each lathe's axis cut into slices about as tall as its widest radius,
    one sphere around each slice (a bottle 19 tall and 9 wide gets five,
    whose outline is half the area of one sphere around it). Scenes of
    more than 16 such spheres get one sphere around all lathes."""
    spheres = []
    for lathe in lathes:
        positions = np.asarray(lathe.local_mesh.positions, dtype=np.float64).reshape(-1, 3)
        radius = SPHERE_MARGIN * float(np.max(np.hypot(positions[:, 0], positions[:, 1])))
        z_low, z_high = float(positions[:, 2].min()), float(positions[:, 2].max())
        height = max(z_high - z_low, 1e-6 * max(radius, 1.0))
        count = int(min(8, max(1, math.ceil(height / max(radius, 1e-12)))))
        matrix = np.asarray(lathe.to_world_matrix, dtype=np.float64)
        scale = float(np.linalg.svd(matrix[:3, :3], compute_uv=False).max())
        half = 0.5 * height / count
        for index in range(count):
            z = z_low + (2 * index + 1) * half
            centre = matrix @ np.array([0.0, 0.0, z, 1.0])
            reach = scale * math.hypot(radius, half)  # (radius holds the margin)
            spheres.append((tuple(float(c) for c in centre[:3]), reach))
    if len(spheres) > MAX_SPHERES:
        low = np.min([np.array(c) - r for c, r in spheres], axis=0)
        high = np.max([np.array(c) + r for c, r in spheres], axis=0)
        spheres = [(tuple(float(c) for c in 0.5 * (low + high)), 0.5 * float(np.linalg.norm(high - low)))]
    return spheres


def bounding_sphere(spheres: list) -> tuple[tuple[float, float, float], float]:
    """A sphere (centre, radius) holding every sphere of ``spheres``
    (around the centre of their bounding box; a unit sphere at the origin
    for none)."""
    if not spheres:
        return (0.0, 0.0, 0.0), 1.0
    centres = np.array([centre for centre, _ in spheres], dtype=np.float64).reshape(-1, 3)
    radii = np.array([radius for _, radius in spheres], dtype=np.float64)
    centre = 0.5 * ((centres - radii[:, None]).min(axis=0) + (centres + radii[:, None]).max(axis=0))
    radius = float(np.max(np.linalg.norm(centres - centre, axis=1) + radii))
    return tuple(float(c) for c in centre), radius


def cone_cosine(centre: mi.Point3f, radius: float, p: mi.Point3f) -> tuple[mi.Vector3f, mi.Float]:
    """Eq. 33: the axis (unit) and the cosine of the half angle of the cone
    from ``p`` around the sphere (``centre``, ``radius``); -1 (all
    directions) from inside the sphere."""
    axis = centre - p
    dist2 = dr.squared_norm(axis)
    sin2 = dr.square(radius) / dr.maximum(dist2, 1e-30)
    cos_max = dr.select(sin2 < 1.0, dr.safe_sqrt(1.0 - sin2), -1.0)
    return dr.normalize(axis), cos_max


def aim_pdf(spheres: list, p: mi.Point3f, d: mi.Vector3f) -> mi.Float:
    """Eq. 33: the solid-angle density of direction ``d`` from ``p`` drawn
    by :meth:`CausticTracer._trace` (a sphere of ``spheres`` chosen
    uniformly, then a direction uniformly in the cone around it; 0 outside
    every cone)."""
    total = mi.Float(0.0)
    for centre, radius in spheres:
        centre = centre if isinstance(centre, mi.Point3f) else mi.Point3f(centre)
        axis, cos_max = cone_cosine(centre, radius, p)
        inside = dr.dot(axis, d) >= cos_max
        total += dr.select(inside, dr.rcp(dr.two_pi * (1.0 - cos_max)), 0.0)
    return total / len(spheres)


def disk_pdf(spheres: list, p: mi.Point3f, d: mi.Vector3f) -> mi.Float:
    """Eq. 34: the density per unit area, across the direction ``d``, of
    the line through ``p`` drawn by a directional light's particles (a
    sphere of ``spheres`` chosen uniformly, then a point uniformly on its
    disk facing ``d``)."""
    total = mi.Float(0.0)
    for centre, radius in spheres:
        v = (centre if isinstance(centre, mi.Point3f) else mi.Point3f(centre)) - p
        across2 = dr.squared_norm(v) - dr.square(dr.dot(v, d))
        total += dr.select(across2 <= radius * radius, dr.rcp(math.pi * radius * radius), 0.0)
    return total / len(spheres)


def adjoint_correction(cos_in_shading: mi.Float, cos_in_geometric: mi.Float, cos_out_shading: mi.Float,
                       cos_out_geometric: mi.Float) -> mi.Float:
    """The factor that turns a BSDF evaluated with shading normals into its
    adjoint, for light carried from the incident to the outgoing direction
    (Veach 1997, eq. 5.17): |wi.Ns| |wo.Ng| / (|wi.Ng| |wo.Ns|); 1 where the
    shading normal is the geometric one."""
    return dr.abs(cos_in_shading * cos_out_geometric
                  / dr.maximum(dr.abs(cos_in_geometric * cos_out_shading), 1e-12))


def area_light_density(p_select: mi.Float, p_area: mi.Float, p_direction: mi.Float,
                       cos_light: mi.Float) -> mi.Float:
    """Eq. 32, light side, for an area light chosen with probability
    ``p_select``: position density ``p_area`` times direction density
    ``p_direction`` (eq. 33), over the cosine at the light."""
    return p_select * p_area * p_direction / dr.maximum(dr.abs(cos_light), 1e-12)


def caustic_weight(own: mi.Float, other: mi.Float) -> mi.Float:
    """Eq. 32: the power-heuristic weight of the technique with density
    ``own`` against ``other`` (each already multiplied by its sample count;
    an infinite ``own`` wins, a zero ``own`` gets nothing)."""
    own2, other2 = dr.square(own), dr.square(other)
    return dr.select(dr.isinf(own), 1.0, dr.select(own2 > 0.0, own2 / (own2 + other2), 0.0))


def pass_seed(seed: int | mi.UInt32, index: int) -> mi.UInt32:
    """The light pass ``index``'s sampler seed for the render seed ``seed``,
    opaque (a new seed compiles no new kernel). ``seed`` is an int from
    ``mi.render``, or a ``UInt32`` where Mitsuba's C++ calls the
    integrator's ``render`` (an ``aov`` integrator wrapping it)."""
    value = mi.UInt32(seed) * 7919 + 104729 * (index + 1)  # (wraps modulo 2^32)
    dr.make_opaque(value)
    return value


class PinholeCamera:
    """What eq. 32 needs of a pinhole ``perspective`` sensor: its position,
    viewing direction, the area of its film (crop window) at unit distance
    and its clip range, and the importance of a connection to it.

    The importance is this class's own, 1 / (film area cos^3) per unit
    solid angle on the film (the density of a camera ray drawn uniformly
    over it): Mitsuba 3.9.1's ``sample_direction`` gives the right film
    position and clip test (its ``pdf`` is 0 outside the clip range and
    off the film) but an importance that ignores ``principal_point_offset``
    (it is 0 on the part of a shifted film outside the unshifted one) and
    the clip range (not 0 beyond ``far_clip``).

    The clip range is the camera rays': Mitsuba's perspective camera starts
    each ray where its depth along the viewing direction (camera-space z)
    is ``near_clip`` and ends it where it is ``far_clip``, so a point is
    seen only at a depth in [near_clip, far_clip], and only what lies at
    such a depth occludes it."""

    def __init__(self, sensor: mi.Sensor) -> None:
        matrix = np.array(sensor.world_transform().matrix, dtype=np.float64).reshape(4, 4)
        # (Mitsuba refuses scale in a perspective camera's to_world: its
        # columns are orthonormal, depth is the dot product with forward)
        forward = matrix[:3, 2] / np.linalg.norm(matrix[:3, 2])
        self.origin = [float(v) for v in matrix[:3, 3]]
        self.forward = [float(v) for v in forward]
        #: The camera rays' clip range (depths along :attr:`forward`).
        self.near_clip = float(sensor.near_clip())
        self.far_clip = float(sensor.far_clip())
        # The film's (its crop window's) corners on the plane at depth 1, from
        # the sensor's own rays (shifted alike by a principal point offset,
        # which changes no area)
        rays = sensor.sample_ray(0.0, 0.5, mi.Point2f([0.0, 1.0], [0.0, 1.0]), mi.Point2f(0.5))[0]
        directions = np.array(rays.d, dtype=np.float64).reshape(3, 2).T @ matrix[:3, :3]  # (camera space)
        corners = directions[:, :2] / directions[:, 2:3]
        #: The film's (its crop window's) area on the plane at unit distance.
        self.film_area = float(abs(np.prod(corners[1] - corners[0])))
        # Opaque, so that a moved camera (a turntable's orbit) compiles no
        # new kernel
        self._origin = dr.opaque(mi.Point3f, self.origin)
        self._forward = dr.opaque(mi.Vector3f, self.forward)
        self._film_area = dr.opaque(mi.Float, self.film_area)
        self._near = dr.opaque(mi.Float, self.near_clip)
        self._far = dr.opaque(mi.Float, self.far_clip)
        # A depth inside the clip range at which a direction's film
        # position is read (their geometric mean: 0.32 at the defaults 0.01
        # and 10^4, within float32's range for any range)
        self._reference_depth = dr.opaque(mi.Float, math.sqrt(self.near_clip * self.far_clip))

    @property
    def clip(self) -> tuple[mi.Vector3f, mi.Float, mi.Float]:
        """(Viewing direction, near clip, far clip), for
        :func:`~lathe_shape.plugin.camera_chain.solve_camera_chain`."""
        return self._forward, self._near, self._far

    def depth(self, p: mi.Point3f) -> mi.Float:
        """The depth of ``p`` along the viewing direction (camera-space z)."""
        return dr.dot(p - self._origin, self._forward)

    def in_clip_range(self, p: mi.Point3f) -> mi.Bool:
        """Whether the camera's rays can reach ``p``: its depth in
        [near_clip, far_clip] (the test of Mitsuba's ``sample_direction``)."""
        z = self.depth(p)
        return (z >= self._near) & (z <= self._far)

    def shadow_ray(self, it: mi.Interaction3f) -> mi.Ray3f:
        """The shadow ray of the straight connection from ``it`` (in the
        clip range) to the camera: it ends on the near-clip plane, as the
        camera rays start there (nothing nearer the camera occludes)."""
        scale = self._near / dr.maximum(self.depth(it.p), self._near)
        return it.spawn_ray_to(self._origin + (it.p - self._origin) * scale)

    def connect(self, sensor: mi.Sensor, it: mi.Interaction3f,
                active: mi.Bool) -> tuple[mi.DirectionSample3f, mi.Spectrum]:
        """The straight connection from ``it`` to the camera: the sensor's
        direction sample (film position ``uv``) and the importance over the
        squared distance, 0 where the camera cannot see ``it`` (behind it,
        off the film, out of the clip range)."""
        ds = sensor.sample_direction(it, mi.Point2f(0.5), active)[0]
        seen = active & (ds.pdf > 0.0)
        importance = dr.select(seen, self.direction_density(-ds.d) / dr.square(ds.dist), 0.0)
        return ds, mi.Spectrum(importance)

    def film_position(self, sensor: mi.Sensor, d: mi.Vector3f,
                      active: mi.Bool) -> tuple[mi.Point2f, mi.Spectrum]:
        """The film position (pixels, crop window) of the camera ray along
        ``d`` (unit, world) and the importance per unit solid angle there
        (0 off the film)."""
        it = dr.zeros(mi.Interaction3f, dr.width(d))
        cos_camera = dr.dot(d, self._forward)
        it.p = self._origin + d * (self._reference_depth / dr.maximum(cos_camera, 1e-6))
        ds = sensor.sample_direction(it, mi.Point2f(0.5), active)[0]
        seen = active & (ds.pdf > 0.0) & (cos_camera > 0.0)
        return ds.uv, mi.Spectrum(dr.select(seen, self.direction_density(d), 0.0))

    def density(self, p: mi.Point3f, n: mi.Normal3f) -> mi.Float:
        """Eq. 32: the area density at ``p`` (normal ``n``) of a camera ray
        drawn uniformly over the whole film: 1 / (film area cos^3) per unit
        solid angle, times |cos| at ``p`` over the squared distance (0
        outside the clip range, which the camera rays do not reach)."""
        to_p = p - self._origin
        dist2 = dr.squared_norm(to_p)
        d = to_p * dr.rsqrt(dist2)
        density = self.direction_density(d) * dr.abs(dr.dot(n, d)) / dist2
        return dr.select(self.in_clip_range(p), density, 0.0)

    def direction_density(self, d: mi.Vector3f) -> mi.Float:
        """Eqs. 32 and 40: the solid-angle density of the camera ray
        direction ``d`` (unit) drawn uniformly over the whole film (0
        behind the camera). (Whether the ray reaches a point along ``d``
        is the clip range's matter: :meth:`density`, and the chain
        solver's first segment for eq. 40.)"""
        cos_camera = dr.dot(d, self._forward)
        return dr.select(cos_camera > 0.0, dr.rcp(self._film_area * dr.maximum(cos_camera, 1e-6) ** 3), 0.0)


def chain_length_limit(max_depth: int, max_chain: int) -> int:
    """The longest specular chain in the caustic class: a path of ``k``
    chain vertices reaches the light at depth ``k + 1``, which the path
    tracer counts when ``k + 1 < max_depth``."""
    return max(0, min(max_chain, max_depth - 2))


class CausticTracer:
    """The light-tracing half of ``lathe_path``'s caustics for one scene:
    which lights send particles, the sphere they aim at, and the pass that
    traces them (:meth:`render`). Made by the integrator each render."""

    def __init__(self, scene: mi.Scene, sensor: mi.Sensor, lathes: list, max_chain: int,
                 normal_check: str, max_vertices: int | None = None, chain_share: float = 0.3,
                 media: bool = False, nee_through_null: bool = False) -> None:
        self.lathes = lathes
        #: Whether the particles and the camera connections carry the
        #: transmittance of the homogeneous media they cross (``lathe_volpath``;
        #: the camera and the lights outside every medium).
        self.media = media
        #: Whether the path tracer's shadow rays cross ``null`` surfaces
        #: (``lathe_volpath``, as Mitsuba's ``volpath``): a path whose chain
        #: from ``D`` to the light holds null crossings alone is then sampled
        #: by emitter sampling, and is no caustic path
        #: (:func:`blocks_shadow_rays`).
        self.nee_through_null = nee_through_null
        #: The sensor's pinhole camera (eq. 32).
        self.camera = PinholeCamera(sensor)
        #: Most Dirac-delta vertices between D and the light, and between
        #: the camera and D (eq. 40).
        self.max_chain = max_chain
        #: Most Dirac-delta vertices on both sides of D together (the path
        #: tracer's max_depth - 2).
        self.max_vertices = max_chain if max_vertices is None else max(max_vertices, max_chain)
        #: Share of the particles landing where the camera sees them only
        #: through Dirac deltas that solve for the chain to the camera
        #: (eqs. 39-40; ``caustic_camera_chains``).
        self.chain_share = float(chain_share)
        self.normal_check = normal_check
        emitters = scene.emitters()
        #: Indices (in ``scene.emitters()``) of the lights that send particles.
        #: (A uniform sky sends none: path tracing meets it in every
        #: direction, and its particles would only take others' share.)
        self.light_indices = [
            index for index, emitter in enumerate(emitters)
            if mi.has_flag(emitter.flags(), mi.EmitterFlags.Surface)
            or mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaPosition)
            or mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaDirection)
            or (mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite)
                and emitter.class_name() != "ConstantBackgroundEmitter")
        ]
        #: How far back a directional light's particles start (beyond the scene).
        box = scene.bbox()
        self.far = 2.0 * float(dr.norm(box.extents())) + 1.0 if box.valid() else 1e4
        #: The lathes whose BSDF is a pure Dirac delta (glass, mirrors): the
        #: particles aim at these alone (a diffuse vase makes no caustic).
        self.specular_lathes = [lathe for lathe in lathes
                                if not mi.has_flag(lathe.bsdf().flags(), mi.BSDFFlags.Smooth)]
        #: The spheres that particles aim at (eq. 33).
        self.spheres = aim_spheres(self.specular_lathes)
        #: The scene's emitters (to tell them apart in :meth:`light_values`).
        self.emitters = list(emitters)
        #: Position density of each light's shape (1 / its area; 0 for lights
        #: without a shape), as path tracing reads it: read per light here,
        #: not by a call on the shape pointer, whose traced dispatch would
        #: reach every live shape, a <shapegroup> of another scene too,
        #: which has no position density.
        self.inverse_areas = [self._inverse_area(emitters[index]) for index in self.light_indices]
        self._inverse_areas = [dr.opaque(mi.Float, value) for value in self.inverse_areas]
        #: Probability of each light (slot of :attr:`light_indices`) to send
        #: a particle: proportional to its power into the aiming cones (eq. 36).
        self.selection = np.zeros(0, dtype=np.float32)
        #: The same as opaque Dr.Jit values (a moved lathe compiles no new kernel).
        self.opaque_spheres = [(dr.opaque(mi.Point3f, centre), dr.opaque(mi.Float, radius))
                               for centre, radius in self.spheres]
        #: A sphere (centre, radius) around every aiming sphere: directional
        #: and environment particles start just outside it (:meth:`_emit`).
        self.bounding_sphere = bounding_sphere(self.spheres)
        centres = [centre for centre, _ in self.spheres]
        self.sphere_centres = np.array(centres, dtype=np.float32).reshape(-1, 3)
        self.sphere_radii = np.array([radius for _, radius in self.spheres], dtype=np.float32)
        if self.active:
            power = self._light_powers(scene)
            power = np.maximum(power, 1e-3 * power.max()) if power.max() > 0.0 else np.ones_like(power)
            self.selection = (power / power.sum()).astype(np.float32)
        self._selection = [dr.opaque(mi.Float, float(value)) for value in self.selection]

    @property
    def active(self) -> bool:
        """Whether there is anything to trace (lights and specular lathes)."""
        return bool(self.light_indices) and bool(self.specular_lathes) and self.max_chain >= 1

    def camera_chain_limit(self, light_chain: mi.UInt32) -> mi.UInt32:
        """Eq. 40: the most Dirac-delta vertices of the camera chain of a
        path whose chain from ``D`` to the light has ``light_chain`` of
        them (both sides of eq. 40 solve with this bound)."""
        return dr.minimum(self.max_chain, self.max_vertices - light_chain)

    def light_density(self, p_select: mi.Float, p_area: mi.Float, cos_light: mi.Float, p: mi.Point3f,
                      d: mi.Vector3f) -> mi.Float:
        """Eq. 32, light side: the density of a particle leaving an area
        light (chosen with probability ``p_select``) at ``p`` (position
        density ``p_area``) in direction ``d``, over ``cos_light``."""
        return area_light_density(p_select, p_area, aim_pdf(self.opaque_spheres, p, d), cos_light)

    def environment_density(self, p_select: mi.Float, pdf_direction: mi.Float, p: mi.Point3f,
                            d: mi.Vector3f) -> mi.Float:
        """Eq. 35, light side: the density of an environment particle along
        the line through ``p`` in direction ``d`` (towards the environment),
        the environment's selection probability ``p_select`` and direction
        density ``pdf_direction`` times the line's density across it
        (eq. 34)."""
        return p_select * pdf_direction * disk_pdf(self.opaque_spheres, p, d)

    # ------------------------------------------------------------------
    # The light pass
    # ------------------------------------------------------------------

    def render(self, scene: mi.Scene, geometry, sensor: mi.Sensor, seed: int, count: int,
               per_camera_sample: float) -> mi.TensorXf:
        """Trace ``count`` particles and splat their camera connections
        through the film's filter: the caustic image to add to the path
        tracer's developed one (H, W, 3). ``per_camera_sample``: particles
        per camera sample over the whole film, the ratio of the two
        techniques' sample counts in eq. 32."""
        film = sensor.film()
        block = mi.ImageBlock(film.crop_size(), film.crop_offset(), 3, film.rfilter(),
                              border=False, normalize=True)
        # (the sensor's importance is normalised over the crop window, and its
        # film positions are the crop's)
        pixels = float(film.crop_size().x * film.crop_size().y)
        offset = mi.Point2f(film.crop_offset())
        passes = max(1, math.ceil(count / PASS_SIZE))
        done = 0
        for index in range(passes):
            size = (count - done) // (passes - index)
            done += size
            sampler = mi.load_dict({"type": "independent"})
            # (opaque: a new seed or count must not compile new kernels)
            sampler.seed(pass_seed(seed, index), size)
            pos, value, splat, behind = self._trace(scene, geometry, sensor, sampler, size, per_camera_sample)
            scale = dr.opaque(mi.Float, pixels / count)
            self._put(block, pos + offset, value * scale, splat)
            dr.eval(block.tensor(), behind)
            # (wait here, where Dr.Jit releases Python's lock: dr.compress
            # waits for the kernel holding it, and a Ctrl-C went unanswered
            # until the pass had ended, tens of seconds on a long render)
            dr.sync_thread()
            lanes = dr.compress(behind[0])
            if dr.width(lanes) > 0:
                behind = tuple(dr.gather(type(field), field, lanes) for field in behind)
                pos, value, splat = self._through_chain(geometry, sensor, behind)
                self._put(block, pos + offset, value * scale, splat)
                dr.eval(block.tensor())
        return block.tensor()

    @staticmethod
    def _put(block: mi.ImageBlock, pos: mi.Point2f, value: mi.Spectrum, splat: mi.Bool) -> None:
        """Splat ``value`` at film positions ``pos`` (lanes ``splat``)."""
        # (a non-finite value would spoil its pixels: none is expected, see
        # tests/plugin/test_caustics.py, but none reaches the film)
        splat &= dr.all(dr.isfinite(value))
        block.put(pos, [value.x, value.y, value.z], splat)

    def _emit(self, scene: mi.Scene, sampler: mi.Sampler, size: int, pick: mi.UInt32,
              per_camera_sample: mi.Float) -> tuple:
        """``size`` particles leaving the lights of slots ``pick`` (in
        :attr:`light_indices`) towards the aiming spheres: (origin as an
        interaction to spawn from, direction, weight, the light side's
        density of eq. 32, infinite where path tracing cannot hit the
        light). The weight holds the selection probability of the light."""
        p_select = dr.gather(mi.Float, jit_array(mi.Float, self.selection), pick)
        index = dr.gather(mi.UInt32, jit_array(mi.UInt32, self.light_indices), pick)
        emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index)
        ps = emitter.sample_position(0.0, sampler.next_2d())[0]
        spheres = self.opaque_spheres
        choice = dr.minimum(mi.UInt32(sampler.next_1d() * len(spheres)), len(spheres) - 1)
        centres = mi.Point3f(*(jit_array(mi.Float, axis) for axis in self.sphere_centres.T))
        centre = dr.gather(mi.Point3f, centres, choice)
        radius = dr.gather(mi.Float, jit_array(mi.Float, self.sphere_radii), choice)
        axis, cos_max = cone_cosine(centre, radius, ps.p)
        local = mi.warp.square_to_uniform_cone(sampler.next_2d(), cos_max)
        d = mi.Frame3f(axis).to_world(local)
        p_cone = aim_pdf(spheres, ps.p, d)
        is_delta = mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaPosition)
        # Area light: radiance along d, times cos / (position, direction density)
        si_light = dr.zeros(mi.SurfaceInteraction3f, size)
        si_light.p, si_light.n, si_light.uv, si_light.time = ps.p, ps.n, ps.uv, ps.time
        si_light.sh_frame = mi.Frame3f(ps.n)
        si_light.wi = si_light.sh_frame.to_local(d)
        cos_light = dr.dot(ps.n, d)
        radiance = emitter.eval(si_light, ~is_delta & (cos_light > 0.0))
        # Point or spot light: its intensity along d, read at unit distance
        it = dr.zeros(mi.Interaction3f, size)
        it.p, it.time = ps.p + d, ps.time
        intensity = emitter.sample_direction(it, mi.Point2f(0.5), is_delta)[1]
        emitted = radiance * dr.maximum(cos_light, 0.0) / dr.maximum(ps.pdf, 1e-30)
        beta = dr.select(is_delta, intensity, emitted) / p_cone
        # Eq. 32: the light side's density (infinite for a point light: path
        # tracing cannot hit it)
        # (the shape's position density, as path tracing reads it: a textured
        # light samples its positions by radiance, which ps.pdf holds)
        p_area = dr.gather(mi.Float, jit_array(mi.Float, self.inverse_areas), pick)
        area_density = per_camera_sample * area_light_density(p_select, p_area, p_cone, cos_light)
        light_density = dr.select(is_delta, dr.inf, area_density)
        # Directional light: a point on the disk of the chosen sphere facing
        # the light, the particle coming from far back through it (eq. 34)
        is_directional = mi.has_flag(emitter.flags(), mi.EmitterFlags.DeltaDirection)
        it_centre = dr.zeros(mi.Interaction3f, size)
        it_centre.p = centre
        sun, irradiance = emitter.sample_direction(it_centre, mi.Point2f(0.5), is_directional)
        disk = mi.warp.square_to_uniform_disk_concentric(sampler.next_2d()) * radius
        through = centre + mi.Frame3f(sun.d).to_world(mi.Vector3f(disk.x, disk.y, 0.0))
        p_disk = disk_pdf(spheres, through, sun.d)
        # Environment: a direction drawn by the environment's own sampling,
        # the particle coming from far back along it through the same kind
        # of disk (eq. 35)
        is_environment = mi.has_flag(emitter.flags(), mi.EmitterFlags.Infinite) & ~is_directional
        sky, sky_weight = emitter.sample_direction(it_centre, sampler.next_2d(), is_environment)
        through_sky = centre + mi.Frame3f(sky.d).to_world(mi.Vector3f(disk.x, disk.y, 0.0))
        p_sky = disk_pdf(spheres, through_sky, sky.d)
        sky_density = per_camera_sample * p_select * sky.pdf * p_sky
        d = dr.select(is_directional, -sun.d, dr.select(is_environment, -sky.d, d))
        beta = dr.select(is_directional, irradiance / dr.maximum(p_disk, 1e-30),
                         dr.select(is_environment, sky_weight / dr.maximum(p_sky, 1e-30), beta))
        beta = dr.select(p_select > 0.0, beta / p_select, 0.0)
        light_density = dr.select(is_environment, sky_density, light_density)
        light_density = dr.select(is_directional, dr.inf, light_density)
        # Where a directional or environment particle starts along its line
        # (the line, and so its density, is the same wherever it starts):
        # just outside the sphere around every aiming sphere (a plane
        # tangent to it, facing the light), so that every lathe it aims at
        # is ahead of it and float32 keeps the line's position at the scale
        # of the lathes (2.5e-7 of a large scene's size from far back:
        # speckles on a floor 10^6 wide). The light reaches that start
        # unhindered only if nothing lies between it and the light:
        # :meth:`_trace` tests that first (the particle's first query, a
        # shadow ray towards the light) and starts from far back, as the
        # light does, where something does.
        infinite = is_directional | is_environment
        towards = dr.select(is_directional, sun.d, sky.d)  # (unit, towards the light)
        line_point = dr.select(is_directional, through, through_sky)
        bound_centre = dr.opaque(mi.Point3f, self.bounding_sphere[0])
        bound_radius = dr.opaque(mi.Float, self.bounding_sphere[1])
        reach = dr.dot(bound_centre - line_point, towards) + bound_radius * (1.0 + 1e-3)
        far = dr.opaque(mi.Float, self.far)
        far_start = line_point + towards * far
        origin = dr.zeros(mi.SurfaceInteraction3f, size)
        origin.p = dr.select(infinite, line_point + towards * dr.maximum(reach, 0.0), ps.p)
        origin.n = dr.select(is_delta | infinite, 0.0, ps.n)
        origin.time = ps.time
        return origin, d, beta, light_density, (infinite, far_start)

    def _light_powers(self, scene: mi.Scene, particles: int = 4096) -> np.ndarray:
        """Eq. 36: each light's power into the aiming cones, estimated from
        ``particles`` particles of its own (the mean of their first weight's
        luminance; a fixed seed, so every render of the scene draws the
        lights alike)."""
        lights = len(self.light_indices)
        self.selection = np.full(lights, 1.0, dtype=np.float32)  # (a weight of 1 in _emit)
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(dr.opaque(mi.UInt32, 12345), particles * lights)
        pick = dr.arange(mi.UInt32, particles * lights) // particles
        beta = self._emit(scene, sampler, particles * lights, pick, mi.Float(1.0))[2]
        power = np.nan_to_num(np.array(mi.luminance(beta)), nan=0.0, posinf=0.0).reshape(lights, particles)
        return np.maximum(power, 0.0).mean(axis=1)

    @staticmethod
    def _inverse_area(emitter: mi.Emitter) -> float:
        """The position density of ``emitter``'s shape (0 without one)."""
        shape = emitter.get_shape()
        area = float(dr.slice(shape.surface_area())) if shape is not None else 0.0
        return 1.0 / area if area > 0.0 else 0.0

    def light_values(self, emitter: mi.EmitterPtr) -> tuple[mi.Float, mi.Float]:
        """(The probability with which :meth:`_trace` picks ``emitter``, the
        position density of its shape as path tracing reads it); (0, 0) for
        lights that send no particles."""
        emitters = self.emitters
        chosen, inverse_area = mi.Float(0.0), mi.Float(0.0)
        for slot, index in enumerate(self.light_indices):
            this = emitter == mi.EmitterPtr(emitters[index])
            chosen = dr.select(this, self._selection[slot], chosen)
            inverse_area = dr.select(this, self._inverse_areas[slot], inverse_area)
        return chosen, inverse_area

    @dr.syntax
    def _trace(self, scene: mi.Scene, geometry, sensor: mi.Sensor, sampler: mi.Sampler, size: int,
               per_camera_sample: float) -> tuple:
        """One wavefront of ``size`` particles: film positions, values (to
        be scaled by pixels / particles) and which lanes splat (values
        not checked for being finite) of the straight camera connections;
        and the lanes whose connection is blocked (a mask, then D, the
        particle's weight, eq. 32's light density and the chain's length
        so far) for :meth:`_through_chain`."""
        check = self.normal_check
        ctx = mi.BSDFContext(mi.TransportMode.Importance)

        # ---------------- Eqs. 33-35: a particle aimed at the lathes ----------------
        pick = mi.DiscreteDistribution(jit_array(mi.Float, self.selection)).sample(sampler.next_1d())
        origin, d, beta, light_density, (infinite, far_start) = self._emit(scene, sampler, size, pick,
                                                                          per_camera_sample)

        ray = origin.spawn_ray(d)                 # Current ray of the particle
        walk = start_walk(size)                   # Its line and last lathe crossing
        chain = mi.UInt32(0)                      # Specular vertices passed so far
        blocking = dr.zeros(mi.Bool, size)        # ... one of them not a vertex shadow rays cross
        active = dr.max(beta) > 0.0               # Particles still going through glass
        # A directional or environment particle starts near the lathes
        # (_emit) where nothing lies between that start and the light: its
        # first query is a shadow ray from there towards the light (which
        # every surface beyond the start blocks, as it would have met the
        # particle coming from far back), then it starts from there or, where
        # blocked, from far back (no light is lost or added: the same line,
        # the same surfaces met along it)
        probing = active & infinite               # Lanes whose start is being tested
        active &= ~probing
        near_ray = mi.Ray3f(ray)                  # (their two starts)
        far_ray = mi.Ray3f(ray)
        far_ray.o = far_start
        landed = dr.zeros(mi.Bool, size)          # Particles that reached a diffuse D
        si_d = dr.zeros(mi.SurfaceInteraction3f, size)  # ... that D
        chain_d = mi.UInt32(0)                    # ... the specular vertices before it
        ds = dr.zeros(mi.DirectionSample3f, size)  # ... its direction to the camera
        importance = mi.Spectrum(0.0)             # ... and the camera's importance there
        medium = dr.zeros(mi.MediumPtr, size)     # Medium the particle travels in (media: lights in none)
        # The camera connection's shadow ray is tested by the next query, in
        # the same traced lathe traversal as the walked rays (as lathe_path's
        # emitter samples: one traversal compiled, not two)
        shadow = dr.zeros(mi.Ray3f, size)         # Connection from D to the camera
        shadow[probing] = mi.Ray3f(ray.o, -d)     # (first: from the near start towards the light)
        pending = mi.Bool(probing)                # Lanes with one to test
        visible = dr.zeros(mi.Bool, size)         # Lanes whose connection is clear
        # (a lane that landed runs once more to test its connection)
        while dr.hint(active | pending, max_iterations=-1, label="lathe_path_caustics"):
            si, walk, occluded = geometry.walk_and_test(ray, active, walk, False, shadow, pending)
            visible |= pending & ~probing & ~occluded
            bsdf = si.bsdf(ray)
            delta = pure_delta(bsdf)
            valid = active & si.is_valid()
            if dr.hint(self.media, mode="scalar"):
                # Eq. 44: the unscattered part of the light, exp(-sigma_t l)
                # of the segment just walked (scattered light is path traced)
                beta[valid] *= segment_transmittance(medium, ray.o, si.t, valid)
            # D: the first smooth surface after at least one specular vertex,
            # one of them a vertex that path tracing's shadow rays do not cross
            # (eq. 32; else its emitter sampling samples the path: a point light
            # under a null or thindielectric sheet in lathe_volpath, counted twice)
            lands = valid & ~delta & (chain >= 1) & ~on_lathe(self.lathes, si)
            if dr.hint(self.nee_through_null, mode="scalar"):
                lands &= blocking
            landed |= lands
            si_d[lands] = si
            chain_d[lands] = chain
            # (the camera's own importance: 0 out of its clip range, right
            # with a principal point offset, PinholeCamera)
            ds_here, importance_here = self.camera.connect(sensor, mi.Interaction3f(si), lands)
            ds[lands] = ds_here
            if dr.hint(self.media, mode="scalar"):
                # ... and eq. 44 on the straight line
                # to the camera (used only where nothing is in between)
                towards = dr.select(si.is_medium_transition(), si.target_medium(ds_here.d), medium)
                importance_here *= segment_transmittance(towards, si.p, ds_here.dist, lands)
            importance[lands] = importance_here
            # (tested off the film too: only a D whose straight line to the
            # camera is blocked tries a chain; where it is clear and off the
            # film, the solver's first trace, that same line, meets no glass
            # and fails on both sides of eq. 40)
            # (to the near-clip plane: what lies nearer the camera is
            # clipped away from its rays and occludes nothing)
            shadow = self.camera.shadow_ray(si)
            pending = lands
            active = valid & delta & (chain < self.max_chain)

            # Eq. 11 at a specular vertex, as lathe_path does
            cos_in_geo = dr.dot(si.n, -ray.d)
            bad_in = active & (cos_in_geo * mi.Frame3f.cos_theta(si.wi) <= 0.0)
            geo_frame = mi.Frame3f(si.n)
            if dr.hint(check == "terminate", mode="scalar"):
                active &= ~bad_in
            elif dr.hint(check == "fallback", mode="scalar"):
                si = with_geometric_frame(si, bad_in, geo_frame)
            sample_1, sample_2 = sampler.next_1d(), sampler.next_2d()
            redraws = (sampler.next_1d(), sampler.next_2d())
            bs, weight, wo_world = sample_with_fallback(
                bsdf, ctx, si, si.wi, (sample_1, sample_2), redraws, cos_in_geo,
                active & (check == "fallback"), active, geo_frame)[2:5]
            if dr.hint(check == "terminate", mode="scalar"):
                active &= ~contradicts(si, cos_in_geo, bs, wo_world)
            # (1 where the geometric frame was used)
            correction = adjoint_correction(mi.Frame3f.cos_theta(si.wi), cos_in_geo,
                                            mi.Frame3f.cos_theta(bs.wo), dr.dot(si.n, wo_world))
            beta[active] *= weight * correction
            if dr.hint(self.nee_through_null, mode="scalar"):
                blocking |= active & blocks_shadow_rays(bs.sampled_type, True)
            if dr.hint(self.media, mode="scalar"):
                medium[active & si.is_medium_transition()] = si.target_medium(wo_world)
            ray = si.spawn_ray(wo_world)
            chain += 1
            active &= dr.max(beta) > 0.0
            # The tested starts: near where the light reaches it unhindered
            ray = dr.select(probing, dr.select(occluded, far_ray, near_ray), ray)
            chain[probing] = 0
            walk.lathe[probing] = NO_LATHE
            active |= probing
            probing &= False

        # ---------------- The camera connection at D ----------------
        splat = landed & visible & (dr.max(importance) > 0.0)
        value, splat = self._connection(si_d, ds.d, beta, light_density, self.camera.density(si_d.p, si_d.n),
                                        importance, splat)
        # Eqs. 37-40: where the straight connection is blocked (a share
        # chain_share of those lanes), the chain to the camera, solved by
        # :meth:`_through_chain` on these lanes alone
        blocked = landed & ~visible & (sampler.next_1d() < self.chain_share)
        behind = (blocked, si_d, beta, light_density, chain_d)
        return ds.uv, value, splat, behind

    def _connection(self, si_d: mi.SurfaceInteraction3f, wo_world: mi.Vector3f, beta: mi.Spectrum,
                    light_density: mi.Float, camera_density: mi.Float, connection: mi.Spectrum,
                    splat: mi.Bool) -> tuple[mi.Spectrum, mi.Bool]:
        """The value a particle at ``D`` (``si_d``, weight ``beta``) splats
        through a camera connection leaving ``D`` along ``wo_world``:
        ``connection`` is the camera's importance times what the connection
        carries per unit area at ``D`` (over the cosine at ``D``, which the
        BSDF value holds), ``camera_density`` path tracing's density of
        ``D`` (eq. 32 or 40). Returns (value, splat)."""
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        wi_world = si_d.to_world(si_d.wi)
        wo_local = si_d.to_local(wo_world)
        wi_geo, wo_geo = dr.dot(si_d.n, wi_world), dr.dot(si_d.n, wo_world)
        # Both directions on the side their shading cosines say (no light
        # leaks through shading normals)
        splat &= wi_geo * mi.Frame3f.cos_theta(si_d.wi) > 0.0
        splat &= wo_geo * mi.Frame3f.cos_theta(wo_local) > 0.0
        bsdf_d = si_d.bsdf()
        value = bsdf_d.eval(ctx, si_d, wo_local, splat)
        # The adjoint BSDF with shading normals (Veach 1997, eq. 5.17)
        correction = adjoint_correction(mi.Frame3f.cos_theta(si_d.wi), wi_geo,
                                        mi.Frame3f.cos_theta(wo_local), wo_geo)
        # Eq. 32: path tracing's density of this path at D (its camera ray,
        # then the BSDF sample from the camera's side towards the glass)
        si_cam = mi.SurfaceInteraction3f(si_d)
        si_cam.wi = wo_local
        pdf_bsdf = bsdf_d.pdf(mi.BSDFContext(), si_cam, si_d.wi, splat)
        path_density = camera_density * pdf_bsdf / dr.maximum(dr.abs(wi_geo), 1e-12)
        weight = caustic_weight(light_density, path_density)
        return beta * value * correction * connection * weight, splat

    def _through_chain(self, geometry, sensor: mi.Sensor, behind: tuple) -> tuple:
        """Eqs. 37-40 for the lanes ``behind`` holds (compacted: the
        solver's loop runs for them alone): (film positions, values,
        splat)."""
        _, si_d, beta, light_density, chain_d = behind
        limit = self.camera_chain_limit(chain_d)
        # (the chain's first vertex in the camera's clip range: the solver
        # traces its first segment as the camera rays)
        solution = solve_camera_chain(geometry, self.camera._origin, si_d.p, si_d.n, si_d.shape, limit,
                                      limit >= 1, media=self.media, clip=self.camera.clip)
        through = solution.found
        uv, importance = self.camera.film_position(sensor, solution.d, through)
        through &= dr.max(importance) > 0.0
        # Eq. 40: the camera's density of D through the chain; the light
        # tracer tries the chain for a share chain_share of its particles
        camera_density = (self.camera.direction_density(solution.d) * solution.branch
                          / solution.area_per_solid_angle)
        # Eq. 39: the camera's importance times the chain's BSDF values and
        # solid angle per area at D (the cosine at D is in the BSDF value)
        cos_d = dr.maximum(dr.abs(dr.dot(si_d.n, solution.wo)), 1e-12)
        share = self.chain_share
        connection = importance * solution.throughput / (cos_d * solution.area_per_solid_angle * share)
        value, splat = self._connection(si_d, solution.wo, beta, light_density * share, camera_density,
                                        connection, through)
        return uv, value, splat
