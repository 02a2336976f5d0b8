"""The ``lathe_prb`` integrator: differentiable path tracing with exact lathes
(parameters: :class:`LathePRBIntegrator`).

Differentiable path tracing on the exact lathe geometry of ``lathe_path``.
The primal render is one symbolic loop, as ``lathe_path``'s. The
differential pass (``render_forward``, ``render_backward``) traces the same
paths again (those of the camera samples that meet a surface or see the
environment, the ended paths dropped after every vertex, drawing the
primal render's numbers), one kernel per vertex, with every lathe hit
attached to the lathe's ``points`` parameter by implicit differentiation
(:mod:`lathe_shape.plugin.attached_hits`, docs/method.md eqs. 21-25) and
every ray following the vertices that made it: through a Dirac-delta chain
(a glass's four walls) the directions turn and the later vertices slide as
the profile moves (eqs. 28-30). Dr.Jit's AD graph keeps each vertex for the
reverse pass, so memory grows with the path length (at most
:data:`MAX_DIFFERENTIAL_DEPTH` vertices). BSDF and emitter parameters are
differentiated too. Use it through ``mi.render(scene, params, ...)`` with
``dr.backward`` or ``dr.forward``.

What is differentiated: everything that varies smoothly with the profile at
a fixed set of visible surfaces (shading, the light's distance and angle,
refraction and reflection through glass: "interior" derivatives). Not
included in that part: the change of *which* surface a ray sees. At the
lathe's outline as the camera sees it, that change is added by edge
sampling of the exact silhouette (``silhouette``, docs/method.md eqs.
26-27), and at the lathes' outlines seen through glass by edge sampling
on scan lines (``glass_outlines``, eqs. 41-43); shadow boundaries are left
out (measured in docs/differentiable.md),
as is a delta vertex within ``grazing_cosine`` (0.2) of grazing (eq. 30). Non-lathe
shapes are not differentiated with respect to their geometry.

Eq. 11 under differentiation (docs/method.md, eq. 25): each policy's decision
(terminate, use the geometric frame, reject a light sample) is taken on the
detached values and held fixed; the derivative is that of the branch taken.
The decisions change only on a set of measure zero in parameter space, so
this is the derivative almost everywhere of the rendered estimate.
"""

from __future__ import annotations

import contextlib
import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np
from mitsuba.ad.integrators.common import RBIntegrator, solid_angle_to_area_jacobian

from .attached_hits import attach_lathe_hits, attached_direction, differentiable_lathes
from .glass_outlines import GLASS_OUTLINE_LINES, glass_outline_backward, glass_outline_forward
from .integrator_base import (
    contradicts,
    exact_lathe_base,
    mis_weight,
    normal_check_parameter,
    with_geometric_frame,
)
from .lane_sampler import lane_sampler, unpaired_lane_sampler
from .params import path_parameters, typed_property
from .scene_geometry import ExactSceneGeometry
from .silhouette import outline_backward, outline_forward, outline_samples
from .variants import cuda_callable_safe_kernels, register_jit_plugin

__all__ = ["LathePRBIntegrator", "register"]

#: The differential pass's longest path (its loop keeps every vertex's state
#: for the reverse pass; ``max_depth = -1`` means this).
MAX_DIFFERENTIAL_DEPTH = 64

#: Cosine (incident or outgoing, with the shading normal) below which a Dirac
#: delta vertex's direction and weight are differentiated no more (eq. 30):
#: the default of the ``grazing_cosine`` parameter.
GRAZING_COSINE = 0.2


#: Eq. 30 for a hit's slide along its ray (eq. 23): held below this times
#: ``grazing_cosine``. At 1.0 (0.2), a few single samples of the wine glass's
#: gradient at 1024 spp slid far enough through the glass's chain to carry
#: one pixel 5-10x the finite difference (6 of 24 tested coordinates below a
#: correlation of 0.9); at 1.25 and 1.5 none (all 24 above 0.97). At 1.5 the
#: hollow inverse design lost its inner wall (seed 2: 5.1% of the height
#: against 0.8%); at 1.25 it does as well as at 1.0, at 0.5 worse.
SLIDE_FACTOR = 1.25


#: Sensors whose image position of a world point the outline terms can ask
#: (``sample_direction``; a thin lens's through its centre).
OUTLINE_CAMERAS = frozenset({"PerspectiveCamera", "ThinLensCamera"})


