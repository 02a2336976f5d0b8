"""The ``lathe_whitted`` integrator: Whitted ray tracing with exact lathes
(parameters: :class:`LatheWhittedIntegrator`).

The ray tree. Every camera ray starts a binary tree, deterministic but for
mixed BSDFs and a full stack (both below):

* at a vertex whose BSDF has Dirac delta lobes (``dielectric``,
  ``thindielectric``, ``conductor``, the specular coat of ``plastic``, the
  null lobe of ``mask`` and ``null``) the reflected and the transmitted
  branches are both traced, each weighted by its lobe's weight. The weights
  are the BSDF's own: :meth:`mi.BSDF.sample` is called once with
  ``BSDFContext.type_mask`` set to the delta reflection lobe and once to the
  delta transmission (or null) lobe, and a branch is kept only where the
  lobe sampled is the one asked for (:func:`sample_lobe`). A single
  BSDF then picks that lobe with probability 1 and returns its Fresnel
  reflectance R or transmittance T (times the radiance scaling 1/eta^2 and
  the BSDF's ``specular_reflectance``/``specular_transmittance``): nothing
  is random, so the specular chains have no noise. A BSDF that mixes
  others (``blendbsdf``, ``mask``) picks one of its parts at random with
  that part's own probability (its blend weight or opacity), as in
  Mitsuba's ``path``, so that the branch has the mixture's weight on
  average: such surfaces are noisy, but conserve energy (a white furnace
  renders 1);
* at a vertex whose BSDF has smooth (diffuse or glossy) lobes, direct light
  is gathered from every emitter of the scene (point, spot, directional,
  area, constant and environment emitters; ``Emitter.sample_direction``,
  one sample and one shadow ray each), and the branch ends there. Point, spot and directional
  lights are exact; area and environment emitters are sampled with the
  sensor's sampler, so their soft shadows converge with the spp while the
  rest of the image does not change;
* a ray that leaves the scene sees the environment, and a ray that hits an
  area emitter adds its radiance.

The tree is traversed depth first inside one symbolic loop: where a vertex
spawns two branches the reflected one is pushed onto a small per-lane stack
(``min(max_depth - 1, MAX_PENDING)`` entries held in registers) and the
transmitted one is followed; a branch that ends pops the next. Where the
stack is full, only one of the two branches goes on, picked at random with
probability proportional to its weight, and its weight is divided by that
probability (as a path tracer picks a lobe): the image stays unbiased and
the cost of a render no longer grows with ``max_depth`` (a stack as deep as
``max_depth`` made the kernel's size and each step's work grow with it).
Branches below ``cutoff`` are not traced, so that a deep ``max_depth``
only costs where light really bounces that often (total internal
reflection). No Python runs per ray, and lanes only wait for the others of
their SIMD packet (LLVM) or warp (CUDA).

Every ``lathe`` is intersected exactly (see
:mod:`lathe_shape.plugin.scene_geometry`); all other shapes, BSDFs and
emitters are Mitsuba's own. What Whitted ray tracing leaves out: caustics,
light reaching a diffuse surface through glass other than by ``filtered``
shadows, interreflection between diffuse surfaces, and rough (glossy)
reflection of anything but the emitters. Participating media are not handled.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .integrator_base import ExactLatheSamplingIntegrator, normal_check_parameter, with_geometric_frame
from .line_walk import start_walk
from .params import typed_property
from .scene_geometry import ExactSceneGeometry
from .variants import register_jit_plugin

__all__ = ["LatheWhittedIntegrator", "SHADOW_MODES", "register"]

#: Values of the ``shadows`` parameter.
SHADOW_MODES = ("opaque", "filtered")

#: Most surfaces a ``filtered`` shadow ray crosses; behind more the point is
#: taken as shadowed (a glass is crossed twice, a bottle four times).
MAX_SHADOW_CROSSINGS = 16

#: The delta lobes that spawn the two branches of the ray tree.
REFLECTION = mi.BSDFFlags.DeltaReflection
TRANSMISSION = mi.BSDFFlags.DeltaTransmission | mi.BSDFFlags.Null

#: Most branches waiting on a lane's stack; where it is full, a vertex with
#: two branches follows one of them at random (see the module docstring).
MAX_PENDING = 16


class PendingBranch:
    """A branch of the ray tree waiting on a lane's stack."""

    DRJIT_STRUCT = {"origin": mi.Point3f, "direction": mi.Vector3f, "weight": mi.Spectrum,
                    "depth": mi.UInt32}

    def __init__(self, ray: mi.Ray3f | None = None, weight: mi.Spectrum | None = None,
                 depth: mi.UInt32 | None = None) -> None:
        # The ray's origin and direction only: its time and wavelengths are
        # the camera ray's, and its maxt infinite.
        self.origin = mi.Point3f(0.0) if ray is None else ray.o
        self.direction = mi.Vector3f(0.0) if ray is None else ray.d
        self.weight = mi.Spectrum(0.0) if weight is None else weight
        self.depth = mi.UInt32(0) if depth is None else depth


