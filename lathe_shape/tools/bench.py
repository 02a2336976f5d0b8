"""Helpers of the benchmark scripts: their shared options, best-of-N render
timing, and scene files loaded with the options applied (and, optionally,
the lathe's profile replaced inline)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

from .scenes import load_string_in, replace_profile, set_film_size

__all__ = ["bench_arguments", "bench_scene", "best_render_time", "load_with_profile"]


def bench_arguments(description: str, argv: list[str] | None = None) -> argparse.Namespace:
    """The benchmark scripts' shared options (``--spp 16``, ``--resolution
    256x256``, ``--seed``, ``--variant``, ``-D``, ``--max-depth 8``,
    ``--repeat 3``), parsed from ``argv`` (default: the command line); selects
    the variant. ``args.size`` is the resolution as (width, height),
    ``args.define_values`` the ``-D`` options as a dict. A bad
    option exits with status 2 and a one-line message."""
    from ..cli.common import (
        CliError,
        add_render_options,
        check_at_least,
        parse_defines,
        parse_resolution,
        select_variant,
    )

    parser = argparse.ArgumentParser(description=description)
    add_render_options(parser, spp_default=16, resolution_default="256x256",
                       seed_help="seed of the warm-up render; timed render k uses SEED + k (default: 0)")
    parser.add_argument("--max-depth", type=int, default=8,
                        help="path depth of every integrator (default: 8)")
    parser.add_argument("--repeat", type=int, default=3,
                        help="timed renders per case, the best counts (default: 3)")
    args = parser.parse_args(argv)
    try:
        check_at_least("--spp", args.spp, 1)
        check_at_least("--repeat", args.repeat, 1)
        args.size = parse_resolution(args.resolution)
        args.define_values = parse_defines(args.defines)
        select_variant(args.variant)
    except (CliError, RuntimeError) as e:
        parser.error(str(e))
    return args


def load_with_profile(scene_file: str | Path, points: np.ndarray | None = None, kind: str = "polyline",
                      size: tuple[int, int] | None = None, **defines: str) -> mi.Scene:
    """Load a scene file with its (first) lathe's profile replaced by the
    inline profile ``points`` of the given ``kind`` (unless None) and every
    film set to ``size`` = (width, height) (unless None)."""
    scene_file = Path(scene_file)
    text = scene_file.read_text()
    if points is not None:
        text = replace_profile(text, points=points, kind=kind, source=str(scene_file))
    if size is not None:
        text = set_film_size(text, size, str(scene_file))
    return load_string_in(scene_file.parent, text, **defines)


def bench_scene(args: argparse.Namespace, scene_file: str | Path, points: np.ndarray | None = None,
                kind: str = "polyline", **defines: str) -> mi.Scene:
    """A benchmark's scene: ``scene_file`` at the options' resolution, with
    the ``spp`` and ``max_depth`` defaults set from them, then ``defines``,
    then the ``-D`` options (which win); the profile replaced as in
    :func:`load_with_profile`."""
    values = {"spp": str(args.spp), "max_depth": str(args.max_depth), **defines, **args.define_values}
    return load_with_profile(scene_file, points, kind, args.size, **values)


def best_render_time(scene: mi.Scene, integrator: mi.Integrator, spp: int,
                     repeat: int, seed: int = 0) -> tuple[float, np.ndarray]:
    """Best wall time of ``repeat`` renders (seeds ``seed + 1``, ...) after a
    warm-up render with ``seed`` (which pays the JIT compilation), and the
    last image."""
    image = mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy()
    times = []
    for k in range(repeat):
        start = time.perf_counter()
        image = mi.render(scene, spp=spp, seed=seed + k + 1, integrator=integrator).numpy()
        times.append(time.perf_counter() - start)
    return min(times), image
