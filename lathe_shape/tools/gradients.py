"""Checking profile gradients: forward-mode gradient images, central finite
differences of the exact render, and the pixel classes they are compared on.

A scene rendered with ``lathe_prb`` gives *interior* derivatives (attached
hits, see lathe_shape/plugin/lathe_prb.py). Finite differences of the
render also contain the motion of discontinuities: the lathe's silhouette,
and in the image of a polyline the lines where the profile's joints lie
(shading jumps across a creased joint). :func:`pixel_classes` sorts the
pixels by exact ray casting at sub-pixel positions: *interior* pixels see
one profile segment only, in all of their footprint and their neighbours';
*silhouette* pixels see the lathe in part of their footprint.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi
import numpy as np

if TYPE_CHECKING:
    from ..plugin.shape import LatheShape

__all__ = ["GlassGradient", "GradientCheck", "check_gradient", "finite_difference", "forward_gradient",
           "glass_gradient", "glass_outline_pixels", "gradient_passes", "gradient_times", "pixel_classes",
           "points_key", "set_points", "wall_count"]


def points_key(params: mi.SceneParameters, lathe: LatheShape) -> str:
    """The ``<id>.points`` key of ``lathe`` in ``params``."""
    for key in params.keys():
        if key.split(".")[-1] == "points" and params.properties[key][2] is lathe:
            return key
    raise KeyError(f"lathe '{lathe.id()}' has no 'points' parameter in the given scene parameters")


def forward_gradient(scene: mi.Scene, key: str, index: int, spp: int, seed: int = 0) -> np.ndarray:
    """d(image) / d(points[index]) by forward-mode AD (the scene's integrator
    must be differentiable, e.g. ``lathe_prb``)."""
    params = mi.traverse(scene)
    value = params[key]
    if not 0 <= index < dr.width(value):
        raise IndexError(f"forward_gradient: index {index} is not a coordinate of '{key}' "
                         f"(0..{dr.width(value) - 1})")
    dr.enable_grad(value)
    try:
        params.update()
        tangent = np.zeros(dr.width(value), dtype=np.float32)
        tangent[index] = 1.0
        dr.set_grad(value, mi.Float(tangent))
        # The integrator directly (mi.render refuses equal primal and gradient
        # seeds): the same samples as the primal renders of finite_difference
        grad = scene.integrator().render_forward(scene, params, seed=seed, spp=spp)
        return np.array(grad)
    finally:
        dr.disable_grad(value)


def set_points(scene: mi.Scene, key: str, values: np.ndarray) -> None:
    """Write new profile points into the scene (re-validated, rebuilt)."""
    params = mi.traverse(scene)
    params[key] = mi.Float(np.asarray(values, dtype=np.float32))
    params.update()


def finite_difference(scene: mi.Scene, key: str, index: int, h: float, spp: int,
                      seed: int = 0) -> np.ndarray:
    """Central difference ``(I(x + h e_i) - I(x - h e_i)) / 2h`` of the
    primal render with one seed (correlated samples); restores the points."""
    base = np.array(mi.traverse(scene)[key], dtype=np.float64)
    if not 0 <= index < len(base):
        raise IndexError(f"finite_difference: index {index} is not a coordinate of '{key}' "
                         f"(0..{len(base) - 1})")
    images = []
    try:
        for sign in (1.0, -1.0):
            moved = base.copy()
            moved[index] += sign * h
            set_points(scene, key, moved)
            images.append(np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float64))
    finally:
        # (also when a step makes an invalid profile, which set_points refuses)
        set_points(scene, key, base)
    return (images[0] - images[1]) / (2.0 * h)


def pixel_classes(scene: mi.Scene, lathe: LatheShape, sub: int = 4,
                  sensor: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Boolean ``(interior, silhouette)`` masks of the film's pixels, from
    ``sub x sub`` exact rays per pixel: interior pixels (and their 8
    neighbours) see one segment of ``lathe`` in all their rays; silhouette
    pixels (dilated by one) see it in some rays only."""
    from ..plugin.scene_geometry import ExactSceneGeometry  # needs a variant

    ray, width, height = _subpixel_rays(scene.sensors()[sensor], sub)
    si = ExactSceneGeometry(scene).ray_intersect(ray, mi.Bool(True))
    mine = np.array(si.is_valid() & (si.shape == mi.ShapePtr(lathe))).reshape(height, width, -1)
    seg = np.where(mine, np.array(si.prim_index, dtype=np.int64).reshape(height, width, -1), -1)
    one_segment = mine.all(axis=2) & (seg.min(axis=2) == seg.max(axis=2))
    partial = mine.any(axis=2) & ~mine.all(axis=2)
    return _erode(one_segment), ~_erode(~partial)


