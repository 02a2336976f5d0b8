"""The ``lathe`` shape plugin: a solid of revolution from a 2D profile.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Description
   * - ``filename``
     - string
     - Profile CSV file (columns ``r,z[,sharp]``, ``#`` comments, optional
       header), resolved like Mitsuba's own file names (relative to the
       scene file). Exactly one of ``filename`` and ``profile``.
   * - ``profile``
     - string
     - Inline profile ``"r z, r z, ..."`` (a third number per point, 0 or 1,
       flags a sharp vertex).
   * - ``kind``
     - string
     - Profile kind: ``polyline`` (default).
   * - ``crease_angle``
     - float
     - Corners of the profile turning by more than this many degrees keep a
       sharp edge instead of smoothly interpolated normals (default: 30).
   * - ``smooth``
     - boolean
     - Interpolate shading normals along the profile (the paper's smooth
       shading, default: true); false renders flat cone frustums.
   * - ``mesh_segments``
     - integer
     - Azimuthal steps of the reference tessellation that stock integrators
       render (default: 256, at least 3).
   * - ``to_world``
     - transform
     - Places the shape's local frame (axis = local +z) in the world.
   * - ``flip_normals``
     - boolean
     - Flip the surface orientation, as for any Mitsuba shape.

Nested ``<bsdf>``, ``<emitter>`` and media work as for any shape.

The plugin is a :class:`mitsuba.Mesh` holding the reference tessellation, so
stock integrators (``path``, ``volpath``, ...) render it as a smooth-shaded
mesh; ``lathe_path`` calls :meth:`LatheShape.ray_intersect_exact` instead.
"""

from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np

from .profile import Profile, ProfileError, make_profile, parse_profile_string, read_profile_csv
from .tessellate import TriangleMesh, tessellate_profile

__all__ = ["LatheShape", "load_profile_from_properties", "register"]

#: Profile kinds the ``kind`` parameter accepts.
PROFILE_KINDS = ("polyline",)


def _describe(props: mi.Properties) -> str:
    name = props.id()
    return f"lathe '{name}'" if name else "lathe"


def load_profile_from_properties(props: mi.Properties) -> Profile:
    """Read ``filename``/``profile``/``crease_angle`` and build the profile.

    Raises :class:`ProfileError` naming the file or parameter on bad input.
    """
    who = _describe(props)
    has_file, has_inline = "filename" in props, "profile" in props
    filename = props.get("filename", "") if has_file else ""
    inline = props.get("profile", "") if has_inline else ""
    crease = float(props.get("crease_angle", 30.0))
    if has_file == has_inline:
        raise ProfileError(
            f"{who}: give exactly one of the parameters 'filename' and 'profile'"
            + (" (both were given)" if has_file else "")
        )
    if has_file:
        path = str(mi.file_resolver().resolve(filename))
        if not os.path.exists(path):
            raise ProfileError(f"{who}: parameter 'filename': profile file '{filename}' not found")
        points, sharp, labels = read_profile_csv(path)
        source = path
    else:
        source = f"{who}: parameter 'profile'"
        points, sharp, labels = parse_profile_string(inline, source)
    return make_profile(points, sharp, labels, source=source, crease_angle=crease)