def _parameter_values(params) -> list:
    """The values of ``params``: a ``mi.SceneParameters``, a dict, a list
    or tuple (what ``render_forward`` takes), or a single value."""
    if isinstance(params, mi.SceneParameters):
        return [params[key] for key in params.keys()]
    if isinstance(params, dict):
        return list(params.values())
    if isinstance(params, (list, tuple)):
        return list(params)
    return [params] if params is not None else []


def _sensor(scene: mi.Scene, sensor: int | mi.Sensor) -> mi.Sensor:
    return scene.sensors()[sensor] if isinstance(sensor, int) else sensor


#: Emitters whose sampled weight depends on the shading point only through
#: the solid angle of an area sample (its Jacobian) and a point light's
#: inverse-square distance (:func:`_reattach_emitter_sample` differentiates
#: those factors instead of evaluating the emitter again).
PLAIN_EMITTERS = frozenset({"AreaLight", "PointLight", "EnvironmentMapEmitter", "ConstantBackgroundEmitter",
                            "DirectionalEmitter"})


def plain_emitters(scene: mi.Scene) -> bool:
    """Whether every emitter of ``scene`` is one of :data:`PLAIN_EMITTERS`."""
    return all(emitter.class_name() in PLAIN_EMITTERS for emitter in scene.emitters())


def _reattach_emitter_sample(scene: mi.Scene, si: mi.SurfaceInteraction3f, ds: mi.DirectionSample3f,
                             em_weight: mi.Spectrum, active: mi.Bool, plain: bool = False):
    """The detached emitter sample ``ds`` and its weight, re-evaluated with
    derivatives of the (moving) shading point, as ``prb`` does (textured area
    lights apart). ``plain``: every emitter is one of :data:`PLAIN_EMITTERS`
    (:func:`plain_emitters`): a diffuse area light's radiance at the held
    sample, an environment's in the held direction and a point light's
    intensity do not change, so the weight's derivative is that of the
    Jacobian and of a point light's ``1 / dist^2``, without evaluating the
    emitter again (a call per emitter kind in the reverse pass)."""
    is_surface = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Surface)
    is_infinite = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Infinite)
    to_light = ds.p - si.p
    ds.d = dr.replace_grad(ds.d, dr.select(is_infinite, ds.d, dr.normalize(to_light)))
    # Point lights fall off with this distance (prb keeps it detached)
    ds.dist = dr.replace_grad(ds.dist, dr.select(is_infinite, ds.dist, dr.norm(to_light)))
    # A moving shading point changes the solid angle of the sampled area
    J = solid_angle_to_area_jacobian(si.p, dr.detach(ds.p), dr.detach(ds.n), active & is_surface)
    if plain:
        point = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.DeltaPosition)
        falloff = dr.select(active & point, dr.rcp(dr.square(ds.dist)), 1.0)
        return ds, em_weight * dr.relative_grad(J) * dr.relative_grad(falloff)
    em_val = scene.eval_emitter_direction(si, ds, active)
    inv_pdf = dr.select(ds.pdf != 0, dr.rcp(ds.pdf), 0)
    em_weight = dr.replace_grad(em_weight, em_val * dr.detach(inv_pdf)) * dr.relative_grad(J)
    return ds, em_weight


def scene_lobes(scene: mi.Scene) -> tuple[bool, bool]:
    """Whether any shape of ``scene`` has a BSDF with Dirac-delta lobes, and
    any with other lobes (the differential pass traces only the code the
    scene needs)."""
    flags = [shape.bsdf().flags() for shape in scene.shapes() if shape.bsdf() is not None]
    delta = any(mi.has_flag(f, mi.BSDFFlags.Delta) for f in flags)
    smooth = any(mi.has_flag(f, mi.BSDFFlags.Smooth) for f in flags)
    return delta, smooth


