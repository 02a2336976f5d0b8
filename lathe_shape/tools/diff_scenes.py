"""Small scenes for differentiable rendering of one lathe: a diffuse lathe
lit by a point light, seen by perspective cameras around it (the gradient
checks, the gradient benchmark and the inverse design use them)."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np

__all__ = ["DEFAULT_PROFILE", "DEFAULT_VIEWS", "glass_scene", "lathe_scene", "profile_string", "straw_scene"]

#: A vase-like polyline (both ends on the axis): smooth joints on the bowl,
#: creases at the rim of the top cap and at the foot.
DEFAULT_PROFILE = "0 0, 0.6 0, 0.7 0.35, 0.72 0.7, 0.6 1.0, 0.4 1.2, 0 1.2"


def profile_string(points: np.ndarray) -> str:
    """``"r z, r z, ..."`` of (n, 2) points (the ``profile`` parameter)."""
    return ", ".join(f"{r:.9g} {z:.9g}" for r, z in np.asarray(points, dtype=np.float64).reshape(-1, 2))


def _camera(azimuth_deg: float, resolution: int, target_z: float, distance: float, height: float) -> dict:
    phi = math.radians(azimuth_deg)
    origin = [distance * math.cos(phi), distance * math.sin(phi), height]
    return {
        "type": "perspective",
        "fov": 35,
        "to_world": mi.ScalarTransform4f().look_at(origin, [0, 0, target_z], [0, 0, 1]),
        "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
        "sampler": {"type": "independent", "sample_count": 4},
    }


#: Camera placements ``(azimuth in degrees, height)`` of the default view.
DEFAULT_VIEWS = ((10.0, 2.5),)

#: Point light positions of the default scene.
DEFAULT_LIGHTS = ((2.0, -2.0, 3.0),)


def lathe_scene(profile: str | np.ndarray = DEFAULT_PROFILE, kind: str = "polyline", resolution: int = 32,
                views: tuple[tuple[float, float], ...] = DEFAULT_VIEWS, integrator: str = "lathe_prb",
                max_depth: int = 2, lathe_id: str = "lathe",
                offset: tuple[float, float, float] = (0.0, 0.0, 0.0), reference: str = "mesh",
                lights: tuple[tuple[float, float, float], ...] = DEFAULT_LIGHTS) -> mi.Scene:
    """A diffuse ``lathe`` (profile string or (n, 2) points, ``kind``) at
    ``offset``, a point light, and one camera per view ``(azimuth in
    degrees, height)``, 3 units from the axis, looking at the point (0, 0,
    0.6) (sensor ``k`` is view ``k``), and a point light at each of
    ``lights``. ``reference`` is the lathe's reference parameter (``proxy``
    when only exact integrators render it)."""
    if not isinstance(profile, str):
        profile = profile_string(profile)
    scene: dict[str, object] = {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": max_depth},
        lathe_id: {"type": "lathe", "profile": profile, "kind": kind, "bsdf": {"type": "diffuse"},
                   "reference": reference, "to_world": mi.ScalarTransform4f().translate(list(offset))},
    }
    for k, position in enumerate(lights):
        scene[f"light_{k}"] = {"type": "point", "position": list(position),
                               "intensity": {"type": "rgb", "value": 20.0}}
    for k, (azimuth, height) in enumerate(views):
        scene[f"camera_{k}"] = _camera(azimuth, resolution, 0.6, 3.0, height)
    return mi.load_dict(scene)


def _smooth_texture(size: int = 128) -> mi.TensorXf:
    """A smooth, non-symmetric grey pattern (finite differences through
    glass need a smooth background: a textured one makes them mostly edge
    crossings)."""
    u = np.linspace(0.0, 1.0, size)
    wave_u = np.sin(2 * np.pi * (2 * u + 0.1))
    wave_v = np.cos(2 * np.pi * (1.5 * u + 0.2))
    value = 0.5 + 0.4 * wave_u[None, :] * wave_v[:, None]
    return mi.TensorXf(np.repeat(value[..., None], 3, axis=2).astype(np.float32))


def _environment_texture(width: int = 256) -> mi.TensorXf:
    """A smooth grey environment map (equirectangular, ``width x width/2``)
    with whole periods around the azimuth, so that it is continuous across
    the map's seam, and at the poles: 12 waves around, 3 from pole to pole
    (the glass, a tenth of the view, refracts a few of them)."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(width // 2) + 0.5) / (width // 2)
    # (the waves around fade out towards the poles, where all azimuths meet)
    around = np.sin(2 * np.pi * 12 * u)
    along = np.sin(np.pi * v) * np.cos(2 * np.pi * (3 * v + 0.1))
    value = 0.5 + 0.4 * around[None, :] * along[:, None]
    return mi.TensorXf(np.repeat(value[..., None], 3, axis=2).astype(np.float32))