def push_or_pop(stack: list[PendingBranch], branch: PendingBranch, push: mi.Bool,
                pop: mi.Bool) -> tuple[list[PendingBranch], PendingBranch]:
    """A lane's stack (top first) after pushing ``branch`` where ``push`` is
    set and popping where ``pop`` is set (never both), and the popped entry.
    The stack is a fixed list of registers shifted by selects: Dr.Jit's
    local memory (``dr.alloc_local``) gave wrong results with per-lane
    indices on the LLVM backend of Dr.Jit 1.5, and a shift costs a few
    selects per entry, little next to an intersection."""
    below = stack[1:] + [PendingBranch()]
    above = [branch] + stack[:-1]
    shifted = [dr.select(push, up, dr.select(pop, down, same))
               for up, down, same in zip(above, below, stack, strict=True)]
    return shifted, stack[0]


def lobe_context(lobe: mi.BSDFFlags, mode: mi.TransportMode = mi.TransportMode.Radiance) -> mi.BSDFContext:
    """A BSDF context that enables only ``lobe``."""
    ctx = mi.BSDFContext(mode)
    ctx.type_mask = lobe
    return ctx


def sample_lobe(bsdf: mi.BSDF, si: mi.SurfaceInteraction3f, lobe: mi.BSDFFlags, sample1: mi.Float,
                active: mi.Bool, mode: mi.TransportMode = mi.TransportMode.Radiance,
                ) -> tuple[mi.BSDFSample3f, mi.Spectrum, mi.Bool]:
    """Sample the delta ``lobe`` (:data:`REFLECTION` or
    :data:`TRANSMISSION`) of ``bsdf``: the sample, its weight and where it
    exists. A sample counts only where its type is in ``lobe``: a BSDF made
    of others (``mask``, ``blendbsdf``) picks a part with ``sample1`` and
    its own probability for it, and may pick one without the lobe (then
    nothing is sampled: the branch's weight is the part's on average).
    ``mask`` asked for a delta reflection alone samples its null lobe, with
    weight 1 (Mitsuba 3.9): there the reflection is sampled again with the
    null lobe enabled too, so that the mask picks its nested BSDF with
    probability ``opacity``. (Not everywhere: ``thindielectric`` would then
    pick its reflection at random.) Delta lobes ignore the 2D sample."""
    bs, weight = bsdf.sample(lobe_context(lobe, mode), si, sample1, mi.Point2f(0.5), active)
    if not lobe & mi.BSDFFlags.Null:
        redo = active & ((bs.sampled_type & int(mi.BSDFFlags.Null)) != 0)
        bs_redo, weight_redo = bsdf.sample(lobe_context(lobe | mi.BSDFFlags.Null, mode), si, sample1,
                                           mi.Point2f(0.5), redo)
        bs = dr.select(redo, bs_redo, bs)
        weight = dr.select(redo, weight_redo, weight)
    exists = active & (bs.pdf > 0.0) & (dr.max(weight) > 0.0) & ((bs.sampled_type & int(lobe)) != 0)
    return bs, weight, exists


