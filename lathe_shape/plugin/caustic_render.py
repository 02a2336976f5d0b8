"""What ``lathe_path`` and ``lathe_volpath`` share for their light-traced
caustics (``caustics``; eqs. 32-40 of docs/method.md): the parameters, the
checks that decide whether a render traces them, and the render that runs
the path tracer's kernel, the deferred solves of eq. 40 and the light
tracer's pass, and adds the caustic image to the film.

(Functions, not a mixin: Mitsuba's integrator classes are nanobind classes,
which take no second base.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..memory import MAX_SAMPLES
from .caustic_paths import CausticTracer, chain_length_limit
from .deferred_solves import DeferredChainSolves, initial_capacity
from .media_segments import heterogeneous_medium
from .params import CAUSTIC_CAMERA_CHAINS, CAUSTIC_PATHS, typed_property

__all__ = ["MAX_PARTICLES", "CausticSettings", "NOTHING_TO_TRACE", "add_to_film", "caustic_media_problem",
           "caustic_setup", "check_particle_count", "render_with_caustics"]

#: Why a render has no light-traced caustic paths though ``caustics`` is on.
NOTHING_TO_TRACE = ("no lathe with a Dirac-delta BSDF, or no light (area, point, spot, directional, "
                    "environment)")


#: Most light particles one render traces: the limit on a render's samples,
#: :data:`~lathe_shape.memory.MAX_SAMPLES` (2^32 - 2^24), which the
#: command-line tools put on its camera samples. A billion particles did not
#: end in hours on two cores.
MAX_PARTICLES = MAX_SAMPLES


@dataclass(frozen=True)
class CausticSettings:
    """The ``caustics``, ``caustic_paths``, ``caustic_camera_chains`` and
    ``caustic_max_chain`` parameters (documented with the integrators);
    ``who``, the plugin they belong to (for errors)."""

    enabled: bool
    paths: float
    camera_chains: float
    max_chain: int
    who: str = "lathe_path"

    @classmethod
    def read(cls, props: mi.Properties, who: str) -> CausticSettings:
        """The parameters of plugin ``who``, checked; errors name it."""
        enabled = typed_property(props, "caustics", bool, True, who)
        paths = typed_property(props, "caustic_paths", float, CAUSTIC_PATHS, who)
        if not (paths > 0.0 and paths < 1e6):
            raise ValueError(f"{who}: parameter 'caustic_paths' must be > 0 and below 1e6 (particles "
                             f"per camera sample); got {paths}")
        chains = typed_property(props, "caustic_camera_chains", float, CAUSTIC_CAMERA_CHAINS, who)
        if not (0.0 <= chains <= 1.0):
            raise ValueError(f"{who}: parameter 'caustic_camera_chains' must be in [0, 1]; got {chains}")
        max_chain = typed_property(props, "caustic_max_chain", int, 8, who)
        if max_chain < 1:
            raise ValueError(f"{who}: parameter 'caustic_max_chain' must be >= 1; got {max_chain}")
        return cls(enabled, paths, chains, max_chain, who)


def check_particle_count(settings: CausticSettings, spp: int, width: int, height: int) -> int:
    """The number of light particles of a render of ``spp`` samples per
    pixel on a ``width`` x ``height`` film (its crop window):
    ``caustic_paths`` per camera sample, at least 1. Raises ValueError,
    naming the parameter, the count and the limit, beyond
    :data:`MAX_PARTICLES`."""
    samples = int(spp) * int(width) * int(height)
    count = max(1, round(settings.paths * samples))
    if count > MAX_PARTICLES:
        raise ValueError(
            f"{settings.who}: parameter 'caustic_paths' = {settings.paths:g} particles per camera sample at "
            f"{spp} spp on a {width}x{height} film is {count} light particles, more than the {MAX_PARTICLES} "
            f"one render may trace: use at most caustic_paths = {MAX_PARTICLES / samples:.6g}, fewer spp, "
            "or average renders with different seeds")
    return count


def caustic_media_problem(scene: mi.Scene, sensor: mi.Sensor) -> str:
    """Why ``lathe_volpath`` cannot trace caustics in ``scene`` (``""`` when
    it can): the particles and the camera connections carry the
    transmittance of homogeneous media in closed form, starting from a
    camera and lights outside every medium."""
    heterogeneous = heterogeneous_medium(scene)
    if heterogeneous is not None:
        shape, medium = heterogeneous
        return f"caustics need homogeneous media (medium '{medium.id()}' of shape '{shape.id()}' is not)"
    if sensor.get_medium() is not None:
        return "caustics need a sensor outside every medium (the sensor has a medium)"
    for emitter in scene.emitters():
        if emitter.get_medium() is not None:
            return f"caustics need lights outside every medium (emitter '{emitter.id()}' has a medium)"
    return ""


def caustic_setup(integrator, settings: CausticSettings, scene: mi.Scene, sensor: mi.Sensor,
                  normal_check: str, media: bool) -> tuple[CausticTracer | None, str]:
    """The caustic tracer of ``integrator``'s render of ``scene`` through
    ``sensor`` and ``""`` or, where caustics are off or unsupported,
    ``None`` and why. ``media``: the particles and connections carry the
    transmittance of the media they cross, and the path tracer's shadow
    rays cross ``null`` surfaces (``lathe_volpath``)."""
    if not settings.enabled:
        return None, "off"
    if not mi.is_rgb:
        return None, f"caustics need an RGB variant (this is '{mi.variant()}')"
    if sensor.class_name() != "PerspectiveCamera":
        return None, f"caustics need a perspective sensor (this is '{sensor.class_name()}')"
    if integrator.hide_emitters:
        return None, "caustics are not traced with hide_emitters"
    if mi.has_flag(sensor.film().flags(), mi.FilmFlags.Special):
        return None, f"caustics need an RGB film (this is '{sensor.film().class_name()}')"
    if media:
        problem = caustic_media_problem(scene, sensor)
        if problem:
            return None, problem
    depth = integrator.max_depth if integrator.max_depth != 0xFFFFFFFF else 1 << 30
    chain = chain_length_limit(depth, settings.max_chain)
    vertices = chain_length_limit(depth, 1 << 30)  # (both chains together)
    geometry = integrator.geometry(scene)
    tracer = CausticTracer(scene, sensor, geometry.lathes, chain, normal_check, vertices,
                           settings.camera_chains, media=media, nee_through_null=media)
    return (tracer, "") if tracer.active else (None, NOTHING_TO_TRACE)


def render_with_caustics(integrator, settings: CausticSettings, base_render: Callable, scene: mi.Scene,
                         sensor: int | mi.Sensor, seed: int, spp: int, develop: bool,
                         evaluate: bool) -> mi.TensorXf:
    """``integrator``'s render: Mitsuba's (``base_render``), plus the
    light-traced caustic paths (eq. 32), added to the developed image and to
    the film. While the path tracer's kernel is traced,
    ``integrator._caustic_render`` holds (tracer, particles per camera
    sample as an opaque Float, the buffer of eq. 40's deferred solves) for
    its ``sample``."""
    sensor_obj = scene.sensors()[sensor] if isinstance(sensor, int) else sensor
    # (Mitsuba's render by sensor index calls this again with the sensor:
    # the inner call renders the paths alone)
    inner = integrator._caustic_render is not None
    tracer, _ = integrator.caustic_setup(scene, sensor_obj) if develop and not inner else (None, "")
    if tracer is None:
        return base_render(scene, sensor, seed, spp, develop, evaluate)
    film = sensor_obj.film()
    spp = spp or sensor_obj.sampler().sample_count()
    crop = film.crop_size()
    count = check_particle_count(settings, spp, crop.x, crop.y)
    per_camera_sample = count / (spp * crop.x * crop.y)
    # Eq. 40's rare solves wait in a buffer (deferred_solves.py); one
    # that overflowed renders again (the same samples) with room for all
    capacity = initial_capacity(spp * crop.x * crop.y)
    while True:
        deferred = DeferredChainSolves(capacity)
        integrator._caustic_render = (tracer, dr.opaque(mi.Float, per_camera_sample), deferred)
        try:
            base_render(scene, sensor, seed, spp, develop=False, evaluate=True)
        finally:
            integrator._caustic_render = None
        if not deferred.overflowed():
            break
        capacity = deferred.count()
    geometry = integrator.geometry(scene)
    deferred.put(tracer, geometry, sensor_obj)
    image = film.develop()
    caustic = tracer.render(scene, geometry, sensor_obj, seed, count, dr.opaque(mi.Float, per_camera_sample))
    image = add_to_film(film, image, caustic)
    if evaluate:
        dr.eval(image)
    return image


def add_to_film(film: mi.Film, image: mi.TensorXf, caustic: mi.TensorXf) -> mi.TensorXf:
    """``image`` (developed, channels as ``film.bitmap()`` names them) with
    ``caustic`` (H, W, 3, linear sRGB) added as the film develops RGB: to
    its R, G, B channels, or converted to X, Y, Z by Mitsuba's
    ``srgb_to_xyz`` (an ``xyz`` or ``xyza`` film), or its luminance to Y
    (``luminance``, ``luminance_alpha``); the film then holds the sum, so
    that ``film.develop()``, ``film.bitmap()`` and ``film.write()`` give it
    too (its weights become 1; it stores RGB whatever it develops)."""
    total = np.array(image, dtype=np.float32)
    caustic = np.asarray(caustic, dtype=np.float32)
    raw = film.bitmap(raw=True)
    raw_names = [raw.struct_()[index].name for index in range(raw.channel_count())]
    developed = film.bitmap()
    names = [developed.struct_()[index].name for index in range(developed.channel_count())]
    ones = np.ones(total.shape[:2] + (1,), dtype=np.float32)
    if names[:3] == ["R", "G", "B"]:
        total[:, :, :3] += caustic
        rgb = total[:, :, :3]
    elif names[:3] == ["X", "Y", "Z"]:
        to_xyz = srgb_to_xyz_matrix()
        total[:, :, :3] += caustic @ to_xyz.T.astype(np.float32)
        # (stored as the RGB that develops to these X, Y, Z)
        rgb = (total[:, :, :3].astype(np.float64) @ np.linalg.inv(to_xyz).T).astype(np.float32)
    elif names[:1] == ["Y"]:  # the caustic's luminance (Rec. 709, as the film weighs RGB)
        total[:, :, 0] += caustic @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
        # (a grey of the developed Y develops to that Y)
        rgb = np.repeat(total[:, :, :1], 3, axis=2)
    else:
        raise ValueError(f"caustics cannot be added to a film whose channels are {names} (pixel formats "
                         "rgb, rgba, xyz, xyza, luminance and luminance_alpha can take them)")

    def stored(name: str) -> np.ndarray:
        if name == "W":
            return ones
        if name in ("R", "G", "B"):
            return rgb[:, :, "RGB".index(name)][:, :, None]
        return total[:, :, names.index(name)][:, :, None]

    storage = np.concatenate([stored(name) for name in raw_names], axis=2)
    film.prepare(raw_names[raw_names.index("W") + 1:])
    film.put_block(mi.ImageBlock(mi.TensorXf(storage), film.crop_offset()))
    return mi.TensorXf(total)


def srgb_to_xyz_matrix() -> np.ndarray:
    """The 3x3 matrix (float64) of Mitsuba's ``srgb_to_xyz``, which an
    ``xyz`` film develops its RGB samples with (read from Mitsuba)."""
    columns = [np.array(mi.srgb_to_xyz(mi.Color3f(*unit)), dtype=np.float64).ravel()
               for unit in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))]
    return np.stack(columns, axis=1)
