"""The ``lathe`` shape plugin: a solid of revolution from a 2D profile
(parameters: :class:`LatheShape`).

Nested ``<bsdf>`` and ``<emitter>`` work as for any shape (``lathe_path``
does not handle participating media). An emitting lathe is traced as its
reference mesh by this package's integrators too, since Mitsuba samples
the emitter's points on that mesh; give it a fine ``mesh_segments``.

The plugin is a :class:`mitsuba.Mesh` holding the reference tessellation, so
stock integrators (``path``, ``volpath``, ...) render it as a smooth-shaded
mesh; ``lathe_path`` calls :meth:`LatheShape.ray_intersect_exact` instead.
The mesh carries a face attribute ``face_lathe_band`` (the profile segment
of each triangle for polylines); Mitsuba's scene optimizer never merges a
mesh with attributes, so lathes that share a BSDF stay lathes.
"""

from __future__ import annotations

import contextlib
import difflib
import os
import threading

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.common import LatheGeometry
from ..profiles import ProfileError, parse_profile_string, read_points, read_profile_options
from ..profiles.bspline import evaluate as evaluate_bspline
from ..surfaces import KINDS, BSplineSurface, PolylineSurface, make_surface
from .interaction import lathe_interaction
from .params import (
    check_traceable_scale,
    check_transform,
    describe_lathe,
    transform_property,
    typed_property,
)
from .profile_param import ProfileIndex, profile_index, rebuild_surface, remember_input
from .reference_mesh import check_mesh_budget, reference_bands, reference_steps
from .variants import register_jit_plugin

__all__ = ["FACE_BAND_ATTRIBUTE", "LatheShape", "load_surface", "register", "scene_lathes",
           "warn_open_dielectrics"]

#: Mitsuba's mesh parameters that hold the reference mesh (written only by
#: the lathe itself).
MESH_BUFFERS = ("vertex_positions", "vertex_normals", "vertex_texcoords", "faces")

#: Face attribute of the reference mesh: the profile band (the profile
#: segment for polylines) that each triangle sweeps.
FACE_BAND_ATTRIBUTE = "face_lathe_band"


def _misspelt_hint(props: mi.Properties) -> str:
    """`` (unknown parameter 'profle': did you mean 'profile'?)`` for a
    property whose name is close to ``filename`` or ``profile``."""
    for name in props.keys():
        close = difflib.get_close_matches(name, ["filename", "profile"], n=1, cutoff=0.7)
        if close and name not in ("filename", "profile"):
            return f" (unknown parameter '{name}': did you mean '{close[0]}'?)"
    return ""


def _read_points(props: mi.Properties, who: str) -> tuple[np.ndarray, np.ndarray, list[str], str]:
    """Points from ``filename`` or ``profile`` (exactly one): (points, sharp,
    labels, source)."""
    has_file, has_inline = "filename" in props, "profile" in props
    if has_file == has_inline:
        hint = " (both were given)" if has_file else _misspelt_hint(props)
        raise ProfileError(f"{who}: give exactly one of the parameters 'filename' and 'profile'{hint}")
    if has_file:
        filename = typed_property(props, "filename", str, "", who)
        path = str(mi.file_resolver().resolve(filename))
        if not os.path.exists(path):
            raise ProfileError(f"{who}: parameter 'filename': profile file '{filename}' not found")
        points, sharp, labels = read_points(path)
        return points, sharp, labels, path
    source = f"{who}: parameter 'profile'"
    points, sharp, labels = parse_profile_string(typed_property(props, "profile", str, "", who), source)
    return points, sharp, labels, source