def _subpixel_rays(camera: mi.Sensor, sub: int) -> tuple[mi.Ray3f, int, int]:
    """Camera rays through ``sub x sub`` evenly spaced positions in every
    pixel (pixel-major, row by row), and the film's width and height."""
    width, height = camera.film().crop_size()
    jx, jy = np.meshgrid((np.arange(sub) + 0.5) / sub, (np.arange(sub) + 0.5) / sub)
    py, px = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    x = (px[..., None, None] + jx) / width
    y = (py[..., None, None] + jy) / height
    ray, _ = camera.sample_ray(0.0, 0.5, mi.Point2f(x.ravel(), y.ravel()), mi.Point2f(0.5))
    return mi.Ray3f(ray), width, height


def _erode(mask: np.ndarray) -> np.ndarray:
    """Pixels whose 3x3 neighbourhood lies in ``mask`` (outside = False)."""
    padded = np.pad(mask, 1, constant_values=False)
    out = np.ones_like(mask)
    for dy in range(3):
        for dx in range(3):
            out &= padded[dy:dy + mask.shape[0], dx:dx + mask.shape[1]]
    return out


@dataclass
class GradientCheck:
    """Sums of a gradient image and its finite difference over pixel classes."""

    ad_interior: float
    fd_interior: float
    ad_silhouette: float
    fd_silhouette: float
    fd_total: float

    @property
    def interior_error(self) -> float:
        """Relative error of the AD gradient on the interior pixels."""
        return abs(self.ad_interior - self.fd_interior) / max(abs(self.fd_interior), 1e-12)

    @property
    def silhouette_share(self) -> float:
        """Share of the FD gradient (sum over the image) carried by the
        silhouette pixels."""
        return self.fd_silhouette / self.fd_total if self.fd_total else 0.0


def check_gradient(scene: mi.Scene, lathe: LatheShape, index: int, h: float, spp: int,
                   seed: int = 0) -> GradientCheck:
    """Forward-mode gradient vs central finite difference for coordinate
    ``index`` of ``lathe``'s points, summed over interior and silhouette
    pixels (:func:`pixel_classes`) and over the whole image."""
    key = points_key(mi.traverse(scene), lathe)
    ad = forward_gradient(scene, key, index, spp, seed).sum(axis=2)
    fd = finite_difference(scene, key, index, h, spp, seed).sum(axis=2)
    interior, silhouette = pixel_classes(scene, lathe)
    return GradientCheck(float(ad[interior].sum()), float(fd[interior].sum()),
                         float(ad[silhouette].sum()), float(fd[silhouette].sum()), float(fd.sum()))


@contextlib.contextmanager
def gradient_passes(scene: mi.Scene, primal: mi.Integrator, spp: int) -> Iterator[dict[str, Callable]]:
    """Within: ``{"primal": run, "backward": run}``, each ``run(seed)`` one
    render with ``spp`` samples per pixel: the primal render with ``primal``
    (e.g. ``lathe_path``), and one backward pass of the scene's own
    integrator (``lathe_prb``: ``render_backward``, its attached pass and
    reverse pass, for the gradient of the image sum with respect to every
    lathe's points, read back). The points' gradients are enabled within,
    and disabled after."""
    from ..plugin.shape import scene_lathes  # needs a variant

    params = mi.traverse(scene)
    keys = [points_key(params, lathe) for lathe in scene_lathes(scene)]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    film = scene.sensors()[0].film()
    channels = film.base_channels_count()
    weights = mi.TensorXf(dr.full(mi.Float, 1.0, film.size()[0] * film.size()[1] * channels),
                          (film.size()[1], film.size()[0], channels))

    def run_primal(seed: int) -> None:
        mi.render(scene, spp=spp, seed=seed, integrator=primal).numpy()

    def run_backward(seed: int) -> None:
        scene.integrator().render_backward(scene, params, weights, seed=seed, spp=spp)
        for key in keys:
            dr.grad(params[key]).numpy()
            dr.clear_grad(params[key])

    try:
        yield {"primal": run_primal, "backward": run_backward}
    finally:
        for key in keys:
            dr.disable_grad(params[key])


def gradient_times(scene: mi.Scene, primal: mi.Integrator, spp: int, repeat: int,
                   seed: int = 0) -> dict[str, list[float]]:
    """Wall times of :func:`gradient_passes`'s primal render and backward
    pass, interleaved (render ``k`` with ``seed + k``), after one warm-up
    of each (which pays the JIT compilation)."""
    with gradient_passes(scene, primal, spp) as cases:
        for run in cases.values():
            run(seed)
        times: dict[str, list[float]] = {name: [] for name in cases}
        for k in range(1, repeat + 1):
            for name, run in cases.items():
                start = time.perf_counter()
                run(seed + k)
                times[name].append(time.perf_counter() - start)
    return times