def glass_scene(filename: str, kind: str = "polyline", lighting: str = "area", resolution: int = 48,
                height: float = 2.0, max_depth: int = 12, integrator: str = "lathe_prb") -> mi.Scene:
    """A clear glass (``dielectric``, IOR 1.5) of the profile file
    ``filename`` (``kind``), scaled to ``height`` units, seen from the side
    in front of smooth light: ``lighting="area"``, a textured emissive
    backdrop behind it; ``"envmap"``, a smooth environment map. The glass's
    id is ``glass``."""
    if lighting not in ("area", "envmap"):
        raise ValueError(f"glass_scene: unknown lighting '{lighting}' (expected area or envmap)")
    probe = mi.load_dict({"type": "lathe", "filename": filename, "kind": kind})
    top = float(probe.bbox().max.z)
    transform = mi.ScalarTransform4f
    scale = height / top
    scene: dict[str, object] = {
        "type": "scene",
        # No Russian roulette: its decisions would flip between the finite
        # differences' renders (noise in the FD, none in the AD)
        "integrator": {"type": integrator, "max_depth": max_depth, "rr_depth": max_depth},
        "camera": {"type": "perspective", "fov": 32,
                   "to_world": transform().look_at(origin=[0.0, -6.0, 0.8 * height],
                                                   target=[0.0, 0.0, 0.5 * height], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 16}},
        "glass": {"type": "lathe", "filename": filename, "kind": kind, "to_world": transform().scale(scale),
                  "bsdf": {"type": "dielectric", "int_ior": 1.5}},
    }
    texture = {"type": "bitmap", "data": _smooth_texture(), "raw": True, "filter_type": "bilinear"}
    if lighting == "area":
        scene["backdrop"] = {"type": "rectangle",
                             "to_world": transform().translate([0, 3, 0.5 * height]).rotate([1, 0, 0], 90)
                             .scale([2.5 * height, 2.5 * height, 1]),
                             "emitter": {"type": "area", "radiance": texture}}
    else:
        scene["sky"] = {"type": "envmap", "bitmap": mi.Bitmap(_environment_texture().numpy())}
    return mi.load_dict(scene)


#: A tumbler (outer radius 0.5, wall 0.05, base 0.1, 1.2 tall) and a straw
#: (radius 0.08) standing in it off the axis, out of it at the top.
TUMBLER_PROFILE = "0 0, 0.5 0, 0.5 1.2, 0.45 1.2, 0.45 0.1, 0 0.1"
STRAW_PROFILE = "0 0.15, 0.08 0.15, 0.08 1.5, 0 1.5"


def straw_scene(resolution: int = 48, max_depth: int = 12, integrator: str = "lathe_prb") -> mi.Scene:
    """A diffuse straw (lathe ``straw``, :data:`STRAW_PROFILE`) in a clear
    tumbler (lathe ``glass``, ``dielectric`` 1.5, :data:`TUMBLER_PROFILE`),
    in front of the smooth emissive backdrop of :func:`glass_scene`, under
    a uniform sky: below the rim the straw's outlines are seen only through
    the glass."""
    transform = mi.ScalarTransform4f
    return mi.load_dict({
        "type": "scene",
        # (no Russian roulette, as in glass_scene)
        "integrator": {"type": integrator, "max_depth": max_depth, "rr_depth": max_depth},
        "camera": {"type": "perspective", "fov": 30,
                   "to_world": transform().look_at(origin=[0, -4, 1.2], target=[0, 0, 0.6], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": 16}},
        "glass": {"type": "lathe", "profile": TUMBLER_PROFILE,
                  "bsdf": {"type": "dielectric", "int_ior": 1.5}},
        "straw": {"type": "lathe", "profile": STRAW_PROFILE,
                  "to_world": transform().translate([0.15, 0.05, 0]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.3, 0.2]}}},
        "backdrop": {"type": "rectangle",
                     "to_world": transform().translate([0, 3, 0.6]).rotate([1, 0, 0], 90).scale([4, 4, 1]),
                     "emitter": {"type": "area", "radiance": {"type": "bitmap", "data": _smooth_texture(),
                                                              "raw": True, "filter_type": "bilinear"}}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.4}},
    })
