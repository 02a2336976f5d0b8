"""Writing a loaded Mitsuba scene as a POV-Ray 3.7 scene (for
``scripts/compare_povray.py``).

Coordinates. POV-Ray is y-up and left-handed, Mitsuba (and these scenes)
z-up and right-handed. Nothing is converted globally: every position and
direction is written in Mitsuba's world coordinates, and the camera is given
by explicit ``location``/``direction``/``right``/``up`` vectors (the
sensor's own axes, image right = minus its local x), never ``look_at``, so
POV-Ray's handedness never enters (it only matters to ``look_at`` and to
rotations, which are not used). POV-Ray's ``lathe`` revolves ``<r, h>``
about its local y axis; Mitsuba's about local z, so each lathe gets the
matrix ``to_world * S``, where ``S`` swaps local y and z.

Profiles. A polyline lathe becomes ``lathe { linear_spline ... }`` (a closed
profile repeats its first point). A uniform cubic B-spline lathe becomes
``bezier_spline``: every segment's four B-spline control points are
converted exactly to the four Bezier points of the same cubic
(:func:`bspline_to_bezier`).

Materials and lights (the models differ; what is matched):

* ``dielectric``: ``pigment { rgbt 1 }`` (POV-Ray's filtered shadows) with
  Fresnel reflection and ``conserve_energy``, ``interior { ior eta }``;
  render Mitsuba with ``lathe_whitted`` ``shadows = filtered``.
* ``diffuse`` (RGB or ``checkerboard``): POV-Ray's ``diffuse k`` has no
  1/pi, so ``diffuse 1/pi`` with the reflectance as pigment.
* ``conductor``: a mirror (``reflection`` = its specular reflectance, no
  complex Fresnel).
* ``point``/``spot``: POV-Ray lights do not fall off unless told;
  ``fade_distance 1 fade_power 2`` gives 2/(1 + d^2), so the colour is half
  the intensity (1/d^2 within 1/d^2 of itself). ``directional`` becomes a
  ``parallel`` light with the irradiance as colour.
* an ``area`` emitter on a rectangle becomes a POV-Ray ``area_light`` of the
  same size and orientation (5x5 adaptive points) with the radiance times
  the area as intensity; it is not visible in reflections, as in POV-Ray.
* ``constant``: the background colour, plus POV-Ray's ambient term (the
  sky's radiance times the diffuse reflectance, without occlusion), where
  Mitsuba samples the sky with shadow rays.
* gamma: ``assumed_gamma 1`` and OpenEXR output, so that both images are
  compared in linear radiance.

Anything else (other shapes, BSDFs or emitters) raises :class:`PovExportError`
naming the object.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["PovExportError", "bezier_evaluate", "bspline_to_bezier", "lathe_spline", "scene_to_pov"]

#: Uniform cubic B-spline -> Bezier: ``bezier = BSPLINE_TO_BEZIER @ controls``
#: per segment (exact: both are the same cubic on t in [0, 1]).
BSPLINE_TO_BEZIER = np.array([[1.0, 4.0, 1.0, 0.0],
                              [0.0, 4.0, 2.0, 0.0],
                              [0.0, 2.0, 4.0, 0.0],
                              [0.0, 1.0, 4.0, 1.0]]) / 6.0

#: POV-Ray's lathe axis is its local y; Mitsuba's is local z: swap them.
SWAP_Y_Z = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


class PovExportError(ValueError):
    """The scene holds something that has no POV-Ray counterpart here."""


def bspline_to_bezier(segment_controls: np.ndarray) -> np.ndarray:
    """(n, 4, 2) uniform cubic B-spline segment controls -> (n, 4, 2) Bezier
    points of the same curves (docs/method.md, eq. 13's profile)."""
    return np.einsum("ij,njc->nic", BSPLINE_TO_BEZIER, np.asarray(segment_controls, dtype=np.float64))


def bezier_evaluate(bezier: np.ndarray, segment: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Points of Bezier segments ``segment`` at ``t`` (Bernstein form), (..., 2)."""
    b = np.asarray(bezier, dtype=np.float64)[np.asarray(segment)]
    t = np.asarray(t, dtype=np.float64)[..., None]
    s = 1.0 - t
    weights = (s**3, 3 * s * s * t, 3 * s * t * t, t**3)
    return sum(w * b[..., k, :] for k, w in enumerate(weights))


def vec(values) -> str:
    """``<a, b, c>`` with enough digits for float32 data."""
    return "<" + ", ".join(f"{float(v):.9g}" for v in values) + ">"


def pov_matrix(matrix: np.ndarray) -> str:
    """POV-Ray's ``matrix`` (row vectors: the columns of our 3x3, then the
    translation) of an affine column-vector 4x4 matrix."""
    m = np.asarray(matrix, dtype=np.float64)
    values = [m[row, col] for col in range(4) for row in range(3)]
    return "matrix <" + ", ".join(f"{v:.9g}" for v in values) + ">"


def lathe_spline(lathe) -> tuple[str, np.ndarray]:
    """(``linear_spline`` or ``bezier_spline``, the (n, 2) points) of a
    ``lathe`` shape's profile."""
    profile = lathe.profile
    if hasattr(profile, "segment_controls"):
        return "bezier_spline", bspline_to_bezier(profile.segment_controls).reshape(-1, 2)
    starts, ends = profile.segment_points()
    points = np.vstack([starts, ends[-1:]])
    return "linear_spline", points


def _matrix(transform) -> np.ndarray:
    """A Mitsuba transform (scalar or JIT, one entry) as a (4, 4) float64 array."""
    return np.array(transform.matrix, dtype=np.float64).reshape(4, 4)


def _params(obj) -> dict:
    import mitsuba as mi

    params = mi.traverse(obj)
    return {key: params[key] for key in params.keys()}


def _rgb(value) -> np.ndarray:
    return np.broadcast_to(np.ravel(np.asarray(value, dtype=np.float64)), (3,)) if np.size(value) in (1, 3) \
        else np.asarray(value, dtype=np.float64).ravel()[:3]


def _color(rgb) -> str:
    return "rgb " + vec(_rgb(rgb))


def material(bsdf, ambient: np.ndarray, who: str) -> str:
    """The POV-Ray texture (and interior) of a Mitsuba BSDF."""
    kind = bsdf.class_name()
    params = _params(bsdf)
    if kind in ("SmoothDielectric", "ThinDielectric"):
        eta = float(np.ravel(params.get("eta", 1.5))[0])
        interior = f"interior {{ ior {eta:.9g} }}" if kind == "SmoothDielectric" else ""
        return ("texture { pigment { rgbt 1 } finish { ambient 0 diffuse 0 "
                "reflection { 0, 1 fresnel on } conserve_energy } } " + interior)
    if kind == "SmoothConductor":
        return "texture { pigment { rgb 0 } finish { ambient 0 diffuse 0 reflection { rgb 1 } } }"
    if kind != "SmoothDiffuse":
        raise PovExportError(f"{who}: BSDF '{kind}' has no POV-Ray counterpart here "
                             "(dielectric, thindielectric, conductor, diffuse)")
    finish = f"finish {{ ambient {_color(ambient)} diffuse {1.0 / math.pi:.9g} }}"
    if "reflectance.value" in params:
        return f"texture {{ pigment {{ {_color(params['reflectance.value'])} }} {finish} }}"
    if "reflectance.color0.value" in params:
        to_uv = np.array(params["reflectance.to_uv"].matrix, dtype=np.float64).reshape(3, 3)
        # Mitsuba's checkerboard has 2 x 2 checks per unit of uv; a
        # rectangle's uv spans its local [-1, 1]: a check is 1/to_uv of it.
        size = 1.0 / to_uv[0, 0]
        # Shifted by half a check along z so that the plane z = 0 does not
        # sit on a check boundary.
        pigment = (f"pigment {{ checker {_color(params['reflectance.color0.value'])} "
                   f"{_color(params['reflectance.color1.value'])} scale {size:.9g} "
                   f"translate <0, 0, {-size / 2:.9g}> }}")
        return f"texture {{ {pigment} {finish} }}"
    raise PovExportError(f"{who}: only RGB and checkerboard reflectances are exported")


def shape_object(shape, ambient: np.ndarray) -> str:
    """A POV-Ray object for a Mitsuba shape (lathe, rectangle, sphere)."""
    from ..plugin.shape import LatheShape

    who = f"shape '{shape.id()}'" if shape.id() else f"a {shape.class_name()} shape"
    texture = material(shape.bsdf(), ambient, who)
    if isinstance(shape, LatheShape):
        spline, points = lathe_spline(shape)
        body = ", ".join(vec(p) for p in points)
        transform = pov_matrix(shape.to_world_matrix @ SWAP_Y_Z)
        return f"lathe {{ {spline} {len(points)}, {body}\n  {texture}\n  {transform} }}\n"
    if shape.class_name() == "Rectangle":
        if shape.emitter() is not None:
            return area_light(shape)
        to_world = _matrix(_params(shape)["to_world"])
        corners = "<-1, -1, 0>, <1, -1, 0>, <1, 1, 0>, <-1, 1, 0>, <-1, -1, 0>"
        return f"polygon {{ 5, {corners}\n  {texture}\n  {pov_matrix(to_world)} }}\n"
    if shape.class_name() == "Sphere":
        to_world = _matrix(_params(shape)["to_world"])
        return f"sphere {{ <0, 0, 0>, 1\n  {texture}\n  {pov_matrix(to_world)} }}\n"
    raise PovExportError(f"{who}: shape '{shape.class_name()}' has no POV-Ray counterpart here "
                         "(lathe, rectangle, sphere)")


def light_source(emitter) -> str:
    """A POV-Ray light for a Mitsuba emitter ('' for the constant sky)."""
    kind = emitter.class_name()
    params = _params(emitter)
    fade = "fade_distance 1 fade_power 2"
    if kind == "PointLight":
        position = np.ravel(np.asarray(params["position"], dtype=np.float64))
        return f"light_source {{ {vec(position)} {_color(_rgb(params['intensity.value']) / 2)} {fade} }}\n"
    if kind == "SpotLight":
        m = _matrix(params["to_world"])
        return (f"light_source {{ {vec(m[:3, 3])} {_color(_rgb(params['intensity.value']) / 2)} spotlight "
                f"point_at {vec(m[:3, 3] + m[:3, 2])} radius {float(params['beam_width']):.6g} "
                f"falloff {float(params['cutoff_angle']):.6g} {fade} }}\n")
    if kind == "DirectionalEmitter":
        m = _matrix(params["to_world"])
        source = -1e5 * m[:3, 2]
        return (f"light_source {{ {vec(source)} {_color(params['irradiance.value'])} parallel "
                f"point_at {vec(np.zeros(3))} }}\n")
    if kind in ("ConstantBackgroundEmitter", "AreaLight"):
        return ""  # the sky: see scene_to_pov; area lights: see area_light
    raise PovExportError(f"emitter '{emitter.id() or kind}': '{kind}' has no POV-Ray counterpart here "
                         "(point, spot, directional, area on a rectangle, constant)")


def area_light(shape) -> str:
    """A POV-Ray ``area_light`` for a Mitsuba rectangle with an ``area``
    emitter (see the module docstring)."""
    m = _matrix(_params(shape)["to_world"])
    axis_u, axis_v = 2 * m[:3, 0], 2 * m[:3, 1]
    area = float(np.linalg.norm(np.cross(axis_u, axis_v)))
    color = _rgb(_params(shape.emitter())["radiance.value"]) * area / 2
    return (f"light_source {{ {vec(m[:3, 3])} {_color(color)} area_light {vec(axis_u)}, {vec(axis_v)}, "
            "5, 5 adaptive 1 fade_distance 1 fade_power 2 }\n")


def camera(sensor) -> str:
    """The camera with explicit vectors (see the module docstring)."""
    params = _params(sensor)
    m = _matrix(sensor.world_transform())
    width, height = (int(v) for v in sensor.film().size())
    aspect = width / height
    x_fov = math.radians(float(np.ravel(params["x_fov"])[0]))
    left, up, forward = (m[:3, i] / np.linalg.norm(m[:3, i]) for i in range(3))
    direction = forward * (aspect / 2) / math.tan(x_fov / 2)
    return (f"camera {{ perspective location {vec(m[:3, 3])} direction {vec(direction)} "
            f"right {vec(-left * aspect)} up {vec(up)} }}\n")


def scene_to_pov(scene, max_trace_level: int = 10, adc_bailout: float = 1.0 / 255.0) -> str:
    """The POV-Ray 3.7 scene text of a loaded Mitsuba scene (see the module
    docstring for what is matched)."""
    sky = next((e for e in scene.emitters() if e.class_name() == "ConstantBackgroundEmitter"), None)
    ambient = _rgb(_params(sky)["radiance.value"]) if sky is not None else np.zeros(3)
    parts = [
        "#version 3.7;\n",
        f"global_settings {{ assumed_gamma 1.0 max_trace_level {max_trace_level} "
        f"adc_bailout {adc_bailout:.9g} ambient_light rgb 1 }}\n",
        f"background {{ {_color(ambient)} }}\n",
        camera(scene.sensors()[0]),
    ]
    parts += [light_source(emitter) for emitter in scene.emitters()]
    parts += [shape_object(shape, ambient) for shape in scene.shapes()]
    return "".join(part for part in parts if part)