class LatheShape(mi.Mesh):
    """A solid of revolution: reference mesh for stock integrators, exact
    intersection through :meth:`ray_intersect_exact` (see module docstring)."""

    def __init__(self, props: mi.Properties) -> None:
        who = _describe(props)
        kind = props.get("kind", "polyline")
        if kind not in PROFILE_KINDS:
            raise ValueError(
                f"{who}: parameter 'kind': unknown profile kind '{kind}' "
                f"(expected one of: {', '.join(PROFILE_KINDS)})"
            )
        steps = int(props.get("mesh_segments", 256))
        if steps < 3:
            raise ValueError(f"{who}: parameter 'mesh_segments' must be at least 3, got {steps}")
        self.smooth = bool(props.get("smooth", True))
        self.profile = load_profile_from_properties(props)
        self.flip = bool(props.get("flip_normals", False))
        to_world = props.get("to_world", mi.ScalarTransform4f())
        #: (4, 4) float64 local-to-world matrix.
        self.to_world_matrix = np.array(to_world.matrix, dtype=np.float64)
        mesh = tessellate_profile(self.profile, steps, smooth=self.smooth)

        super().__init__(props.id() or "lathe", len(mesh.positions), len(mesh.faces), props,
                         has_vertex_normals=True)
        self._set_mesh(mesh, self.to_world_matrix)
        self._to_world = mi.Transform4f(self.to_world_matrix.astype(np.float32))
        self._to_local = self._to_world.inverse()
        dr.make_opaque(self._to_world, self._to_local)
        self._kernel_data = None

    def _set_mesh(self, mesh: TriangleMesh, matrix: np.ndarray) -> None:
        linear, offset = matrix[:3, :3], matrix[:3, 3]
        positions = mesh.positions @ linear.T + offset
        normals = mesh.normals @ np.linalg.inv(linear)  # inverse transpose
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        faces = mesh.faces
        if np.linalg.det(linear) < 0.0:
            # A mirroring transform flips the winding; keep faces outward.
            faces = faces[:, ::-1]
        params = mi.traverse(self)
        buffers = {
            "vertex_positions": positions.astype(np.float32),
            "vertex_normals": normals.astype(np.float32),
            "faces": np.ascontiguousarray(faces, dtype=np.uint32),
        }
        for key, value in buffers.items():
            # The buffer types differ between JIT and scalar variants.
            params[key] = type(params[key])(value.ravel())
        params.update()

    # -- exact intersection -------------------------------------------------

    @property
    def kernel_data(self):
        """Packed, opaque segment buffers for the intersection kernel (built
        on first use)."""
        if self._kernel_data is None:
            from .kernels.polyline import build_polyline_data

            p0, p1 = self.profile.segment_points()
            n0, n1 = self.profile.normal_start, self.profile.normal_end
            if not self.smooth:
                n0 = n1 = self.profile.segment_normals()
            self._kernel_data = build_polyline_data(
                p0[:, 0], p0[:, 1], p1[:, 0], p1[:, 1],
                n0[:, 0], n0[:, 1], n1[:, 0], n1[:, 1],
            )
        return self._kernel_data

    def ray_intersect_exact(self, ray: mi.Ray3f, active: mi.Bool = True) -> mi.SurfaceInteraction3f:
        """Intersect a world-space ray with the exact lathe.

        Returns a full :class:`mitsuba.SurfaceInteraction3f`: ``t`` (inf on a
        miss), ``p``, geometric ``n``, ``sh_frame`` from the interpolated
        normal (the geometric one when ``smooth`` is false), ``uv`` (azimuth
        / 2 pi, profile arclength fraction), ``dp_du``, ``dp_dv``,
        ``prim_index`` (profile segment), ``shape`` (this lathe) and ``wi``.
        """
        from .kernels.polyline import intersect_polyline

        active = mi.Bool(active)
        o = self._to_local @ ray.o
        d = self._to_local @ ray.d
        hit = intersect_polyline(self.kernel_data, o, d, mi.Float(ray.maxt), active)
        return self._interaction(ray, o, d, hit)

    def ray_test_exact(self, ray: mi.Ray3f, active: mi.Bool = True) -> mi.Bool:
        """Shadow-ray test: does the world-space ray hit the lathe before
        ``ray.maxt``?"""
        from .kernels.polyline import occluded_polyline

        o = self._to_local @ ray.o
        d = self._to_local @ ray.d
        return occluded_polyline(self.kernel_data, o, d, mi.Float(ray.maxt), mi.Bool(active))

    def _interaction(self, ray: mi.Ray3f, o: mi.Point3f, d: mi.Vector3f, hit) -> mi.SurfaceInteraction3f:
        from .kernels.polyline import polyline_geometry

        valid = hit.valid
        t = dr.select(valid, hit.t, 0.0)
        geo = polyline_geometry(self.kernel_data, o + t * d, hit.seg, hit.u, self.smooth)
        n = dr.normalize(self._to_world @ mi.Normal3f(geo.n))
        sh_n = dr.normalize(self._to_world @ mi.Normal3f(geo.sh_n))
        if self.flip:
            n, sh_n = -n, -sh_n

        si = dr.zeros(mi.SurfaceInteraction3f)
        si.t = dr.select(valid, hit.t, dr.inf)
        si.time = ray.time
        si.wavelengths = ray.wavelengths
        si.p = ray(t)
        si.n = n
        si.sh_frame = mi.Frame3f(sh_n)
        si.uv = geo.uv
        si.dp_du = self._to_world @ geo.dp_du
        si.dp_dv = self._to_world @ geo.dp_dv
        si.prim_index = hit.seg
        si.shape = dr.select(valid, mi.ShapePtr(self), dr.zeros(mi.ShapePtr))
        si.wi = dr.select(valid, si.to_local(-ray.d), -ray.d)
        return si

    def to_string(self) -> str:
        r_max, z_min, z_max = self.profile.bounds()
        return (
            f"LatheShape[id='{self.id()}', source='{self.profile.source}', "
            f"segments={self.profile.segment_count}, r_max={r_max:g}, "
            f"z=[{z_min:g}, {z_max:g}], smooth={self.smooth}]"
        )


def _unsupported_variant(props: mi.Properties) -> mi.Shape:
    raise RuntimeError(
        f"{_describe(props)}: Mitsuba variant '{mi.variant()}' is not supported; "
        "lathe_shape needs a JIT variant such as 'llvm_ad_rgb' or 'cuda_ad_rgb'"
    )


def register() -> None:
    """Register ``<shape type="lathe">`` for the active variant."""
    if dr.is_jit_v(mi.Float):
        mi.register_shape("lathe", lambda props: LatheShape(props))
    else:
        mi.register_shape("lathe", _unsupported_variant)