def load_surface(props: mi.Properties) -> PolylineSurface | BSplineSurface:
    """Read the profile parameters (``filename``/``profile``, ``kind``,
    ``crease_angle``, ``smooth``) and build the validated surface.

    Raises :class:`ValueError` naming the file or parameter on bad input.
    """
    who = describe_lathe(props)
    crease = typed_property(props, "crease_angle", float, 30.0, who)
    smooth = typed_property(props, "smooth", bool, True, who)
    if not (0.0 <= crease <= 180.0):
        raise ValueError(f"{who}: parameter 'crease_angle' must be within [0, 180] degrees, got {crease:g}")
    points, sharp, labels, source = _read_points(props, who)
    declared = read_profile_options(source, KINDS) if "filename" in props else {}
    kind = _option(props, "kind", str, declared, "polyline", who, source)
    open_sheet = _option(props, "open", bool, declared, False, who, source)
    if kind not in KINDS:
        raise ValueError(
            f"{who}: parameter 'kind': unknown profile kind '{kind}' "
            f"(expected one of: {', '.join(KINDS)})"
        )
    surface = make_surface(kind, points, sharp, labels, source, crease, smooth, open_sheet)
    # Kept for the differentiable 'points' parameter (profile_param.py).
    return remember_input(surface, points, sharp, labels, source, crease, smooth, open_sheet)


def _option(props: mi.Properties, name: str, kind: type, declared: dict, default, who: str,
            source: str):
    """A parameter that a profile CSV may also declare (``# name: value``):
    the parameter, else the file's value, else ``default``; both given must
    agree."""
    if name not in declared:
        return typed_property(props, name, kind, default, who)
    value = declared[name]
    if name in props and typed_property(props, name, kind, default, who) != value:
        raise ValueError(f"{who}: parameter '{name}' is {props[name]!r} but the profile file "
                         f"{source} declares '{name}: {value}'")
    return value


def _ring_bound(surface: PolylineSurface | BSplineSurface, reference: str = "mesh") -> int:
    """Profile rings of the reference mesh, at most (polylines: two per
    segment where every vertex is a crease; B-splines: their samples; a
    proxy: two per band it keeps)."""
    rings = surface.mesh_rings()
    bands = reference_bands(reference)
    return rings if bands is None else min(rings, 2 * bands)


#: Per thread: the depth of nested lathe constructors and the lathes whose
#: mesh the outermost one still has to write (see :func:`_constructing`).
_CONSTRUCTION = threading.local()


@contextlib.contextmanager
def _constructing():
    """Count a lathe constructor on this thread; yields whether it is the
    outermost.

    Mitsuba's parallel loader (the default of ``mi.load_file`` and
    ``mi.load_dict``) runs plugin constructors as tasks of Dr.Jit's thread
    pool, and a thread that waits for the pool (as writing a mesh does:
    ``params.update()`` evaluates, and Mitsuba's ``Mesh.parameters_changed``
    reads the vertices back) runs other pending tasks meanwhile: another
    lathe's constructor, nested on the same stack, which waits in turn.
    With thousands of lathes the nesting reached Python's recursion limit
    (issue 24, item 5). So a nested constructor only queues its lathe, and
    the outermost one writes the queued meshes, in a loop, before it
    returns: constructors nest at most two deep. Every lathe's mesh is
    written before the loader's scene (which waits for every shape) is
    built."""
    depth = getattr(_CONSTRUCTION, "depth", 0)
    if depth == 0:
        _CONSTRUCTION.pending = []
    _CONSTRUCTION.depth = depth + 1
    try:
        yield depth == 0
    finally:
        _CONSTRUCTION.depth = depth
        if depth == 0:
            _CONSTRUCTION.pending = []


def _finish_pending() -> None:
    """Write the meshes of the lathes queued on this thread (those queued
    meanwhile too)."""
    pending = _CONSTRUCTION.pending
    while pending:
        pending.pop(0)._finish_mesh()


