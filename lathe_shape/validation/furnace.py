"""White-furnace check of energy conservation (used by tests and scripts).

A dielectric lathe under a uniform white environment (radiance 1) loses no
energy when every path eventually escapes: every pixel must come out 1.0.
Where a ``normal_check`` policy kills paths, pixels come out darker; where
inconsistent shading normals mis-track inside/outside, pixels scatter above
and below 1 (speckles).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["FURNACE_PROFILE", "FurnaceResult", "first_hit_mask", "furnace_scene", "furnace_table",
           "glass_mask", "run_furnace"]

#: A thick-walled glass with a rounded rim (closed profile, both ends on axis).
FURNACE_PROFILE = (
    "0 0, 1.2 0, 1.25 0.1, 1.0 0.6, 0.25 1.2, 0.2 2.0, 0.9 2.4, 1.3 3.2, 1.45 4.2, "
    "1.4 4.9, 1.33 4.95, 1.3 4.9, 1.33 4.2, 1.2 3.3, 0.8 2.6, 0.0 2.4"
)


def furnace_scene(
    integrator: dict | None = None,
    resolution: int | tuple[int, int] = 64,
    bsdf: dict | None = None,
    profile: str = FURNACE_PROFILE,
    smooth: bool = True,
) -> mi.Scene:
    """A lathe glass alone under a uniform white environment; ``resolution``
    is the film's (width, height), or one number for a square."""
    width, height = (resolution, resolution) if isinstance(resolution, int) else resolution
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator or {"type": "lathe_path", "max_depth": -1},
        "sensor": {
            "type": "perspective",
            "fov": 30,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, -16, 6], target=[0, 0, 2.4], up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": width, "height": height,
                     "rfilter": {"type": "box"}},
        },
        "light": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        "glass": {
            "type": "lathe",
            "profile": profile,
            "crease_angle": 60.0,
            "smooth": smooth,
            "mesh_segments": 256,
            "bsdf": bsdf or {"type": "dielectric", "int_ior": 1.5},
        },
    })


@dataclass
class FurnaceResult:
    mean: float          #: mean pixel value over the glass
    loss: float          #: 1 - mean
    speckle: float       #: fraction of glass pixels off by more than 20 %
    std: float           #: pixel standard deviation over the glass
    pixels: int          #: number of glass pixels


def glass_mask(scene: mi.Scene) -> np.ndarray:
    """Pixels whose centre ray hits one of the scene's lathes (exact
    intersection)."""
    from ..plugin.shape import scene_lathes

    sensor = scene.sensors()[0]
    width, height = sensor.film().size()
    idx = dr.arange(mi.UInt32, width * height)
    pos = mi.Point2f(mi.Float(idx % width) + 0.5, mi.Float(idx // width) + 0.5)
    ray, _ = sensor.sample_ray(0.0, 0.5, pos / mi.ScalarVector2f(width, height), mi.Point2f(0.5))
    hit = mi.Bool(False)
    for lathe in scene_lathes(scene):
        hit |= lathe.ray_intersect_exact(ray).is_valid()
    return hit.numpy().reshape(height, width)


def first_hit_mask(scene: mi.Scene, sensor: mi.Sensor | None = None,
                   lathes: list | None = None) -> np.ndarray:
    """(H, W) bool: the pixels of ``sensor`` (the scene's first) whose centre
    ray meets one of ``lathes`` (every exact lathe) before anything else,
    the lathes intersected exactly."""
    from ..plugin.caustic_paths import on_lathe
    from ..plugin.scene_geometry import ExactSceneGeometry

    sensor = sensor or scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    index = dr.arange(mi.UInt32, width * height)
    pixel = mi.Point2f(mi.Float(index % width) + 0.5, mi.Float(index // width) + 0.5)
    ray, _ = sensor.sample_ray(0.0, 0.5, pixel / mi.ScalarPoint2f(width, height), mi.Point2f(0.5))
    geometry = ExactSceneGeometry(scene)
    si = geometry.ray_intersect(mi.Ray3f(ray), mi.Bool(True))
    hit = si.is_valid() & on_lathe(geometry.lathes if lathes is None else lathes, si)
    return np.asarray(hit.numpy(), dtype=bool).reshape(height, width)


def run_furnace(scene: mi.Scene, spp: int = 64, seed: int = 0,
                integrator: mi.Integrator | None = None) -> FurnaceResult:
    """Render the furnace scene and summarise the glass pixels."""
    image = mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy().mean(axis=2)
    mask = glass_mask(scene)
    values = image[mask]
    return FurnaceResult(
        mean=float(values.mean()),
        loss=float(1.0 - values.mean()),
        speckle=float((np.abs(values - 1.0) > 0.2).mean()),
        std=float(values.std()),
        pixels=int(mask.sum()),
    )


def furnace_table(resolution: int | tuple[int, int] = 128, spp: int = 256,
                  seed: int = 0) -> Iterator[tuple[str, FurnaceResult]]:
    """(label, result) of every ``normal_check`` policy of ``lathe_path``
    (eq. 11), then of two baselines: stock ``path`` on the reference mesh
    (vertex normals), and the exact lathe with flat normals (nothing can
    contradict them: lossless). All with ``max_depth -1``; yielded one by one
    as they are rendered."""
    from ..plugin.lathe_path import NORMAL_CHECKS

    def lathe_path(**extra: str) -> mi.Integrator:
        return mi.load_dict({"type": "lathe_path", "max_depth": -1, **extra})

    scene = furnace_scene(resolution=resolution)
    for policy in NORMAL_CHECKS:
        yield policy, run_furnace(scene, spp, seed, lathe_path(normal_check=policy))
    yield "path (mesh)", run_furnace(scene, spp, seed, mi.load_dict({"type": "path", "max_depth": -1}))
    flat = furnace_scene(resolution=resolution, smooth=False)
    yield "flat normals", run_furnace(flat, spp, seed, lathe_path())