@dataclass
class GlassGradient:
    """A gradient image and its finite difference on a glass's interior
    pixels (camera rays that meet the glass, eroded by two pixels: no
    outline pixels), with the number of walls each pixel's camera line
    crosses."""

    ad: np.ndarray
    fd: np.ndarray
    interior: np.ndarray
    walls: np.ndarray

    def correlation(self, mask: np.ndarray | None = None, trim: float = 0.0) -> float:
        """Per-pixel correlation of AD and FD on the interior (and ``mask``),
        leaving out the ``trim`` share of pixels where they differ most (the
        heavy tail of paths through solid glass)."""
        a, f = self.trimmed(mask, trim)
        return float(np.corrcoef(a, f)[0, 1])

    def trimmed(self, mask: np.ndarray | None = None, trim: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """AD and FD on the interior (and ``mask``) without the ``trim``
        share of pixels where they differ most."""
        m = self.interior if mask is None else self.interior & mask
        a, f = self.ad[m], self.fd[m]
        if trim > 0.0:
            keep = np.abs(a - f) <= np.quantile(np.abs(a - f), 1.0 - trim)
            a, f = a[keep], f[keep]
        return a, f

    def half_sums(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``((AD, FD) left, (AD, FD) right)``: interior sums on either side
        of the image's middle column (a glass seen from the side gives
        nearly antisymmetric images, whose total cancels)."""
        middle = self.ad.shape[1] // 2
        left = np.zeros_like(self.interior)
        left[:, :middle] = True
        return tuple((float(self.ad[self.interior & side].sum()), float(self.fd[self.interior & side].sum()))
                     for side in (left, ~left))


def wall_count(scene: mi.Scene, lathe: LatheShape, max_walls: int = 16) -> np.ndarray:
    """How many walls of ``lathe`` each pixel's central camera line crosses
    (straight on, unrefracted)."""
    from ..plugin.scene_geometry import ExactSceneGeometry  # needs a variant

    ray, width, height = _subpixel_rays(scene.sensors()[0], 1)
    geometry = ExactSceneGeometry(scene)
    count = np.zeros(width * height, dtype=np.int64)
    active = mi.Bool(True)
    for _ in range(max_walls):
        si = geometry.ray_intersect(ray, active)
        mine = si.is_valid() & (si.shape == mi.ShapePtr(lathe))
        count += np.array(mine, dtype=np.int64)
        active &= si.is_valid()
        ray = si.spawn_ray(ray.d)
    return count.reshape(height, width)


def glass_gradient(scene: mi.Scene, lathe: LatheShape, index: int, h: float, spp: int,
                   seed: int = 0) -> GlassGradient:
    """Forward-mode gradient and central finite difference (step ``h``)
    of coordinate ``index`` of ``lathe``'s points, summed over channels."""
    key = points_key(mi.traverse(scene), lathe)
    ad = forward_gradient(scene, key, index, spp, seed).sum(axis=2)
    fd = finite_difference(scene, key, index, h, spp, seed).sum(axis=2)
    walls = wall_count(scene, lathe)
    interior = _erode(_erode(walls > 0))
    return GlassGradient(ad, fd, interior, walls)


def glass_outline_pixels(scene: mi.Scene, lathe: LatheShape, sub: int = 4, max_walls: int = 16) -> np.ndarray:
    """Pixels where an outline is seen through the glass: camera rays at
    ``sub x sub`` positions in the pixel, followed through ``lathe`` along
    the refracted path (reflecting only where the light is totally
    reflected), do not all cross the same number of walls."""
    from ..plugin.scene_geometry import ExactSceneGeometry  # needs a variant

    ray, width, height = _subpixel_rays(scene.sensors()[0], sub)
    geometry = ExactSceneGeometry(scene)
    count = np.zeros(dr.width(ray.o), dtype=np.int64)
    active = mi.Bool(True)
    ctx = mi.BSDFContext()
    for _ in range(max_walls):
        si = geometry.ray_intersect(ray, active)
        mine = active & si.is_valid() & (si.shape == mi.ShapePtr(lathe))
        count += np.array(mine, dtype=np.int64)
        bs, _ = si.bsdf().sample(ctx, si, 1.0 - 1e-6, mi.Point2f(0.5), mine)
        active = mine & (bs.pdf > 0)
        ray = si.spawn_ray(si.to_world(bs.wo))
    count = count.reshape(height, width, -1)
    return count.min(axis=2) != count.max(axis=2)
