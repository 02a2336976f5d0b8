"""Ray queries against a scene whose lathes are intersected exactly.

Mitsuba 3.9.1's accelerator cannot call Python intersection code, so the
exact lathes are merged with Mitsuba's own hit here: a second scene holds the
original scene's non-lathe shape objects (the objects are shared, so BSDFs,
area emitters and textures are the same), Mitsuba traces it, and every lathe's
exact kernel is run with the ray's ``maxt`` shortened to that hit. The lathes'
reference triangles are therefore never reported.

The surface interaction of a hit on those few shapes is computed by calls
of their own methods (:func:`rest_interaction`), not by Mitsuba's virtual
call over ``mi.ShapePtr``: Dr.Jit records that call once for every shape
alive in the process (lathes included, whether in this scene or not), on
every render: the render kernel would hold the lathes' reference meshes'
code (never run: the second scene has no lathe), and with many lathes its
cost grew with the lathe count far more than the lathes' own traversal.
More than :data:`DIRECT_SHAPES` such shapes, or instances among them, go
through Mitsuba's call.

Lathes are intersected by kind (see kernels/top_level.py): a kind with
several lathes goes through one :class:`~lathe_shape.kernels.top_level.LatheSet`
(their profiles' kernel data concatenated, lathes of the same profile
sharing it, and a BVH over the lathes' world boxes), so the traced kernel
is the same for 2 or 2000 lathes and a ray only visits the lathes whose box
it enters; a kind with one lathe calls that lathe's own kernel.

A ray that goes on straight past a lathe crossing (the integrator passes
the :class:`~lathe_shape.plugin.line_walk.LineWalk` of its previous hit to
:meth:`ExactSceneGeometry.ray_intersect_walk`) queries the lathes on the
line that crossing was found on, for the crossing after it: no offset, so
no crossing skipped or taken twice. Mitsuba's shapes are traced on that
line too, from the crossing taken; a lathe crossing must come before their
hit by more than the spawn offset (where a lathe touches a shape, the
shape wins).

An integrator may hand the shadow ray of its last vertex to that query
(:meth:`ExactSceneGeometry.walk_and_test`, as ``lathe_path`` does): a
single polyline lathe then answers both rays in one traced traversal, so
that the kernel's longest code is compiled once per render kernel, not
twice (the first render from an empty kernel cache is mostly LLVM's
compilation).

The second scene is built once per set of shapes. A lathe that moves
(:meth:`LatheShape.set_to_world`) is followed before the next query: its
kind's transforms and top-level BVH are rebuilt as opaque arrays (no
recompilation); when other shapes move (through
``mi.traverse`` of the original scene, which updates the shared objects in
place) only the second scene's acceleration structure is rebuilt
(:meth:`ExactSceneGeometry.refresh`): automatically when a shape's bounding
box changed (or an emitting lathe's transform or profile, see
:func:`~lathe_shape.plugin.shape.mesh_state`), and after
:meth:`ExactSceneGeometry.mark_moved` for a move that keeps it (say a square
floor turned by 90 degrees).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from operator import attrgetter, is_not

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.common import NO_CROSSING, after_t_with_ties, opaque
from ..kernels.top_level import NO_LATHE, CrossingPlace, LatheSet, ProfileTable, SetHit
from ..surfaces import kind_of
from .interaction import lathe_interaction
from .line_walk import LineWalk, continues_line
from .shape import LatheShape, mesh_state, own_mesh_updates, scene_lathes, warn_open_dielectrics

__all__ = ["ExactSceneGeometry", "LatheGroup", "profile_key"]

_SURFACE = attrgetter("surface")
_MATRIX = attrgetter("to_world_matrix")


class ExactSceneGeometry:
    """Nearest-hit and shadow-ray queries with every lathe made exact."""

    def __init__(self, scene: mi.Scene) -> None:
        # No reference to the scene itself: it owns the integrator that owns
        # this object (a cycle through C++ references would never be freed).
        self.fingerprint = self.scene_fingerprint(scene)
        self.state = self.rest_state(scene)
        shapes = scene.shapes()
        self.lathes: list[LatheShape] = [s for s in scene_lathes(scene) if _exact(s)]
        warn_open_dielectrics(scene)  # (open dielectric sheets no other sheet closes)
        others = [s for s in shapes if not _exact(s)]
        by_kind: dict[object, list[LatheShape]] = {}
        for lathe in self.lathes:
            # Kinds of one kernel layout (the B-spline kernel's cubic kinds)
            # share a set.
            by_kind.setdefault(id(kind_of(lathe.surface).layout), []).append(lathe)
        #: Lathes intersected by their own kernel (the only one of their kind).
        self.single = [group[0] for group in by_kind.values() if len(group) == 1]
        #: Kinds of several lathes, each intersected as one set.
        self.groups = [LatheGroup(group) for group in by_kind.values() if len(group) > 1]
        # Lathe indices of walks (line_walk.py): the single lathes', then
        # each group's in turn
        first = len(self.single)
        for group in self.groups:
            group.number_from(first)
            first += len(group.lathes)
        if any(s.class_name() == "Instance" for s in others):
            self._refuse_instanced_lathes(scene)
            if self.lathes:
                # Mitsuba 3.9 cannot load an instance into another scene
                # (load_dict fails with "Couldn't find key"): say why.
                raise RuntimeError(
                    "the exact integrators (lathe_path, lathe_whitted, lathe_prb) cannot render a "
                    "scene with <shapegroup> instances and lathes: they trace the shapes other than "
                    "lathes in a scene of their own, and Mitsuba cannot place an instance there. "
                    "Replace the instances by shapes, or render the scene with a stock integrator."
                )
        #: The non-lathe shapes whose surface interaction is computed by
        #: their own calls (see :func:`rest_interaction`); ``None``: by
        #: Mitsuba's call (no lathes, too many shapes, or instances).
        self.direct = others if direct_interaction(others, len(self.lathes)) else None
        if not self.lathes:
            self.rest = scene
        else:
            description: dict[str, object] = {"type": "scene"}
            ids = [shape.id() for shape in others]
            for index, shape in enumerate(others):
                description[f"shape_{index}"] = shape
            self.rest = mi.load_dict(description)
            # load_dict renames the shared objects after their keys; restore
            # their ids so that mi.traverse(scene) keeps the user's names.
            for shape, name in zip(others, ids, strict=True):
                shape.set_id(name)

    def _refuse_instanced_lathes(self, scene: mi.Scene) -> None:
        """Lathes inside a <shapegroup> are only reached through Mitsuba's
        instances, which cannot call the exact kernel: say so instead of
        silently rendering their reference mesh."""
        direct = {lathe.ptr for lathe in scene_lathes(scene)}
        params = mi.traverse(scene)
        for key in params.keys():
            node = params.properties[key][2]
            if isinstance(node, LatheShape) and node.ptr not in direct:
                name = f"lathe '{node.id()}'" if node.id() else f"a lathe ({key.rsplit('.', 1)[0]})"
                raise RuntimeError(
                    f"{name} is inside a <shapegroup>; the exact integrators (lathe_path, "
                    "lathe_whitted, lathe_prb) cannot intersect instanced lathes. Place it in the "
                    "scene directly (several lathes with their own to_world), or render the scene "
                    "with a stock integrator."
                )

    @staticmethod
    def scene_fingerprint(scene: mi.Scene) -> tuple:
        """Identity of every shape (lathes apart): changes when the scene is
        another one or its shapes are others."""
        return tuple((shape.ptr, _exact(shape)) for shape in scene.shapes())

    @staticmethod
    def rest_state(scene: mi.Scene) -> tuple:
        """State of the shapes traced by Mitsuba (all but the exact
        lathes; :func:`~.shape.mesh_state`): changes when one is moved or
        edited."""
        return tuple(mesh_state(shape) for shape in scene.shapes() if not _exact(shape))

    def matches(self, scene: mi.Scene) -> bool:
        """Whether this geometry is still valid for ``scene``: the same
        shapes, none of the non-lathe ones moved since (lathes may move)."""
        return self.fingerprint == self.scene_fingerprint(scene) and self.state == self.rest_state(scene)

    @classmethod
    def for_scene(cls, scene: mi.Scene, previous: ExactSceneGeometry | None = None) -> ExactSceneGeometry:
        """The geometry of ``scene``: ``previous`` while it matches; when
        only non-lathe shapes moved, a new geometry sharing ``previous``'s
        second scene with its acceleration structure rebuilt (no new
        scene); else a new one."""
        if previous is None or previous.fingerprint != cls.scene_fingerprint(scene):
            return cls(scene)
        previous.follow_moves()
        if previous.state == cls.rest_state(scene):
            return previous
        moved = copy.copy(previous)
        moved.refresh()
        moved.state = cls.rest_state(scene)
        return moved

    def accept_moves(self, scene: mi.Scene) -> None:
        """The caller moved non-lathe shapes through ``mi.traverse(self.rest)``
        (which rebuilt this scene's structure): their new state is valid."""
        self.state = self.rest_state(scene)

    def mark_moved(self) -> None:
        """Non-lathe shapes moved (perhaps keeping their bounds): the next
        :meth:`for_scene` rebuilds their acceleration structure."""
        self.state = None

    def refresh(self) -> None:
        """Rebuild the acceleration structure of the non-lathe shapes after
        they were moved or edited in the original scene (the objects are
        shared: only this scene's own structure is stale)."""
        if self.rest is None or not self.lathes:
            return  # without lathes the original scene is traced directly
        params = mi.traverse(self.rest)
        for key in params.keys():
            if key.split(".")[-1] in ("to_world", "vertex_positions"):
                params.set_dirty(key)
        with own_mesh_updates(self.rest.shapes()):  # (emitting lathes are here)
            params.update()

    def follow_moves(self) -> None:
        """Bring the lathe sets up to date with lathes moved since the last
        query (numpy; no recompilation)."""
        for group in self.groups:
            group.follow_moves()

    def ray_intersect(self, ray: mi.Ray3f, active: mi.Bool,
                      coherent: mi.Bool | bool = False) -> mi.SurfaceInteraction3f:
        """Nearest surface interaction along ``ray`` (``t = inf`` on a miss);
        ``coherent``: as Mitsuba's (camera rays: Embree traces the rest of
        the scene faster). The hit is found on the detached ray; where
        ``ray`` carries derivatives (a differentiated path's moving ray),
        the other shapes' interactions follow them (Mitsuba recomputes its
        shapes' hits along a differentiable ray) and ``wi`` is the moving
        ray's; lathe hits stay detached (attach them with
        :func:`~lathe_shape.plugin.attached_hits.attach_lathe_hits`)."""
        self.follow_moves()
        attached, ray = ray, mi.Ray3f(dr.detach(ray))
        with dr.suspend_grad():  # the kernels' loops record no derivatives
            pi, si = self._rest_preliminary(ray, active, coherent)
            won = mi.Bool(False)  # a lathe is nearer than the rest
            for lathe in self.single:
                ray_lathe = mi.Ray3f(ray)
                ray_lathe.maxt = dr.minimum(ray.maxt, si.t)
                si_lathe = lathe.ray_intersect_exact(ray_lathe, active)
                take = si_lathe.t < si.t
                si, won = dr.select(take, si_lathe, si), won | take
            for group in self.groups:
                si_group = group.ray_intersect(ray, dr.minimum(ray.maxt, si.t), active)
                take = si_group.t < si.t
                si, won = dr.select(take, si_group, si), won | take
        if dr.grad_enabled(attached):
            # The moving ray's interaction with the other shapes is
            # differentiated from this hit: stored, so that a reverse pass
            # reads it instead of tracing the ray again
            dr.eval(pi, si, won)
        return _with_wi(dr.select(won, si, self._rest_interaction(attached, pi, active & ~won)), attached)

    def ray_intersect_walk(self, ray: mi.Ray3f, active: mi.Bool, walk: LineWalk,
                           coherent: mi.Bool | bool = False) -> tuple[mi.SurfaceInteraction3f, LineWalk]:
        """Nearest surface interaction along ``ray``, a ray that may go on
        along the line of ``walk`` past its last lathe crossing: see
        :meth:`walk_and_test`, which this is without a shadow ray."""
        si, walk, _ = self.walk_and_test(ray, active, walk, coherent)
        return si, walk

    def walk_and_test(self, ray: mi.Ray3f, active: mi.Bool, walk: LineWalk,
                      coherent: mi.Bool | bool = False, shadow: mi.Ray3f | None = None,
                      shadow_active: mi.Bool | None = None
                      ) -> tuple[mi.SurfaceInteraction3f, LineWalk, mi.Bool]:
        """Nearest surface interaction along ``ray``, a ray that may go on
        along the line of ``walk`` past its last lathe crossing (see
        :mod:`~lathe_shape.plugin.line_walk`): where it does, the lathes
        are queried on that line for the crossing after the one taken (no
        offset, none skipped or found twice); elsewhere as
        :meth:`ray_intersect` (``coherent`` too). With ``shadow``, also
        :meth:`ray_test` of that ray (lanes ``shadow_active``): a single
        polyline lathe then answers both rays with one traced traversal
        (:meth:`LatheShape.walk_and_test_exact`), compiled once instead of twice,
        which shortens a render's first, uncached compilation. Returns the
        interaction (``t`` along ``ray``), the walk to pass with the next
        ray and whether ``shadow`` is occluded (False without it)."""
        self.follow_moves()
        occluded = mi.Bool(False)  # the shadow ray is blocked
        if shadow is not None:
            occluded = self.rest.ray_test(shadow, shadow_active)
        same = mi.Bool(active) & continues_line(ray, walk)
        line = mi.Ray3f(ray)
        line.o = dr.select(same, walk.o, ray.o)
        line.d = dr.select(same, walk.d, ray.d)
        t0 = dr.select(same, walk.t, 0.0)  # the line's parameter at ray.o
        # A walked lathe crossing must come before another shape's hit by
        # more than the spawn offset of ray.o, as it had to on the offset
        # ray (Mitsuba's spawn_ray): where a lathe touches a shape (a glass
        # standing on a floor, bottom and floor coplanar) the shape wins.
        spawn_offset = (1.0 + dr.max(dr.abs(ray.o))) * mi.math.RayEpsilon * dr.rcp(dr.norm(ray.d))
        margin = dr.select(same, spawn_offset, 0.0)
        # ... both measured on the walked line: the other shapes too are
        # traced from the crossing taken (which lies on none of them: a tie
        # there went to the shape), not from the offset origin, which is
        # off the line (moved along a leaning wall's normal it would put the
        # floor farther than the glass's coplanar bottom)
        ray = mi.Ray3f(ray)
        ray.o = dr.select(same, line(t0), ray.o)
        ray.d = line.d
        pi, si = self._rest_preliminary(ray, active, coherent)
        after = CrossingPlace(dr.select(same, walk.lathe, NO_LATHE), walk.s, walk.key, t0)
        walk = LineWalk(line.o, line.d, dr.full(mi.UInt32, NO_LATHE, dr.width(t0)), walk.s, walk.key, t0)
        won = mi.Bool(False)  # a lathe is nearer than the rest
        t_rest = si.t         # the rest's hit (along ray)
        hits = []             # (nearer, hit) of each lathe and set, in turn
        # Lathes and sets in the order of their walk indices: at equal t on
        # the line the first asked keeps the crossing (eq. 31)
        for index, lathe in enumerate(self.single):
            line.maxt = self._line_reach(t0, ray.maxt, t_rest, won, walk)
            mine = after.lathe == index
            after_s, after_key = dr.select(mine, after.s, 0.0), dr.select(mine, after.key, NO_CROSSING)
            # after another lathe's crossing at t0, a later one's at t0 too
            after_t = after_t_with_ties(t0, (after.lathe != NO_LATHE) & (after.lathe < index))
            if shadow is None:
                si_lathe, s, key = lathe.next_crossing_exact(line, active, after_s, after_key, after_t)
            else:
                si_lathe, s, key, blocked = lathe.walk_and_test_exact(
                    line, active, after_s, after_key, after_t, shadow, shadow_active & ~occluded)
                occluded |= blocked
            place = CrossingPlace(mi.UInt32(index), s, key, mi.Float(si_lathe.t))
            hit, walk, take = _nearer(t_rest, won, walk, si_lathe, place, t0, margin)
            hits.append((take, hit))
            won |= take
        for group in self.groups:
            line.maxt = self._line_reach(t0, ray.maxt, t_rest, won, walk)
            si_group, place = group.ray_walk(line, active, after)
            hit, walk, take = _nearer(t_rest, won, walk, si_group, place, t0, margin)
            hits.append((take, hit))
            won |= take
            if shadow is not None:
                occluded |= group.set.occluded(shadow.o, shadow.d, shadow.maxt, shadow_active & ~occluded)
        # The interactions are chosen once, the later nearer hit winning
        # (one selection of the whole interaction per lathe or set)
        si = self._rest_interaction(ray, pi, active & ~won)
        for take, hit in hits:
            si = dr.select(take, hit, si)
        return _with_wi(si, ray), walk, occluded

    @staticmethod
    def _line_reach(t0: mi.Float, maxt: mi.Float, t_rest: mi.Float, won: mi.Bool, walk: LineWalk) -> mi.Float:
        """How far along the walked line the next lathe is asked: to the
        rest's hit (or the ray's end), and once a lathe has won, a little
        past its crossing (``walk.t``): at equal ``t`` on the line the
        lathe's order decides (:func:`_nearer`)."""
        return dr.select(won, walk.t * (1.0 + 1e-6), t0 + dr.minimum(maxt, t_rest))

    def _rest_preliminary(self, ray: mi.Ray3f, active: mi.Bool, coherent: mi.Bool | bool = False
                          ) -> tuple[mi.PreliminaryIntersection3f, mi.SurfaceInteraction3f]:
        """Mitsuba's nearest hit with the non-lathe shapes: the preliminary
        intersection, and an interaction holding only its ``t`` (inf on a
        miss) for the lathes to compare with; the full interaction is
        computed only where no lathe is nearer (:meth:`_rest_interaction`)."""
        pi = self.rest.ray_intersect_preliminary(ray, coherent=coherent, active=active)
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.t = dr.select(pi.is_valid(), pi.t, dr.inf)
        return pi, si

    def _rest_interaction(self, ray: mi.Ray3f, pi: mi.PreliminaryIntersection3f,
                          active: mi.Bool) -> mi.SurfaceInteraction3f:
        """The full interaction of the rest's hit ``pi`` (lanes ``active``)."""
        if self.direct is None:  # always so without lathes (see direct_interaction)
            return pi.compute_surface_interaction(ray, mi.RayFlags.All, active)
        return rest_interaction(self.direct, ray, pi, active)

    @dr.syntax
    def skip_area_emitters(self, ray: mi.Ray3f, active: mi.Bool) -> mi.Ray3f:
        """``ray`` (a camera ray) moved past the area emitters it meets
        first, for ``hide_emitters`` as Mitsuba's ``path`` does: where its
        first hit is on a shape with an area emitter, it starts again just
        past that hit, until it first meets a shape without one (or
        nothing)."""
        ray = mi.Ray3f(ray)
        si = self.ray_intersect(ray, active)
        skip = active & si.is_valid() & (si.shape.emitter() != None)  # noqa: E711 (Dr.Jit's test)
        while skip:
            ray[skip] = si.spawn_ray(ray.d)
            si = self.ray_intersect(ray, skip)
            skip &= si.is_valid() & (si.shape.emitter() != None)  # noqa: E711
        return ray

    def ray_test(self, ray: mi.Ray3f, active: mi.Bool) -> mi.Bool:
        """Is anything hit along ``ray`` before ``ray.maxt``? (No
        derivatives: the kernels' loops record none.)"""
        self.follow_moves()
        with dr.suspend_grad():
            ray = mi.Ray3f(dr.detach(ray))
            occluded = self.rest.ray_test(ray, active)
            for lathe in self.single:
                occluded |= lathe.ray_test_exact(ray, active & ~occluded)
            for group in self.groups:
                occluded |= group.set.occluded(ray.o, ray.d, ray.maxt, active & ~occluded)
        return occluded


def _exact(shape: mi.Shape) -> bool:
    """Whether ``shape`` is a lathe intersected exactly: every lathe but an
    emitting one. Mitsuba samples an area emitter's points on its mesh, which
    lies inside the exact surface where the profile is convex: an exact lathe
    would shadow its own light. So an emitting lathe is traced as its
    reference mesh, as stock integrators trace it."""
    return isinstance(shape, LatheShape) and shape.emitter() is None


def _with_wi(si: mi.SurfaceInteraction3f, ray: mi.Ray3f) -> mi.SurfaceInteraction3f:
    """``si``, chosen among the lathes' and the other shapes' interactions
    with ``ray``'s direction, with its ``wi`` made once for all of them, as
    each makes it (Mitsuba's ``finalize_surface_interaction``,
    ``lathe_interaction``: the valid lanes' ``-ray.d`` in the shading
    frame, else ``-ray.d``): the kernel computes it once, not per source."""
    si.wi = dr.select(si.is_valid(), si.to_local(-ray.d), -ray.d)
    return si


def _nearer(t_rest: mi.Float, won: mi.Bool, walk: LineWalk, si_lathe: mi.SurfaceInteraction3f,
            place: CrossingPlace, t0: mi.Float, margin: mi.Float
            ) -> tuple[mi.SurfaceInteraction3f, LineWalk, mi.Bool]:
    """Whether a lathe's hit ``si_lathe`` (``t`` along the walked line,
    which the ray meets at ``t0``) is the nearest so far: before the rest's
    hit ``t_rest`` (along the ray) by more than ``margin``, and, where a
    lathe asked before has ``won``, before that lathe's crossing on the
    line (``walk.t``; equal: the one asked before keeps it, eq. 31).
    Returns ``(hit, walk, take)``: the lathe's hit with its ``t`` along the
    ray, the walk that goes on from the nearer, and whether the lathe's hit
    is the nearer."""
    t_ray = dr.maximum(si_lathe.t - t0, 0.0)
    take = si_lathe.is_valid() & (t_ray < t_rest - margin) & (~won | (place.t < walk.t))
    walk = LineWalk(walk.o, walk.d, dr.select(take, place.lathe, walk.lathe),
                    dr.select(take, place.s, walk.s), dr.select(take, place.key, walk.key),
                    dr.select(take, place.t, walk.t))
    # A copy: Mitsuba's field accessors return references, so si_lathe.t
    # must not be assigned (place.t may be that very array).
    hit = mi.SurfaceInteraction3f(si_lathe)
    hit.t = t_ray
    return hit, walk, take


#: Most non-lathe shapes whose surface interactions are computed by
#: :func:`rest_interaction` rather than by Mitsuba's virtual call (which
#: traces every shape alive, lathes included, on each render).
DIRECT_SHAPES = 8


def direct_interaction(shapes: list[mi.Shape], lathe_count: int) -> bool:
    """Whether :func:`rest_interaction` should serve ``shapes`` in a scene
    of ``lathe_count`` lathes: some lathes (without, the scene is traced as
    it is), few other shapes, none an instance (whose hits name the
    instance, not the shape)."""
    return (lathe_count > 0 and len(shapes) <= DIRECT_SHAPES
            and all(s.class_name() != "Instance" for s in shapes))


def rest_interaction(shapes: list[mi.Shape], ray: mi.Ray3f, pi: mi.PreliminaryIntersection3f,
                     active: mi.Bool) -> mi.SurfaceInteraction3f:
    """Mitsuba's ``pi.compute_surface_interaction(ray)`` for a scene made of
    ``shapes``, calling only these shapes' own ``compute_surface_interaction``
    instead of the virtual call over ``mi.ShapePtr``: Dr.Jit records that
    call for every shape registered in the process (a lathe's reference
    mesh, or a thousand lathes' proxies, included) on every render, though
    only these can be hit. One shape is called directly; several through a
    ``dr.switch`` whose targets leave the interaction's ``shape`` null (it
    is ``pi.shape``, set after the call), so that the targets of shapes with
    the same code (two rectangles) are one function of the compiled kernel."""
    active = mi.Bool(active) & pi.is_valid()
    if len(shapes) > 1:
        index = dr.zeros(mi.UInt32, dr.width(pi.t))  # position of the hit shape in shapes
        for k, shape in enumerate(shapes[1:], 1):
            index = dr.select(pi.shape == mi.ShapePtr(shape), k, index)
        si = dr.switch(index, [functools.partial(_shape_interaction, shape) for shape in shapes],
                       ray, pi, active)
        si.shape = pi.shape
    else:
        si = dr.zeros(mi.SurfaceInteraction3f)
        for shape in shapes:
            here = active & (pi.shape == mi.ShapePtr(shape))
            si = dr.select(here, shape.compute_surface_interaction(ray, pi, mi.RayFlags.All, here), si)
    # What SurfaceInteraction::finalize_surface_interaction does after the call.
    si.t = dr.select(active, si.t, dr.inf)
    valid = active & si.is_valid()
    si.shape = dr.select(valid, si.shape, mi.ShapePtr(None))
    si.instance = dr.select(valid, si.instance, mi.ShapePtr(None))
    si.time = ray.time
    si.wavelengths = ray.wavelengths
    si.initialize_sh_frame()
    si.wi = dr.select(valid, si.to_local(-ray.d), -ray.d)
    si.duv_dx = dr.zeros(mi.Point2f)
    si.duv_dy = dr.zeros(mi.Point2f)
    return si


def _shape_interaction(shape: mi.Shape, ray: mi.Ray3f, pi: mi.PreliminaryIntersection3f,
                       active: mi.Bool) -> mi.SurfaceInteraction3f:
    """A target of :func:`rest_interaction`'s switch: ``shape``'s own
    interaction with a null ``shape`` field (no per-shape literal)."""
    si = shape.compute_surface_interaction(ray, pi, mi.RayFlags.All, active)
    si.shape = dr.zeros(mi.ShapePtr, dr.width(si.t))
    return si


def profile_key(lathe: LatheShape) -> tuple:
    """What makes two lathes' kernel data equal: the kind, the shading mode
    and every array and number of the validated profile (not its source
    name). Lathes with equal keys share one profile's data."""
    surface = lathe.surface
    key: list = [surface.kind, surface.smooth]
    for field in dataclasses.fields(surface.profile):
        value = getattr(surface.profile, field.name)
        if isinstance(value, np.ndarray):
            key.append((value.dtype.str, value.shape, value.tobytes()))
        elif not isinstance(value, str):
            key.append(value)
    return tuple(key)


class LatheGroup:
    """The lathes of one kind, intersected as one
    :class:`~lathe_shape.kernels.top_level.LatheSet`: the Mitsuba side (shape
    pointers, ``flip_normals``, following moves)."""

    def __init__(self, lathes: list[LatheShape]) -> None:
        self.lathes = lathes
        self._build()

    def _build(self) -> None:
        """The profile table, transforms and top-level BVH of the lathes."""
        lathes = self.lathes
        profiles: dict[tuple, int] = {}
        first: list[LatheShape] = []  # the first lathe of each distinct profile
        profile_of = []
        for lathe in lathes:
            key = profile_key(lathe)
            if key not in profiles:
                profiles[key] = len(first)
                first.append(lathe)
            profile_of.append(profiles[key])
        table = ProfileTable(kind_of(lathes[0].surface).layout, [lathe.surface.data for lathe in first],
                             [lathe.surface.smooth for lathe in first])
        self._matrices = [lathe.to_world_matrix for lathe in lathes]
        # The surfaces the profile table was built from (a new 'points'
        # value gives a lathe a new surface).
        self._surfaces = [lathe.surface for lathe in lathes]
        #: The lathes' kernels: profiles, transforms, top-level BVH.
        self.set = LatheSet(table, profile_of, np.stack(self._matrices))
        self.shapes = mi.ShapePtr(lathes)
        dr.make_opaque(self.shapes)
        self.flip = opaque(np.array([lathe.flip for lathe in lathes], dtype=np.uint32), mi.UInt32)

    def follow_moves(self) -> None:
        """Rebuild the transforms and the top-level BVH when a lathe moved
        (``set_to_world`` gives it a new matrix object), and everything
        when a lathe's profile changed (its ``points`` parameter)."""
        # map/attrgetter/is_not: this runs at every query of every render,
        # over all the lathes, so it stays out of Python-level loops.
        if any(map(is_not, map(_SURFACE, self.lathes), self._surfaces)):
            self._build()
            return
        matrices = list(map(_MATRIX, self.lathes))
        if any(map(is_not, matrices, self._matrices)):
            self.set.set_transforms(np.stack(matrices))
            self._matrices = matrices

    def ray_intersect(self, ray: mi.Ray3f, tmax: mi.Float, active: mi.Bool) -> mi.SurfaceInteraction3f:
        """Nearest hit with any of the lathes before ``tmax``."""
        return self._interaction(ray, self.set.intersect(ray.o, ray.d, tmax, active))

    def number_from(self, first: int) -> None:
        """Number the lathes ``first, first + 1, ...`` in walks (opaque:
        the lathe count is no constant of the traced kernels)."""
        self.first = opaque(np.array([first], dtype=np.uint32), mi.UInt32)
        self.count = opaque(np.array([len(self.lathes)], dtype=np.uint32), mi.UInt32)

    def ray_walk(self, line: mi.Ray3f, active: mi.Bool,
                 after: CrossingPlace) -> tuple[mi.SurfaceInteraction3f, CrossingPlace]:
        """Nearest crossing with any of the lathes along the walked ``line``
        (before ``line.maxt``) after the place ``after`` (see
        :meth:`ExactSceneGeometry.ray_intersect_walk`; lathes numbered as
        :meth:`number_from` says), and its place."""
        mine = (after.lathe >= self.first) & (after.lathe - self.first < self.count)
        lathe = dr.select(mine, after.lathe - self.first, NO_LATHE)
        local = CrossingPlace(lathe, after.s, after.key, after.t)
        # After a lathe numbered before this set's, every lathe of the set
        # comes later (a crossing at after.t too, eq. 31); after one
        # numbered past it, or none, none does
        ties_from = dr.select((after.lathe != NO_LATHE) & (after.lathe < self.first), mi.UInt32(0),
                              mi.UInt32(NO_LATHE))
        hit, place = self.set.next_crossing(line.o, line.d, line.maxt, active, local, ties_from)
        place.lathe = place.lathe + self.first
        return self._interaction(line, hit), place

    def _interaction(self, ray: mi.Ray3f, hit: SetHit) -> mi.SurfaceInteraction3f:
        """The surface interaction of the set's ``hit`` along ``ray``."""
        geo, prim_index = self.set.geometry(hit, ray.o, ray.d)
        flip = dr.gather(mi.UInt32, self.flip, hit.lathe, hit.valid) != 0
        geo.n = dr.select(flip, -geo.n, geo.n)
        geo.sh_n = dr.select(flip, -geo.sh_n, geo.sh_n)
        shape = dr.gather(mi.ShapePtr, self.shapes, hit.lathe, hit.valid)
        return lathe_interaction(ray, hit, geo, prim_index, shape)