class LatheShape(mi.Mesh):
    """A solid of revolution: reference mesh for stock integrators, exact
    intersection through :meth:`ray_intersect_exact`.

    .. pluginparameters::

     * - filename
       - |string|
       - Profile CSV file (columns ``r,z[,sharp]``, ``#`` comments, optional
         header) or a ``.json``/``.toml`` arc profile spec (see
         :mod:`lathe_shape.profiles.arcs`), resolved like Mitsuba's own file
         names (relative to the scene file). Exactly one of ``filename`` and
         ``profile``.

     * - profile
       - |string|
       - Inline profile ``"r z, r z, ..."`` (a third number per point, 0 or 1,
         flags a sharp vertex).

     * - kind
       - |string|
       - Profile kind: ``polyline`` (the points are the polyline),
         ``bspline`` (the points are uniform cubic B-spline control points:
         closed periodic when the last equals the first, otherwise open with
         tripled ends, which must then lie on the axis), or one of POV-Ray's
         curves: ``bezier`` (4 points per segment), ``catmull_rom`` (POV-Ray's
         ``cubic_spline``: the first and last points only set tangents),
         ``quadratic`` (``quadratic_spline``) and ``sor`` (points ``(r, h)``,
         ``r^2`` a cubic in ``h``, closed by flat discs unless ``open``). A
         profile CSV may name its kind in a ``# kind: NAME`` comment line
         (as ``lathe-profile --from-pov`` writes); the parameter, when given,
         must agree. The kinds are those of the registry
         :data:`lathe_shape.surfaces.KINDS` (:func:`~lathe_shape.surfaces.register_kind`
         adds one). (Default: ``polyline``)

     * - open
       - |bool|
       - The profile is a single open sheet, not the outline of a solid
         (or the CSV says ``# open: true``): its ends need not
         meet or lie on the axis, and it has no inside. A ``sor`` drops its
         end discs. Use BSDFs that need no inside and work on both sides
         (``thindielectric``, or any BSDF inside a ``twosided``); a
         ``dielectric`` or a one-sided BSDF (``diffuse``, ``conductor`` ...)
         logs a warning. (Default: false)

     * - crease_angle
       - |float|
       - Corners of the profile turning by more than this many degrees keep a
         sharp edge instead of smoothly interpolated normals. (Default: 30)

     * - smooth
       - |bool|
       - Polylines: interpolate shading normals along the profile (the paper's
         smooth shading); false renders flat cone frustums. B-splines always
         use their exact normals. (Default: true)

     * - mesh_segments
       - |int|
       - Azimuthal steps of the reference tessellation that stock integrators
         render, at least 3. A mesh that would take more than half the
         available memory is refused, with the estimate. (Default: 256)

     * - reference
       - |string|
       - ``mesh``: the full reference mesh; ``proxy``: a light, coarse
         stand-in (12 steps) for scenes of many lathes rendered exactly with
         ``lathe_path``, which never traces the mesh (stock integrators then
         render the proxy; keep ``mesh`` for emitting lathes). (Default:
         ``mesh``)

     * - to_world
       - |transform|
       - Places the shape's local frame (axis = local +z) in the world.

     * - flip_normals
       - |bool|
       - Flip the surface orientation, as for any Mitsuba shape.
    """

    def __init__(self, props: mi.Properties) -> None:
        with _constructing() as outermost:
            self._construct(props, outermost)

    def _construct(self, props: mi.Properties, outermost: bool) -> None:
        who = describe_lathe(props)
        steps = typed_property(props, "mesh_segments", int, 256, who)
        if steps < 3:
            raise ValueError(f"{who}: parameter 'mesh_segments' must be at least 3, got {steps}")
        #: ``mesh`` (the full reference mesh) or ``proxy`` (a coarse stand-in).
        self.reference = typed_property(props, "reference", str, "mesh", who)
        steps = reference_steps(self.reference, steps, who)
        #: Azimuthal steps of the reference mesh (after ``reference``).
        self.mesh_segments = steps
        #: The profile kind's surface: tessellation and exact kernels.
        self.surface = load_surface(props)
        self.profile = self.surface.profile
        self.smooth = self.surface.smooth
        self.flip = typed_property(props, "flip_normals", bool, False, who)
        #: (4, 4) float64 local-to-world matrix.
        self.to_world_matrix = transform_property(props, "to_world", who)
        check_mesh_budget(_ring_bound(self.surface, self.reference), steps, who)
        #: The reference tessellation in the local frame.
        self.local_mesh = self.surface.tessellate(steps, reference_bands(self.reference))
        check_traceable_scale(self.to_world_matrix, self._local_size(), f"{who}: parameter 'to_world'")

        super().__init__(props.id() or "lathe", len(self.local_mesh.positions),
                         len(self.local_mesh.faces), props, has_vertex_normals=True,
                         has_vertex_texcoords=True)
        # Written by the outermost lathe constructor of this thread (see
        # _constructing): a nested one returns at once
        _CONSTRUCTION.pending.append(self)
        if outermost:
            _finish_pending()
        self._set_transform(self.to_world_matrix)
        self._warn_open_dielectric(who)
        self._warn_emitting_proxy(who)

    def _finish_mesh(self) -> None:
        """Write the reference mesh and its face attribute."""
        self._write_mesh(self._mesh_buffers(self.to_world_matrix))
        # A mesh attribute makes Mitsuba's scene optimizer (the default
        # optimize=True of mi.load_file, and mi.load_dict with a shared BSDF)
        # leave this mesh alone: it merges only meshes without attributes, and
        # a merged lathe would lose its exact surface without a word.
        self.add_attribute(FACE_BAND_ATTRIBUTE, 1, mi.Float(self.local_mesh.face_band.astype(np.float32)))

    def _local_size(self) -> float:
        """The reference mesh's largest extent in the local frame."""
        positions = self.local_mesh.positions
        return float(np.ptp(positions, axis=0).max())

    def _warn_emitting_proxy(self, who: str) -> None:
        """Mitsuba samples an area emitter's points on the reference mesh and
        every integrator sees the lamp there: with ``reference="proxy"`` that
        is the coarse proxy, so the light is dimmer (the polygon's area) and
        the visible lamp faceted (issue 24, item 9)."""
        if self.reference == "proxy" and self.emitter() is not None:
            mi.Log(mi.LogLevel.Warn,
                   f"{who}: an emitter on a lathe with parameter 'reference' = 'proxy': Mitsuba "
                   f"samples and shows the emitter on the {self.mesh_segments}-sided proxy mesh, so "
                   f"its light comes out dimmer (the polygons' smaller area) and "
                   f"the lamp looks faceted; use reference 'mesh' with a fine mesh_segments for "
                   f"an emitting lathe")

    def _warn_open_dielectric(self, who: str) -> None:
        """An open sheet has no inside: a dielectric (which refracts into
        an inside) renders it as the boundary of nothing in particular,
        unless other open sheets close it (the interfaces of a liquid in a
        glass, each one sheet with both indices, meeting at the fill line):
        that warning waits for the scene (:func:`warn_open_dielectrics`),
        where it is given only if a free end of the sheet meets no other
        sheet's."""
        open_sheet = getattr(self.profile, "open_sheet", False)
        bsdf = self.bsdf() if open_sheet else None
        name = str(bsdf).split("[", 1)[0] if bsdf is not None else ""
        #: The open-dielectric warning waiting for the scene (None: none).
        self.open_dielectric_warning = None
        messages = []
        if name in ("SmoothDielectric", "RoughDielectric"):
            messages.append(f"{who}: a {name} BSDF on an open profile (a single sheet, no inside) whose "
                            f"ends meet no other open lathe's: rays refract into a solid that is not "
                            f"there; use 'thindielectric' for a thin glass sheet, or close the profile")
        media = [side for side, medium in (("interior", self.interior_medium()),
                                           ("exterior", self.exterior_medium())) if medium is not None]
        if open_sheet and media:
            messages.append(f"{who}: an {' and an '.join(media)} medium on an open profile (a single "
                            f"sheet, no inside) whose ends meet no other open lathe's: rays that pass "
                            f"its free ends miss the medium; close the profile, or close the sheet with "
                            f"other open lathes (a liquid's surface)")
        if messages:
            message = "; ".join(messages)
            if self.free_end_rings() is None:
                mi.Log(mi.LogLevel.Warn, message)
            else:
                self.open_dielectric_warning = message
        if bsdf is not None and name not in ("SmoothDielectric", "RoughDielectric") \
                and not mi.has_flag(bsdf.flags(), mi.BSDFFlags.BackSide):
            mi.Log(mi.LogLevel.Warn,
                   f"{who}: a one-sided {name} BSDF on an open profile (a single sheet): its "
                   f"inner side renders black; wrap the BSDF in a 'twosided' one")

    def free_end_rings(self) -> list[np.ndarray] | None:
        """The circles that an open sheet's ends sweep, away from the axis:
        each as three world points (its centre and its points at 0 and 90
        degrees), ``(3, 3)``; None for kinds whose ends are not read here
        (``sor``)."""
        profile = self.profile
        if hasattr(profile, "segment_controls"):  # B-spline segments: the curve's ends (eq. 12)
            controls = np.asarray(profile.segment_controls, dtype=np.float64)
            ends = np.stack(evaluate_bspline(controls, [0, len(controls) - 1], [0.0, 1.0]), axis=-1)
        elif hasattr(profile, "segments"):  # a polyline
            ends = [profile.points[profile.segments[0, 0]], profile.points[profile.segments[-1, 1]]]
        else:
            return None
        size = max(float(np.abs(np.asarray(profile.points, dtype=np.float64)).max()), 1e-30)
        rings = []
        for r, z in ends:
            if r > 1e-9 * size:
                local = np.array([[0.0, 0.0, z, 1.0], [r, 0.0, z, 1.0], [0.0, r, z, 1.0]])
                rings.append((local @ self.to_world_matrix.T)[:, :3])
        return rings

    def _set_transform(self, matrix: np.ndarray) -> None:
        self.to_world_matrix = np.array(matrix, dtype=np.float64)
        # Inverses in float64: float32's (from the 4x4 determinant, the cube
        # of the scale) overflow beyond scales of about 1e+-12, and the exact
        # surface then vanished (issue 24, item 10). The normals' matrix (the
        # inverse transpose) is divided by its largest entry: normals are
        # normalized after it, and unscaled they under- or overflow there.
        to_local = np.linalg.inv(self.to_world_matrix)
        normals = to_local.T / np.abs(to_local[:3, :3]).max()
        self._to_world = mi.Transform4f(mi.Matrix4f(self.to_world_matrix.astype(np.float32)),
                                        mi.Matrix4f(normals.astype(np.float32)))
        self._to_local = mi.Transform4f(mi.Matrix4f(to_local.astype(np.float32)),
                                        mi.Matrix4f(self.to_world_matrix.T.astype(np.float32)))
        # Opaque: a new transform is a new kernel input, not a recompile.
        dr.make_opaque(self._to_world, self._to_local)

    def _mesh_buffers(self, matrix: np.ndarray) -> dict[str, np.ndarray]:
        """World-space mesh buffers of the reference tessellation."""
        mesh = self.local_mesh
        linear, offset = matrix[:3, :3], matrix[:3, 3]
        positions = mesh.positions @ linear.T + offset
        normals = mesh.normals @ np.linalg.inv(linear)  # inverse transpose
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        faces = mesh.faces
        if np.linalg.det(linear) < 0.0:
            # A mirroring transform flips the winding; keep faces outward.
            faces = faces[:, ::-1]
        return {
            "vertex_positions": positions.astype(np.float32),
            "vertex_normals": normals.astype(np.float32),
            "vertex_texcoords": mesh.texcoords.astype(np.float32),
            "faces": np.ascontiguousarray(faces, dtype=np.uint32),
        }

    def set_to_world(self, matrix: np.ndarray | mi.ScalarTransform4f, scene: mi.Scene | None = None,
                     *, exact_only: bool = False) -> None:
        """Move the lathe: new local-to-world transform (4x4 matrix or
        ``mi.ScalarTransform4f``).

        Updates the exact intersection and the reference mesh, through
        ``mi.traverse(scene)`` of ``scene``, the scene holding the lathe, so
        that Mitsuba rebuilds its acceleration structure: stock integrators
        trace the mesh, and every integrator traces an emitting lathe's.
        ``exact_only=True`` (with ``scene`` None) moves only what the
        package's integrators trace (a turntable's fast path): stock
        integrators then see the mesh where it was."""
        if isinstance(matrix, (mi.ScalarTransform4f, mi.ScalarTransform4d)):
            matrix = np.array(matrix.matrix, dtype=np.float64)
        matrix = np.asarray(matrix, dtype=np.float64)
        who = (f"lathe '{self.id()}'" if self.id() else "lathe") + ": set_to_world"
        if matrix.shape != (4, 4):
            raise ValueError(f"{who} needs a 4x4 matrix, got shape {matrix.shape}")
        check_transform(matrix, who)
        check_traceable_scale(matrix, self._local_size(), who)
        if np.linalg.det(matrix[:3, :3]) * np.linalg.det(self.to_world_matrix[:3, :3]) < 0.0:
            # The mesh's face winding was fixed for the original handedness.
            raise ValueError(f"{who}: the new transform mirrors the shape relative to the old one")
        if scene is None and not exact_only:
            raise ValueError(
                f"{who}: pass the scene that holds the lathe, set_to_world(matrix, scene): without it "
                "Mitsuba's acceleration structure keeps the mesh where it was, and stock integrators "
                "render a stale shape (exact_only=True moves only what lathe_path and the package's "
                "other integrators trace)")
        if scene is None and self.emitter() is not None:
            raise ValueError(
                f"{who}: the lathe emits light, and every integrator traces an emitting lathe as its "
                "mesh: pass the scene that holds it, set_to_world(matrix, scene)")
        buffers = self._mesh_buffers(matrix)
        params = mi.traverse(self if scene is None else scene)
        for name in ("vertex_positions", "vertex_normals"):
            # This lathe's own parameter (keys of unnamed shapes are generated).
            keys = [k for k in params.keys() if k.split(".")[-1] == name and params.properties[k][2] is self]
            if not keys:
                raise ValueError(f"lathe '{self.id()}' is not part of the given scene")
            params[keys[0]] = type(params[keys[0]])(buffers[name].ravel())
        with own_mesh_updates([self]):
            params.update()
        self._set_transform(matrix)

    # -- the profile as a differentiable parameter ---------------------------

    def traverse(self, cb: mi.TraversalCallback) -> None:
        """Mitsuba's mesh parameters, plus ``points``: the profile's points
        as flat ``(r, z)`` pairs in the order the user gave them
        (differentiable; see :mod:`lathe_shape.plugin.profile_param`)."""
        super().traverse(cb)
        if not hasattr(self, "profile_points"):
            # First traversal (from __init__): the loaded points.
            self.profile_points = mi.Float(self.surface.given.points.ravel().astype(np.float32))
            self._accepted_points = mi.Float(self.profile_points)
        cb.put("points", self.profile_points, mi.ParamFlags.Differentiable | mi.ParamFlags.Discontinuous)

    def parameters_changed(self, keys: list[str]) -> None:
        """A new ``points`` value re-validates the profile and rebuilds the
        kernel data and the reference mesh; an invalid one raises the loading
        error and leaves the previous profile in place, and the parameter
        holds again the variable accepted last (the same Dr.Jit variable,
        attached to AD as it was), so that an optimisation that catches the
        error can go on."""
        edited = [key for key in keys if key in MESH_BUFFERS]
        if edited and not getattr(self, "_writing_mesh", False):
            # Edited from outside (mi.traverse): put the mesh back, refuse.
            self._write_mesh(self._mesh_buffers(self.to_world_matrix))
            who = f"lathe '{self.id()}'" if self.id() else "lathe"
            raise ValueError(
                f"{who}: parameter '{edited[0]}' is the lathe's reference mesh, made from its "
                "profile and transform, and cannot be edited: move the lathe with "
                "LatheShape.set_to_world(matrix, scene), or change its profile through its "
                "'points' parameter"
            )
        if "points" in keys:
            self._update_profile()
        rest = [key for key in keys if key != "points"]
        if rest or not keys:
            super().parameters_changed(rest)

    def _update_profile(self) -> None:
        who = (f"lathe '{self.id()}'" if self.id() else "lathe") + ": parameter 'points'"
        given = self.surface.given
        try:
            surface = rebuild_surface(given, self.profile_points.numpy(), who)
            check_mesh_budget(_ring_bound(surface, self.reference), self.mesh_segments, who)
        except ValueError:
            # Keep the previous profile: its value goes back into the parameter,
            # the very variable accepted last (its AD variable included: a
            # fresh, detached copy left the next render unattached, and an
            # optimiser that caught the error could not go on).
            mi.set_property(self.profile_points, self._accepted_points)
            raise
        # The same JIT and AD variables as the parameter, for a later refusal.
        self._accepted_points = mi.Float(self.profile_points)
        self.surface = surface
        self.profile = surface.profile
        self._index = None
        self.local_mesh = surface.tessellate(self.mesh_segments, reference_bands(self.reference))
        self._write_mesh({**self._mesh_buffers(self.to_world_matrix),
                          FACE_BAND_ATTRIBUTE: self.local_mesh.face_band.astype(np.float32)})

    def _write_mesh(self, buffers: dict[str, np.ndarray]) -> None:
        """Write the reference mesh's buffers (the only writer allowed: see
        :meth:`parameters_changed`)."""
        params = mi.traverse(self)
        for key, value in buffers.items():
            # The buffer types differ between JIT and scalar variants.
            params[key] = type(params[key])(value.ravel())
        with own_mesh_updates([self]):
            params.update()

    @property
    def profile_index(self) -> ProfileIndex:
        """Index maps from the kernels' segments to ``points`` (built on
        first use after each profile change)."""
        if getattr(self, "_index", None) is None:
            self._index = profile_index(self.surface)
        return self._index

    # -- exact intersection -------------------------------------------------

    def ray_intersect_exact(self, ray: mi.Ray3f, active: mi.Bool = True) -> mi.SurfaceInteraction3f:
        """Intersect a world-space ray with the exact lathe.

        Returns a full :class:`mitsuba.SurfaceInteraction3f`: ``t`` (inf on a
        miss), ``p``, geometric ``n``, ``sh_frame`` from the interpolated
        normal (the geometric one when ``smooth`` is false or the profile is
        a B-spline), ``uv`` (azimuth / 2 pi, position along the profile:
        arclength fraction for polylines, (segment + t) / segments for
        B-splines; the reference mesh carries the same texture coordinates),
        ``dp_du``, ``dp_dv``, ``prim_index`` (profile segment), ``shape``
        (this lathe) and ``wi``.
        """
        active = mi.Bool(active)
        # The local ray keeps the world ray's parameterisation: t is shared.
        o = self._to_local @ ray.o
        d = self._to_local @ ray.d
        hit = self.surface.intersect(o, d, mi.Float(ray.maxt), active)
        return self._interaction(ray, o, d, hit)

    def next_crossing_exact(self, line: mi.Ray3f, active: mi.Bool, after_s: mi.Float,
                            after_key: mi.UInt32, after_t: mi.Float
                            ) -> tuple[mi.SurfaceInteraction3f, mi.Float, mi.UInt32]:
        """Walk the world-space ``line`` through its crossings with the exact
        lathe, without offsets: the crossing
        after the one at ``(after_s, after_key)`` that a previous call with
        the same ``line.o``, ``line.d`` returned, or where ``after_key`` is
        ``NO_CROSSING`` the first one with ``t > after_t``, before
        ``line.maxt``. Returns the surface interaction (as
        :meth:`ray_intersect_exact`, ``t`` along ``line``) and the
        crossing's place ``(s, key)``."""
        active = mi.Bool(active)
        o = self._to_local @ line.o
        d = self._to_local @ line.d
        hit, s, key = self.surface.next_crossing(o, d, mi.Float(line.maxt), active, after_s, after_key,
                                                 after_t)
        return self._interaction(line, o, d, hit), s, key

    def walk_and_test_exact(self, line: mi.Ray3f, active: mi.Bool, after_s: mi.Float, after_key: mi.UInt32,
                            after_t: mi.Float, shadow: mi.Ray3f, shadow_active: mi.Bool
                            ) -> tuple[mi.SurfaceInteraction3f, mi.Float, mi.UInt32, mi.Bool]:
        """:meth:`next_crossing_exact` of ``line`` and :meth:`ray_test_exact`
        of the world-space ``shadow`` ray together: ``(si, s, key,
        occluded)``. A polyline lathe answers both with one traversal."""
        active = mi.Bool(active)
        o = self._to_local @ line.o
        d = self._to_local @ line.d
        shadow_o = self._to_local @ shadow.o
        shadow_d = self._to_local @ shadow.d
        hit, s, key, occluded = self.surface.walk_and_test(
            o, d, mi.Float(line.maxt), active, after_s, after_key, after_t,
            shadow_o, shadow_d, mi.Float(shadow.maxt), mi.Bool(shadow_active))
        return self._interaction(line, o, d, hit), s, key, occluded

    def ray_test_exact(self, ray: mi.Ray3f, active: mi.Bool = True) -> mi.Bool:
        """Shadow-ray test: does the world-space ray hit the lathe before
        ``ray.maxt``?"""
        o = self._to_local @ ray.o
        d = self._to_local @ ray.d
        return self.surface.occluded(o, d, mi.Float(ray.maxt), mi.Bool(active))

    def _interaction(self, ray: mi.Ray3f, o: mi.Point3f, d: mi.Vector3f, hit) -> mi.SurfaceInteraction3f:
        valid = hit.valid
        t = dr.select(valid, hit.t, 0.0)
        # Misses are evaluated at the local origin, so that their fields stay
        # finite even for rays with non-finite origins.
        geo = self.surface.geometry(dr.select(valid, o + t * d, 0.0), hit.seg, hit.u)
        n = dr.normalize(self._to_world @ mi.Normal3f(geo.n))
        sh_n = dr.normalize(self._to_world @ mi.Normal3f(geo.sh_n))
        if self.flip:
            n, sh_n = -n, -sh_n
        world = LatheGeometry(n=n, sh_n=sh_n, uv=geo.uv, dp_du=self._to_world @ geo.dp_du,
                              dp_dv=self._to_world @ geo.dp_dv)
        shape = dr.select(valid, mi.ShapePtr(self), dr.zeros(mi.ShapePtr))
        return lathe_interaction(ray, hit, world, hit.seg, shape)

    def to_string(self) -> str:
        r_max, z_min, z_max = self.profile.bounds()
        return (
            f"LatheShape[id='{self.id()}', kind='{self.surface.kind}', source='{self.profile.source}', "
            f"segments={self.profile.segment_count}, r_max={r_max:g}, "
            f"z=[{z_min:g}, {z_max:g}], smooth={self.smooth}]"
        )


