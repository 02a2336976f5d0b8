"""Opening a command's scene: the variant selected, ``-D`` and
``--resolution`` applied (:func:`open_scene`), and its sensor's values
checked like the options (:func:`check_sensor`)."""

from __future__ import annotations

import os
from collections.abc import Callable

from .errors import CliError
from .options import parse_defines, parse_resolution
from .variants import select_variant

__all__ = ["check_sensor", "open_scene"]


def open_scene(
    path: str | os.PathLike,
    variant: str,
    defines: list[str] | None = None,
    resolution: str | None = None,
    extra_defines: dict[str, str] | None = None,
    edit: Callable[[str, str], str] | None = None,
) -> object:
    """What every command-line tool does first: select ``variant``, register
    the plugins, parse ``-D key=value`` items and a ``WxH`` resolution, load
    the scene (edited by ``edit(text, path)``, see
    :func:`..tools.scenes.load_scene`). Raises :class:`SceneError` with a
    clear message."""
    from ..tools.scenes import load_scene

    select_variant(variant)
    values = parse_defines(defines)
    values.update(extra_defines or {})
    size = parse_resolution(resolution) if resolution else None
    return load_scene(path, values, size, edit)


def check_sensor(scene, path: str | os.PathLike, spp: int | None = None) -> tuple[int, int, int]:
    """(width, height, samples per pixel) of the first sensor of ``scene``
    (loaded from the file ``path``): ``spp`` (the ``--spp`` option), or
    the sampler's ``sample_count`` when None. Raises :class:`CliError`
    naming the file and the parameter when the scene has no sensor, when
    its film is 0 pixels wide or high, or when its sampler takes 0 samples
    per pixel (Mitsuba would fail in a kernel, or crash)."""
    if not scene.sensors():
        raise CliError(f"{os.fspath(path)}: the scene has no sensor")
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    for name, value in (("width", width), ("height", height)):
        if value < 1:
            raise CliError(f"{os.fspath(path)}: the film's '{name}' is {value}: it must be at least 1 "
                           "(fix the scene, or set --resolution)")
    if spp is None:
        spp = int(sensor.sampler().sample_count())
        if spp < 1:
            raise CliError(f"{os.fspath(path)}: the sampler's 'sample_count' is {spp}: it must be at "
                           "least 1 (fix the scene, or set --spp)")
    return width, height, int(spp)