class LatheWhittedIntegrator(ExactLatheSamplingIntegrator):
    """Whitted ray tracer that renders every ``lathe`` shape exactly.

    .. pluginparameters::

     * - max_depth
       - |int|
       - Most surface interactions along one branch of the ray tree, >= 0.
         1 renders only directly visible emitters, 2 adds direct light at the
         first surface, 3 one specular bounce before it, and so on (as
         ``lathe_path`` counts). A deep tree costs only where its branches
         stay above ``cutoff`` (total internal reflection): the kernel and
         the stack of pending branches do not grow with it. (Default: 10)

     * - cutoff
       - |float|
       - A branch whose throughput (largest channel, the product of the
         Fresnel and BSDF weights along it) falls below this is not traced,
         as POV-Ray's ``adc_bailout``; in [0, 1). (Default: 1/255)

     * - shadows
       - |string|
       - ``opaque``: every surface blocks light, as Mitsuba's dielectrics do
         for emitter samples. ``filtered``: light reaches a point through
         dielectrics (and thin dielectrics) in a straight line, attenuated at
         every crossing by the surface's transmittance (the Fresnel
         transmittance from the outside at that angle, times
         ``specular_transmittance``), without refraction, as POV-Ray's shadows
         through transparent objects. (Default: ``opaque``)

     * - normal_check
       - |string|
       - What to do where the interpolated shading normal contradicts the real
         surface (docs/method.md, eq. 11), as in ``lathe_path``: ``none``,
         ``terminate`` (the branch stops) or ``fallback`` (that vertex is
         redone with the geometric normal). (Default: ``fallback``)

     * - hide_emitters
       - |bool|
       - Hide directly visible emitters as ``lathe_path`` does: camera rays go
         on through the area emitters they meet first, and the environment
         seen directly is black with alpha 0. (Default: false)
    """

    plugin_name = "lathe_whitted"

    def __init__(self, props: mi.Properties) -> None:
        # Read before Mitsuba's base class reads it (whose type error names no plugin)
        hide_emitters = typed_property(props, "hide_emitters", bool, False, type(self).plugin_name)
        super().__init__(props)
        who = self.plugin_name
        self.max_depth = typed_property(props, "max_depth", int, 10, who)
        if self.max_depth < 0:
            raise ValueError(f"lathe_whitted: parameter 'max_depth' must be >= 0, got {self.max_depth}")
        self.cutoff = typed_property(props, "cutoff", float, 1.0 / 255.0, who)
        if not 0.0 <= self.cutoff < 1.0:
            raise ValueError(f"lathe_whitted: parameter 'cutoff' must be in [0, 1), got {self.cutoff}")
        self.shadows = typed_property(props, "shadows", str, "opaque", who)
        if self.shadows not in SHADOW_MODES:
            raise ValueError(
                f"lathe_whitted: parameter 'shadows': unknown mode '{self.shadows}' "
                f"(expected one of: {', '.join(SHADOW_MODES)})"
            )
        self.normal_check = normal_check_parameter(props, who)
        self.hide_emitters = hide_emitters

    @dr.syntax
    def sample(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.RayDifferential3f,
               medium: mi.Medium = None,
               active: mi.Bool = True) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
        geometry = self.geometry(scene)

        ray = mi.Ray3f(ray)                  # Ray of the branch being traced
        weight = mi.Spectrum(1.0)            # Its throughput (Fresnel and BSDF weights so far)
        depth = mi.UInt32(0)                 # Its number of surface interactions so far
        pending = mi.UInt32(0)               # Branches waiting on this lane's stack ...
        stack = [PendingBranch() for _ in range(self.stack_size())]  # ... top first
        L = mi.Spectrum(0.0)                 # Radiance gathered by the whole tree
        active = mi.Bool(active) & (self.max_depth > 0)  # Lanes with a branch to trace
        # Alpha: the camera ray saw a surface, or a visible environment
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
        if dr.hint(self.hide_emitters, mode="scalar"):
            ray = geometry.skip_area_emitters(ray, active)  # as lathe_path

        while dr.hint(active, max_iterations=-1, label="lathe_whitted"):
            si = geometry.ray_intersect(ray, active, depth == 0)  # camera rays: coherent
            valid = si.is_valid()

            # Emitters seen directly or along a specular chain (area lights
            # hit, the environment on a miss): no other strategy finds them.
            # (hidden: the environment seen by the camera ray itself)
            shown = active & (valid | (depth > 0)) if self.hide_emitters else active
            L += dr.select(shown, weight * si.emitter(scene).eval(si, shown), 0.0)
            vertex = active & valid & (depth + 1 < self.max_depth)

            si, vertex, cos_in_geo = self.incident_check(si, ray, vertex)
            bsdf = si.bsdf(ray)
            # (a surface other than a null one on any branch, as Mitsuba's path)
            valid_ray |= active & valid & ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)

            # ------------- Direct light at diffuse and glossy lobes -------------
            smooth = vertex & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            L += weight * self.direct_light(scene, geometry, sampler, si, bsdf, cos_in_geo, smooth)

            # ---------- The two specular branches, each with its weight ----------
            # (The random numbers only choose among the parts of a mixture.)
            wo_r, weight_r, go_r = self.specular_branch(bsdf, si, REFLECTION, sampler.next_1d(),
                                                        cos_in_geo, vertex)
            wo_t, weight_t, go_t = self.specular_branch(bsdf, si, TRANSMISSION, sampler.next_1d(),
                                                        cos_in_geo, vertex)
            weight_r *= weight
            weight_t *= weight
            go_r &= (dr.max(weight_r) >= self.cutoff) & (dr.max(weight_r) > 0.0)
            go_t &= (dr.max(weight_t) >= self.cutoff) & (dr.max(weight_t) > 0.0)

            # Full stack: one of the two branches, picked in proportion to
            # its weight, carries the weight of both on average.
            pick = go_r & go_t & (pending >= len(stack))
            share_r = dr.max(weight_r) / (dr.max(weight_r) + dr.max(weight_t))
            pick_r = pick & (sampler.next_1d() < share_r)
            weight_r[pick_r] /= share_r
            weight_t[pick & ~pick_r] /= 1.0 - share_r
            go_r &= ~pick | pick_r
            go_t &= ~pick_r

            # ------- Next branch: a child here, else the top of the stack -------
            # Both children: push the reflection, follow the transmission.
            push = go_r & go_t
            follow = go_r | go_t
            pop = active & ~follow & (pending > 0)
            reflected = PendingBranch(si.spawn_ray(wo_r), weight_r, depth + 1)
            stack, popped = push_or_pop(stack, reflected, push, pop)
            pending[push] += 1
            pending[pop] -= 1
            ray_popped = mi.Ray3f(popped.origin, popped.direction, ray.time, ray.wavelengths)
            ray = dr.select(follow, si.spawn_ray(dr.select(go_t, wo_t, wo_r)), ray_popped)
            weight = dr.select(follow, dr.select(go_t, weight_t, weight_r), popped.weight)
            depth = dr.select(follow, depth + 1, popped.depth)
            active = follow | pop

        # A hidden environment seen directly, or only through null surfaces, is black
        return dr.select(valid_ray, L, 0.0), valid_ray, []

    def stack_size(self) -> int:
        """Entries of a lane's stack of pending branches: a branch at depth
        d can leave at most d pending, and never more than MAX_PENDING."""
        return max(min(self.max_depth - 1, MAX_PENDING), 1)

    def incident_check(self, si: mi.SurfaceInteraction3f, ray: mi.Ray3f,
                       vertex: mi.Bool) -> tuple[mi.SurfaceInteraction3f, mi.Bool, mi.Float]:
        """Eq. 11 on the incident side (I . N* must agree with I . N) under
        ``normal_check``: the vertex stops (``terminate``) or takes the
        geometric frame (``fallback``). Returns (si, vertex, cos_in_geo)."""
        cos_in_geo = dr.dot(si.n, -ray.d)
        contradicts = vertex & (cos_in_geo * mi.Frame3f.cos_theta(si.wi) <= 0.0)
        if self.normal_check == "terminate":
            vertex = vertex & ~contradicts
        elif self.normal_check == "fallback":
            si = with_geometric_frame(si, contradicts)
        return si, vertex, cos_in_geo

    def specular_branch(self, bsdf: mi.BSDF, si: mi.SurfaceInteraction3f, lobe: mi.BSDFFlags,
                        sample1: mi.Float, cos_in_geo: mi.Float,
                        active: mi.Bool) -> tuple[mi.Vector3f, mi.Spectrum, mi.Bool]:
        """The branch of the delta ``lobe`` (reflection or transmission) at
        ``si``: world direction, weight and whether it exists (the lobe
        sampled is ``lobe``: see :func:`sample_lobe`). Under
        ``normal_check`` a reflection must stay on the incident side of the
        real surface and a transmission must cross it (eq. 11); ``fallback``
        redoes a contradicting branch with the geometric normal."""
        bs, lobe_weight, exists = sample_lobe(bsdf, si, lobe, sample1, active)
        wo = si.to_world(bs.wo)
        if self.normal_check == "none":
            return wo, lobe_weight, exists
        side = cos_in_geo * dr.dot(si.n, wo)
        bad = exists & ((side <= 0.0) if lobe == REFLECTION else (side >= 0.0))
        if self.normal_check == "terminate":
            return wo, lobe_weight, exists & ~bad
        si_geo = with_geometric_frame(si, bad)
        bs_geo, weight_geo, exists_geo = sample_lobe(bsdf, si_geo, lobe, sample1, bad)
        wo = dr.select(bad, si_geo.to_world(bs_geo.wo), wo)
        lobe_weight = dr.select(bad, weight_geo, lobe_weight)
        exists &= ~bad | exists_geo
        return wo, lobe_weight, exists

    @dr.syntax
    def direct_light(self, scene: mi.Scene, geometry: ExactSceneGeometry, sampler: mi.Sampler,
                     si: mi.SurfaceInteraction3f, bsdf: mi.BSDF, cos_in_geo: mi.Float,
                     active: mi.Bool) -> mi.Spectrum:
        """Light reflected at ``si`` from every emitter, one sample each, with
        its shadow ray: as Whitted (and POV-Ray) sum over all lights, so that
        point, spot and directional lights are exact. (Mitsuba's
        ``Scene.sample_emitter_direction`` would pick one emitter at random,
        which is noise.)"""
        emitters = scene.emitters_dr()
        reflected = mi.Spectrum(0.0)         # Light gathered so far
        index = mi.UInt32(0)                 # The emitter sampled next
        while dr.hint(active & (index < len(scene.emitters())), max_iterations=-1,
                      label="lathe_whitted_lights"):
            emitter = dr.gather(mi.EmitterPtr, emitters, index, active)
            ds, emitter_weight = emitter.sample_direction(si, sampler.next_2d(), active)
            # (A black emitter, e.g. a sky of radiance 0, costs no shadow ray.)
            lit = active & (ds.pdf != 0.0) & (dr.max(emitter_weight) > 0.0)
            if dr.hint(self.normal_check != "none", mode="scalar"):
                # Eq. 11 for the light direction, as in lathe_path.
                side_geo = dr.dot(si.n, ds.d) * cos_in_geo
                side_sh = mi.Frame3f.cos_theta(si.to_local(ds.d)) * mi.Frame3f.cos_theta(si.wi)
                lit &= side_geo * side_sh > 0.0
            visibility = self.visibility(geometry, sampler, si, ds.p, lit)
            bsdf_value = bsdf.eval(mi.BSDFContext(), si, si.to_local(ds.d), lit)
            reflected += dr.select(lit, bsdf_value * emitter_weight * visibility, 0.0)
            index += 1
        return reflected

    def visibility(self, geometry: ExactSceneGeometry, sampler: mi.Sampler, si: mi.SurfaceInteraction3f,
                   target: mi.Point3f, active: mi.Bool) -> mi.Spectrum:
        """How much light passes from ``target`` to ``si`` (``shadows``)."""
        if self.shadows == "filtered":
            return self.filtered_visibility(geometry, sampler, si, target, active)
        occluded = geometry.ray_test(si.spawn_ray_to(target), active)
        return dr.select(occluded, mi.Spectrum(0.0), mi.Spectrum(1.0))

    @dr.syntax
    def filtered_visibility(self, geometry: ExactSceneGeometry, sampler: mi.Sampler,
                            si: mi.SurfaceInteraction3f, target: mi.Point3f,
                            active: mi.Bool) -> mi.Spectrum:
        """Transmittance of the straight segment from ``si`` to ``target``
        (``shadows`` = ``filtered``): the product of the delta (or null)
        transmission weights of the surfaces crossed, each taken for light
        arriving from the outside at that angle, in importance mode so that
        no 1/eta^2 radiance scaling enters; 0 behind any other surface (a
        mixture such as ``mask`` lets light through with its transmitting
        part's probability: :func:`sample_lobe`). The segment walks its
        line through the lathes (line_walk.py): no crossing skipped or
        counted twice."""
        origin = mi.Interaction3f(si)        # Where the segment starts (last surface crossed)
        transmittance = mi.Spectrum(1.0)     # Product of the crossings' transmittances
        crossings = mi.UInt32(0)             # Surfaces crossed so far
        active = mi.Bool(active)             # Lanes whose segment may hit more surfaces
        walk = start_walk(dr.width(active))  # Its line and last lathe crossing (line_walk.py)
        direction = dr.normalize(target - origin.p)  # One line from si to the target
        while dr.hint(active, max_iterations=-1, label="lathe_whitted_shadow"):
            distance = dr.dot(target - origin.p, direction)
            segment = origin.spawn_ray(direction)
            segment.maxt = distance * (1.0 - mi.math.ShadowEpsilon)
            hit, walk = geometry.ray_intersect_walk(segment, active, walk)
            active &= hit.is_valid()
            # The transmittance of light arriving from outside at this angle,
            # also where the segment leaves the glass: it is not refracted,
            # so total internal reflection on the way out would be an
            # artifact of the straight line.
            hit.wi = mi.Vector3f(hit.wi.x, hit.wi.y, dr.abs(hit.wi.z))
            _, crossing, crossed = sample_lobe(hit.bsdf(segment), hit, TRANSMISSION, sampler.next_1d(),
                                               active, mi.TransportMode.Importance)
            transmittance[active] *= dr.select(crossed, crossing, 0.0)
            crossings[active] += 1
            blocked = active & (crossings >= MAX_SHADOW_CROSSINGS)
            transmittance[blocked] = 0.0
            active &= ~blocked & (dr.max(transmittance) > 0.0)
            origin = dr.select(active, mi.Interaction3f(hit), origin)
        return transmittance

    def to_string(self) -> str:
        return (
            f"LatheWhittedIntegrator[max_depth={self.max_depth}, cutoff={self.cutoff:g}, "
            f"shadows='{self.shadows}', normal_check='{self.normal_check}', "
            f"hide_emitters={self.hide_emitters}]"
        )


def register() -> None:
    """Register ``<integrator type="lathe_whitted">`` for the active variant."""
    register_jit_plugin(mi.register_integrator, "lathe_whitted", LatheWhittedIntegrator,
                        lambda props: "lathe_whitted", polarized=False)