@contextlib.contextmanager
def own_mesh_updates(shapes: list[mi.Shape]):
    """Within this context the lathes among ``shapes`` accept updates of
    their reference mesh (an acceleration structure rebuilt around them
    marks their buffers dirty; see :meth:`LatheShape.parameters_changed`)."""
    lathes = [shape for shape in shapes if isinstance(shape, LatheShape)]
    for lathe in lathes:
        lathe._writing_mesh = True
    try:
        yield
    finally:
        for lathe in lathes:
            lathe._writing_mesh = False


def mesh_state(shape: mi.Shape) -> tuple:
    """What a rebuild of the acceleration structure around ``shape`` must
    follow: its bounds, and for a lathe also its transform and profile
    (a moved or reshaped lathe may keep its bounds)."""
    box = shape.bbox()
    state = (tuple(box.min), tuple(box.max))
    if isinstance(shape, LatheShape):
        state += (shape.to_world_matrix.tobytes(), id(shape.surface))
    return state


def warn_open_dielectrics(scene: mi.Scene) -> list[str]:
    """Give the open-dielectric warnings of ``scene``'s lathes (see
    :meth:`LatheShape._warn_open_dielectric`) whose sheets have a free end
    that meets no other open lathe's free end (within 1e-5 of the larger
    lathe's size); each lathe warns once. Returns the messages given."""
    lathes = [lathe for lathe in scene_lathes(scene) if getattr(lathe.profile, "open_sheet", False)]
    rings = {id(lathe): lathe.free_end_rings() or [] for lathe in lathes}
    reach = {id(lathe): float(np.linalg.norm(lathe.bbox().extents())) for lathe in lathes}
    given = []
    for lathe in lathes:
        if lathe.open_dielectric_warning is None:
            continue
        others = [(other, ring) for other in lathes if other is not lathe for ring in rings[id(other)]]
        closed = all(any(np.abs(ring - end).max() <= 1e-5 * max(reach[id(lathe)], reach[id(other)])
                         for other, ring in others) for end in rings[id(lathe)])
        if not closed:
            mi.Log(mi.LogLevel.Warn, lathe.open_dielectric_warning)
            given.append(lathe.open_dielectric_warning)
        lathe.open_dielectric_warning = None
    return given


def scene_lathes(scene: mi.Scene) -> list[LatheShape]:
    """The lathes among ``scene.shapes()`` (in that order): the one way the
    package finds them."""
    return [shape for shape in scene.shapes() if isinstance(shape, LatheShape)]


def register() -> None:
    """Register ``<shape type="lathe">`` for the active variant."""
    register_jit_plugin(mi.register_shape, "lathe", LatheShape, describe_lathe)