@dataclasses.dataclass
class _Path:
    """The state of a path between two vertices."""

    ray: mi.Ray3f              # The ray to the next vertex (it moves with the vertex that made it)
    depth: mi.UInt32           # Number of surface interactions so far
    L: mi.Spectrum             # Radiance gathered so far
    beta: mi.Spectrum          # Path throughput weight
    eta: mi.Float              # Product of relative IORs (Russian roulette)
    active: mi.Bool            # Lanes whose path goes on
    prev: mi.Interaction3f     # The previous vertex (detached), for MIS of hit emitters
    bsdf_pdf_prev: mi.Float    # BSDF pdf of the direction that left it ...
    bsdf_delta_prev: mi.Bool   # ... and whether it was a Dirac delta
    valid_ray: mi.Bool         # Alpha: the camera ray met a surface or a visible environment


class LathePRBIntegrator(exact_lathe_base(RBIntegrator)):
    """Differentiable path tracing with exact lathes.

    .. pluginparameters::

     * - max_depth
       - |int|
       - The path's longest depth (-1 = infinite; the differential pass stops
         at 64 vertices), as for ``lathe_path``. (Default: 6)

     * - rr_depth
       - |int|
       - Path depth from which Russian roulette may stop paths. (Default: 5)

     * - hide_emitters
       - |bool|
       - Hide directly visible emitters, as for ``lathe_path``. (Default: false)

     * - normal_check
       - |string|
       - The eq. 11 policy where the interpolated shading normal contradicts
         the real surface, as for ``lathe_path``: ``none``, ``terminate`` or
         ``fallback``. (Default: ``fallback``)

     * - silhouette
       - |bool|
       - Add the derivative of the lathes' moving outlines as the camera sees
         them (edge sampling of the exact silhouette,
         :mod:`lathe_shape.plugin.silhouette`). With this or
         ``glass_outlines``, the camera must be ``perspective`` or
         ``thinlens``. (Default: true)

     * - silhouette_spp
       - |int|
       - Camera rays on each side of every outline sample. (Default: 4)

     * - glass_outlines
       - |bool|
       - Add the derivative of the lathes' outlines that the camera sees
         through Dirac-delta chains (the inner rim, the far wall or a solid
         stem seen through a glass's wall): edge sampling on scan lines,
         :mod:`lathe_shape.plugin.glass_outlines`, docs/method.md eqs.
         41-43, with ``silhouette_spp`` paths either side of each crossing.
         Only where the scene has a Dirac-delta BSDF. (Default: true)

     * - glass_outline_lines
       - |int|
       - Scan lines per pixel, across the rows and down the columns, on
         which ``glass_outlines`` looks for those outlines. (Default: 1)

     * - grazing_cosine
       - |float|
       - Eq. 30: a Dirac-delta vertex whose incident or outgoing cosine is
         below this is not differentiated (its derivative is unbounded
         there), nor the slide along its ray of a hit reached through one
         whose cosine is below 1.25 times this. Lower values leave out
         less of the derivative of paths that graze a wall seen through
         glass, at the price of a heavier tail (more variance). In (0, 1).
         (Default: 0.2)
    """

    plugin_name = "lathe_prb"

    def __init__(self, props: mi.Properties) -> None:
        who = type(self).plugin_name
        # Checked before Mitsuba's RBIntegrator reads them (it takes any type
        # and keeps its own copies; its default depth is 6)
        path_parameters(props, who, max_depth_default=6)
        super().__init__(props)
        self.normal_check = normal_check_parameter(props, who)
        self.silhouette = typed_property(props, "silhouette", bool, True, who)
        self.silhouette_spp = typed_property(props, "silhouette_spp", int, 4, who)
        if self.silhouette_spp < 1:
            raise ValueError(f"lathe_prb: parameter 'silhouette_spp' must be >= 1, got {self.silhouette_spp}")
        self.glass_outlines = typed_property(props, "glass_outlines", bool, True, who)
        self.glass_outline_lines = typed_property(props, "glass_outline_lines", int, GLASS_OUTLINE_LINES, who)
        if self.glass_outline_lines < 1:
            raise ValueError("lathe_prb: parameter 'glass_outline_lines' must be >= 1, "
                             f"got {self.glass_outline_lines}")
        self.grazing_cosine = typed_property(props, "grazing_cosine", float, GRAZING_COSINE, who)
        if not 0.0 < self.grazing_cosine < 1.0:
            raise ValueError("lathe_prb: parameter 'grazing_cosine' must be in (0, 1), "
                             f"got {self.grazing_cosine:g}")
        self._differentiating = False
        self._seed, self._sensor = 0, None
        self._lobes = (True, True)
        self._forward_sources: list = []  # (see _forward_tangent)
        self._forward_lathes: list = []
        self._plain_emitters = False

    def prepare_geometry(self, geometry: ExactSceneGeometry) -> None:
        """The differentiable lathes' index maps, built here, outside the
        traced loop (no new buffers inside it)."""
        for lathe in differentiable_lathes(geometry.lathes):
            lathe.profile_index  # noqa: B018

    def render_forward(self, scene: mi.Scene, params, sensor=0, seed=0, spp=0):
        with cuda_callable_safe_kernels():
            image = self._render_forward(scene, params, sensor, seed, spp)
            dr.eval(image)  # its kernels assembled here, within the flag's scope
        return image

    def render_backward(self, scene: mi.Scene, params, grad_in, sensor=0, seed=0, spp=0):
        with cuda_callable_safe_kernels():
            self._render_backward(scene, params, grad_in, sensor, seed, spp)

    def _render_forward(self, scene: mi.Scene, params, sensor, seed, spp):
        camera = _sensor(scene, sensor)
        silhouette, through_glass = self._outline_terms(scene, camera)
        # Before the interior pass, which consumes the parameters' tangents
        terms = []
        if silhouette:
            terms.append(outline_forward(self, scene, camera, seed, self.silhouette_spp))
        if through_glass:
            terms.append(glass_outline_forward(self, scene, camera, seed, self.silhouette_spp,
                                               self.glass_outline_lines))
        # (the parameters other than the lathes' points whose tangents the
        # interior pass propagates, see _forward_tangent)
        self._forward_lathes = lathes = self.geometry(scene).lathes
        self._forward_sources = [value for value in _parameter_values(params)
                                 if not any(value is lathe.profile_points for lathe in lathes)]
        try:
            with self._attached_pass_only(seed, camera):
                image = super().render_forward(scene, params, sensor, seed, spp)
        finally:
            self._forward_sources = []
        for term in terms:
            image += mi.TensorXf(term[..., : image.shape[2]].astype(np.float32))
        return image

    def _render_backward(self, scene: mi.Scene, params, grad_in, sensor, seed, spp):
        camera = _sensor(scene, sensor)
        silhouette, through_glass = self._outline_terms(scene, camera)
        if silhouette or through_glass:
            # The outline pieces (numpy: it waits for queued kernels) before
            # the interior pass is queued: that pass's kernel then runs while
            # the outline terms are traced
            if silhouette:
                pieces = outline_samples(camera, differentiable_lathes(self.geometry(scene).lathes))
            grad_image = np.array(grad_in)
        with self._attached_pass_only(seed, camera):
            super().render_backward(scene, params, grad_in, sensor, seed, spp)
        if silhouette:
            outline_backward(self, scene, camera, grad_image, seed, self.silhouette_spp, pieces)
        if through_glass:
            glass_outline_backward(self, scene, camera, grad_image, seed, self.silhouette_spp,
                                   self.glass_outline_lines)

    def _outline_terms(self, scene: mi.Scene, camera: mi.Sensor) -> tuple[bool, bool]:
        """Whether the outline term and the through-glass outline term
        apply: asked for, a lathe's points are differentiated (the outline
        terms are their derivative alone: a gradient of BSDF or emitter
        parameters needs neither), and for the second the scene has a
        Dirac-delta BSDF; and the camera maps points to the image."""
        moving = any(dr.grad_enabled(lathe.profile_points) for lathe in self.geometry(scene).lathes)
        silhouette = self.silhouette and moving
        through_glass = self.glass_outlines and moving and scene_lobes(scene)[0]
        if (silhouette or through_glass) and camera.class_name() not in OUTLINE_CAMERAS:
            raise ValueError(
                f"lathe_prb: the outline terms (parameters 'silhouette' and 'glass_outlines') need a "
                f"perspective or thinlens camera, not sensor '{camera.id()}' ({camera.class_name()}): "
                f"set both to false for the gradient without them")
        return silhouette, through_glass

    def sample(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
               δL: mi.Spectrum | None, state_in: mi.Spectrum | None, active: mi.Bool,
               **kwargs) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float], mi.Spectrum]:
        if mode != dr.ADMode.Primal:
            return self.sample_attached(mode, scene, sampler, ray, δL, active)
        if self._differentiating:
            # The base class's primal pass before a differential one: its
            # radiance would only be the state handed to that pass, which
            # the attached pass does not read (it traces its own)
            nothing = dr.zeros(mi.Spectrum, dr.width(ray))
            return nothing, dr.zeros(mi.Bool, dr.width(ray)), [], nothing
        return self.sample_primal(scene, sampler, ray, active)

    @contextlib.contextmanager
    def _attached_pass_only(self, seed, sensor: mi.Sensor):
        """Within: the base class's render_forward/render_backward skip
        their primal pass (see :meth:`sample`); the render's ``seed`` and
        ``sensor`` give the attached pass's sampler (:meth:`_camera_hits`)."""
        self._differentiating, self._seed, self._sensor = True, seed, sensor
        try:
            yield
        finally:
            self._differentiating = False

    def _camera_hits(self, scene: mi.Scene, geometry: ExactSceneGeometry, ray: mi.Ray3f, active: mi.Bool):
        """The path states of the camera rays that meet a surface or see the
        environment, one lane each (compacted), their lanes among ``ray``'s,
        the alpha of every lane, and a sampler for the compacted lanes. A
        camera ray that meets nothing and sees no environment has a zero
        derivative, and the attached pass, whose per-vertex kernels and
        reverse pass read every lane's stored values, skips it (on the
        diffuse vase of ``bench_gradients.py``, 63% of the lanes). The
        compacted lanes draw the numbers the sensor's ``independent``
        sampler draws for them in the primal render
        (:func:`~lathe_shape.plugin.lane_sampler.lane_sampler`: the gradient
        and a finite difference of primal renders see the same paths); with
        another sampler, from an ``independent`` sampler of their own."""
        start = self._start(scene, geometry, ray, active)
        with dr.suspend_grad():
            hit = start.active & geometry.ray_intersect(start.ray, start.active, True).is_valid()
        # (a visible environment's own parameters are differentiated where
        # a camera ray sees it: those lanes are kept too)
        kept = hit | (start.active & start.valid_ray)
        dr.eval(kept, hit, start.ray)  # (one kernel: the rays are gathered below)
        lanes = dr.compress(kept)
        count = dr.width(lanes)
        alpha = start.valid_ray | hit
        if count == 0:
            return None, lanes, alpha, None
        # (the start's other fields are values every lane shares)
        path = dataclasses.replace(start, ray=dr.gather(mi.Ray3f, start.ray, lanes),
                                   active=dr.full(mi.Bool, True, count))
        sampler = lane_sampler(self._sensor, self._seed, lanes)
        if sampler is None:
            sampler = unpaired_lane_sampler(self._seed, count)
        return path, lanes, alpha, sampler

    def _start(self, scene: mi.Scene, geometry: ExactSceneGeometry, ray: mi.Ray3f, active: mi.Bool,
               depth: mi.UInt32 | None = None) -> _Path:
        """The path state of the camera ray ``ray``, or with ``depth`` of a
        ray that leaves a Dirac-delta vertex at that path depth."""
        active = mi.Bool(active)
        ray = mi.Ray3f(dr.detach(ray))
        if self.hide_emitters and depth is None:
            ray = geometry.skip_area_emitters(ray, active)  # as Mitsuba's prb
        # Alpha: the camera ray met a surface, or a visible environment
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
        depth = mi.UInt32(0) if depth is None else mi.UInt32(depth)
        return _Path(ray, depth, mi.Spectrum(0), mi.Spectrum(1), mi.Float(1), active,
                     dr.zeros(mi.Interaction3f), mi.Float(1), mi.Bool(True), valid_ray)

    def sample_from(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
                    depth: mi.UInt32) -> mi.Spectrum:
        """The primal radiance along ``ray``, which leaves a Dirac-delta
        vertex of a camera path at path ``depth`` (the paths the image
        continues there: ``max_depth`` counts from the camera, emitters are
        seen as after any delta vertex)."""
        return self.sample_primal(scene, sampler, ray, mi.Bool(True), depth)[0]

    @dr.syntax
    def sample_primal(self, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f, active: mi.Bool,
                      depth: mi.UInt32 | None = None
                      ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float], mi.Spectrum]:
        """The primal render: the paths of :meth:`sample_attached`, detached,
        in one symbolic loop (from path ``depth``: :meth:`sample_from`)."""
        geometry = self.geometry(scene)
        path = self._start(scene, geometry, ray, active, depth)  # Path state (see _Path)
        while dr.hint(path.active, max_iterations=self.max_depth, label="lathe_prb (Primal)"):
            path = self._vertex(scene, geometry, sampler, path, self.max_depth, False)
        return path.L, path.valid_ray, [], path.L

    def sample_attached(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
                        δL: mi.Spectrum | None, active: mi.Bool
                        ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float], mi.Spectrum]:
        """The differential pass (docs/method.md, eqs. 28-29): the paths of
        the primal render traced again with every lathe vertex attached to
        the profile and every ray following the vertices that made it, so
        that a Dirac-delta chain (glass walls, mirrors) turns and slides as
        the profile moves. Only the camera samples that meet a surface or
        see the environment (:meth:`_camera_hits`), and after every vertex
        only the paths that go on (:meth:`_compact`). One kernel per
        vertex; Dr.Jit's AD graph then holds every vertex for the reverse
        pass (memory grows with the path length, up to
        :data:`MAX_DIFFERENTIAL_DEPTH` vertices)."""
        geometry = self.geometry(scene)
        self._lobes = scene_lobes(scene)
        self._plain_emitters = plain_emitters(scene)
        max_depth = min(self.max_depth, MAX_DIFFERENTIAL_DEPTH)
        width = dr.width(ray)
        path, lanes, alpha, sampler = self._camera_hits(scene, geometry, ray, active)
        nothing = dr.zeros(mi.Spectrum, width)
        if path is None:  # nothing seen: zero derivative
            return nothing, alpha, [], nothing
        with dr.resume_grad():
            count = dr.width(lanes)
            index = dr.arange(mi.UInt32, count)  # Each path's lane among the camera hits
            L = dr.zeros(mi.Spectrum, count)     # The radiance of the paths that ended
            for _ in range(max_depth):
                stored: list = []  # The vertex's detached values the reverse pass reads
                path = self._vertex(scene, geometry, sampler, path, max_depth, True, stored)
                # Evaluated vertex by vertex, in one kernel with the values
                # it stores: unevaluated, each vertex's kernel would
                # recompute the whole path before it
                sampler.schedule_state()
                dr.eval(path, stored)
                going = int(dr.count(path.active)[0])
                if going == 0:
                    break
                # The paths that ended leave (their radiance is final); the
                # others go on alone. At every vertex, even where none
                # ended: the reverse pass then has one kernel per vertex, the
                # same code every render (compacting only where many ended
                # grouped the vertices differently from render to render,
                # and each grouping compiled its own reverse kernels)
                path, index, sampler, L = self._compact(path, index, sampler, L, going)
            dr.scatter(L, path.L, index)  # (the paths left)
            dr.eval(L)  # (a scatter's target: evaluated before another kernel reads it)
            # (the fourth output, the primal radiance, is read by no caller:
            # zero, not scattered back)
            if not dr.grad_enabled(L):  # no lathe seen: zero derivative
                return nothing, alpha, [], nothing
            if mode == dr.ADMode.Backward:
                dr.backward_from(dr.gather(mi.Spectrum, δL, lanes) * L)
                return nothing, alpha, [], nothing
            derivative = dr.zeros(mi.Spectrum, width)
            dr.scatter(derivative, self._forward_tangent(L), lanes)
            dr.eval(derivative)  # (a scatter's target: evaluated before another kernel reads it)
            return derivative, alpha, [], nothing

    def _forward_tangent(self, L: mi.Spectrum) -> mi.Spectrum:
        """The tangent of ``L`` for the tangents set on the render's
        parameters. With the lathes' points alone, ``dr.forward_to(L)``.
        With other parameters (a BSDF's, an emitter's), propagated forward
        from them: ``dr.forward_to(L)``, which traverses only towards
        ``L``, refused the edges from a parameter into a BSDF's or
        emitter's method called as a function, such as a diffuse
        reflectance's ("tried to forward-propagate derivatives across edge
        ... outside of the current dr.isolate_grad() scope"). That
        propagation reaches every graph built on those parameters, and
        consumes it (Mitsuba's ``prb`` refuses the case outright)."""
        sources = [value for value in self._forward_sources if dr.grad_enabled(value)]
        if not sources:
            return dr.forward_to(L)  # (the lathes' points alone: read outside any such method)
        points = [lathe.profile_points for lathe in self._forward_lathes]
        dr.enqueue(dr.ADMode.Forward, *sources, *(value for value in points if dr.grad_enabled(value)))
        # (the sources' tangents consumed, as forward_to does; interior ones kept: L's is read)
        dr.traverse(dr.ADMode.Forward, dr.ADFlag.ClearEdges | dr.ADFlag.ClearInput)
        tangent = dr.grad(L)
        dr.eval(tangent)
        return mi.Spectrum(tangent)

    @staticmethod
    def _compact(path: _Path, index: mi.UInt32, sampler, L: mi.Spectrum, going: int):
        """The paths of ``path`` that go on, alone (their lanes among the
        camera hits, ``index``, and their samplers' states gathered), after
        the radiance of those that ended is scattered to their lanes of
        ``L``."""
        dr.scatter(L, path.L, index, ~path.active)
        dr.eval(L)
        keep = dr.compress(path.active)
        fields, width = {}, dr.width(path.active)
        for field in dataclasses.fields(path):
            value = getattr(path, field.name)
            if field.name == "active":
                value = dr.full(mi.Bool, True, going)
            elif dr.width(value) == width and width > 1:  # (not a value every lane shares)
                # (each lane once: a permutation in the reverse pass,
                # whatever the sizes)
                value = dr.gather(type(value), value, keep, mode=dr.ReduceMode.Permute)
            fields[field.name] = value
        return _Path(**fields), dr.gather(mi.UInt32, index, keep), sampler.take(keep), L

    def _vertex(self, scene: mi.Scene, geometry: ExactSceneGeometry, sampler: mi.Sampler, path: _Path,
                max_depth: int, attached: bool, stored: list | None = None) -> _Path:
        """One path vertex: the hit of ``path.ray``, its emission, a light
        sample and a BSDF sample (eq. 11 as ``normal_check`` says), the
        next ray and Russian roulette. ``attached``: the vertex moves with
        the profile (derivatives recorded, see :meth:`sample_attached`);
        ``stored`` then receives the detached values (hit, samples, MIS
        weights) that the reverse pass reads instead of recomputing them,
        evaluated with the path state."""
        check = self.normal_check
        ctx = mi.BSDFContext()
        ray, depth, beta, eta, active = path.ray, path.depth, path.beta, path.eta, path.active
        si = geometry.ray_intersect(ray, active, depth == 0)
        if attached:
            if not dr.grad_enabled(ray):
                # Stored, so that the reverse pass reads the hit instead of
                # tracing the ray again (a moving ray's hit is stored by
                # ray_intersect)
                stored.append(si)
            si = attach_lathe_hits(geometry.lathes, ray, si)
        si_detached = dr.detach(si)
        valid_ray = path.valid_ray | (active & si.is_valid() & (depth == 0))
        cos_in_geo = dr.dot(si_detached.n, -dr.detach(ray.d))
        if attached:
            # A hit near grazing slides without bound along its ray (eq.
            # 23's slope n . d vanishes): held in place within eq. 30's
            # SLIDE_FACTOR * grazing_cosine where the ray came through a
            # Dirac delta (where such slides compound along a glass's
            # chain; a camera ray's or a diffuse bounce's hit moves as it
            # must)
            slope = dr.abs(cos_in_geo) * dr.rcp(dr.norm(dr.detach(ray.d)))
            grazing = si_detached.is_valid() & (slope < SLIDE_FACTOR * self.grazing_cosine)
            si = dr.select(grazing & path.bsdf_delta_prev & (depth > 0), si_detached, si)

        # ------------ Eq. 11, incident side (eq. 25: decided detached) ------------
        active_next = active & si.is_valid() & (depth + 1 < max_depth)
        bad_in = active_next & (cos_in_geo * mi.Frame3f.cos_theta(si_detached.wi) <= 0.0)
        if check == "terminate":
            active_next &= ~bad_in
        elif check == "fallback":
            si = with_geometric_frame(si, bad_in)
            si_detached = dr.detach(si)
        bsdf = si.bsdf(ray)

        # -------------------- Direct emission (BSDF-sampled) --------------------
        ds = mi.DirectionSample3f(scene, si=si_detached, ref=path.prev)
        pdf_em = scene.pdf_emitter_direction(path.prev, ds, ~path.bsdf_delta_prev)
        mis = mis_weight(path.bsdf_pdf_prev, pdf_em)
        if attached:
            stored.append(mis)  # (as the hit)
        show = active & (depth > 0) if self.hide_emitters else active
        L = path.L + beta * mis * ds.emitter.eval(si, show)

        # --------------------------- Emitter sampling ----------------------------
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds, em_weight = scene.sample_emitter_direction(si_detached, sampler.next_2d(), False, active_em)
        active_em &= ds.pdf != 0.0
        if check != "none":
            side_geo = dr.dot(si_detached.n, ds.d) * cos_in_geo
            side_sh = mi.Frame3f.cos_theta(si_detached.to_local(ds.d)) * mi.Frame3f.cos_theta(si_detached.wi)
            active_em &= side_geo * side_sh > 0.0
        active_em &= ~geometry.ray_test(si_detached.spawn_ray_to(ds.p), active_em)
        if attached:
            stored.append((active_em, ds, em_weight))  # (as the hit: not traced again)
        if attached:
            ds, em_weight = _reattach_emitter_sample(scene, si, ds, em_weight, active_em,
                                                     self._plain_emitters)
        bsdf_val_em, bsdf_pdf_em = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active_em)
        mis_em = dr.select(ds.delta, 1, mis_weight(ds.pdf, dr.detach(bsdf_pdf_em)))
        L += dr.select(active_em, beta * mis_em * bsdf_val_em * em_weight, 0)

        # ------------------ BSDF sampling (eq. 11 on the detached draw) ------------------
        sample_1, sample_2 = sampler.next_1d(), sampler.next_2d()
        bs, bsdf_weight = bsdf.sample(ctx, si_detached, sample_1, sample_2, active_next)
        wo_world = si_detached.to_world(bs.wo)
        if check != "none":
            bad_out = active_next & contradicts(si_detached, cos_in_geo, bs, wo_world, bsdf_weight)
            if check == "fallback":
                # Drawn again in the geometric frame (the same call site)
                sample_1 = dr.select(bad_out, sampler.next_1d(), sample_1)
                sample_2 = dr.select(bad_out, sampler.next_2d(), sample_2)
                si = with_geometric_frame(si, bad_out)
                si_detached = dr.detach(si)
                redrawn, weight_redrawn = bsdf.sample(ctx, si_detached, sample_1, sample_2, bad_out)
                bs = dr.select(bad_out, redrawn, bs)
                bsdf_weight = dr.select(bad_out, weight_redrawn, bsdf_weight)
                wo_world = dr.select(bad_out, si_detached.to_world(bs.wo), wo_world)
            else:
                active_next &= ~bad_out
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        if attached:
            stored.append((bs, bsdf_weight, wo_world, sample_2, active_next))  # (as the hit)
            wo_world, factor = attached_direction(bsdf, ctx, si, bs, wo_world, sample_2, active_next,
                                                   self._lobes, self.grazing_cosine, stored)
            bsdf_weight = bsdf_weight * factor
        beta = beta * bsdf_weight
        eta = eta * bs.eta

        # ---------------------------- Russian roulette ----------------------------
        beta_max = dr.max(mi.unpolarized_spectrum(dr.detach(beta)))
        active_next &= beta_max != 0
        rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
        rr_active = depth >= self.rr_depth
        beta[rr_active] *= dr.rcp(rr_prob)
        active_next &= ~rr_active | (sampler.next_1d() < rr_prob)

        depth = dr.select(si_detached.is_valid(), depth + 1, depth)
        return _Path(si.spawn_ray(wo_world), depth, L, beta, eta, active_next, mi.Interaction3f(si_detached),
                     bs.pdf, delta, valid_ray)

    def to_string(self) -> str:
        depth = -1 if self.max_depth == 0xFFFFFFFF else self.max_depth
        return (f"LathePRBIntegrator[max_depth={depth}, rr_depth={self.rr_depth}, "
                f"hide_emitters={self.hide_emitters}, normal_check='{self.normal_check}']")


def register() -> None:
    """Register ``<integrator type="lathe_prb">`` for the active variant."""
    register_jit_plugin(mi.register_integrator, "lathe_prb", LathePRBIntegrator, lambda props: "lathe_prb")
