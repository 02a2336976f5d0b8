"""Helpers of the benchmark scripts: their shared options, render timing
(interleaved repeats summarised by median and spread), the first render
from a cold kernel cache (and where its time goes), the coarsest reference
mesh that agrees with the exact render, and scene files loaded with the
options applied (and, optionally, the lathe's profile replaced inline)."""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import mitsuba as mi
import numpy as np

from ..tools.scenes import load_string_in, replace_profile, set_film_size

__all__ = [
    "bench_arguments",
    "bench_scene",
    "cold_first_render",
    "cold_first_render_parts",
    "coarsest_agreeing_mesh",
    "interleaved_render_times",
    "load_with_profile",
    "median_spread",
    "square_side",
]


def bench_arguments(description: str, argv: list[str] | None = None, repeat: int = 3,
                    depths: tuple[int, ...] | None = None,
                    extra: Callable[[argparse.ArgumentParser], None] | None = None) -> argparse.Namespace:
    """The benchmark scripts' shared options (``--spp 16``, ``--resolution
    256x256``, ``--seed``, ``--variant``, ``-D``, ``--max-depth 8``,
    ``--repeat 3``), parsed from ``argv`` (default: the command line); selects
    the variant. ``args.size`` is the resolution as (width, height),
    ``args.define_values`` the ``-D`` options as a dict. With ``depths``,
    ``--max-depth`` takes several values (default ``depths``), kept in
    ``args.max_depths`` (``args.max_depth`` is the first). ``extra(parser)``
    adds a script's own options. A bad option exits with status 2 and a
    one-line message."""
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
    if depths:
        parser.add_argument("--max-depth", dest="max_depths", type=int, nargs="+", default=list(depths),
                            help=f"path depths to measure (default: {' '.join(map(str, depths))})")
    else:
        parser.add_argument("--max-depth", type=int, default=8,
                            help="path depth of every integrator (default: 8)")
    if extra is not None:
        extra(parser)
    parser.add_argument("--repeat", type=int, default=repeat,
                        help=f"timed renders per case (default: {repeat})")
    args = parser.parse_args(argv)
    try:
        check_at_least("--spp", args.spp, 1)
        check_at_least("--repeat", args.repeat, 1)
        if depths:
            args.max_depth = args.max_depths[0]
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


def interleaved_render_times(cases: dict[str, tuple[mi.Scene, mi.Integrator]], spp: int, repeat: int,
                             seed: int = 0) -> dict[str, list[float]]:
    """Wall times of ``repeat`` renders of every case, taken in turn (A B C
    A B C ...) so that a slow spell of the machine hits all cases alike,
    after one warm-up render of each (which pays the JIT compilation)."""
    for scene, integrator in cases.values():
        mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy()
    times: dict[str, list[float]] = {name: [] for name in cases}
    for k in range(repeat):
        for name, (scene, integrator) in cases.items():
            start = time.perf_counter()
            mi.render(scene, spp=spp, seed=seed + k + 1, integrator=integrator).numpy()
            times[name].append(time.perf_counter() - start)
    return times


def median_spread(times: list[float]) -> tuple[float, float, float]:
    """(median, min, max) of a list of times."""
    return float(np.median(times)), float(min(times)), float(max(times))


def coarsest_agreeing_mesh(scene_at: Callable[[int], mi.Scene], exact_scene: mi.Scene, max_depth: int,
                           spp: int, seed: int = 0,
                           candidates: tuple[int, ...] = (16, 32, 64, 128, 256, 512, 1024, 2048),
                           ) -> tuple[int | None, float, float]:
    """The coarsest ``mesh_segments`` whose stock ``path`` render agrees with
    the exact render within noise on the glass pixels.

    The exact render uses ``lathe_path`` with ``normal_check none`` and
    without ``caustics`` (whose light-traced paths are drawn apart), which
    draws random numbers as ``path`` does, so with the same seed the two
    renders differ by the geometry, not by noise. The noise is the error
    between two exact renders of different seeds. Returns (segments, its
    error, the noise); segments is None when no candidate agrees.
    ``scene_at(n)`` loads the scene with ``mesh_segments`` n.
    """
    from ..tools.images import relative_error
    from .furnace import glass_mask

    exact_integrator = mi.load_dict({"type": "lathe_path", "max_depth": max_depth, "normal_check": "none",
                                     "caustics": False})
    mesh_integrator = mi.load_dict({"type": "path", "max_depth": max_depth})
    mask = glass_mask(exact_scene)
    exact = mi.render(exact_scene, spp=spp, seed=seed, integrator=exact_integrator).numpy()
    other = mi.render(exact_scene, spp=spp, seed=seed + 7919, integrator=exact_integrator).numpy()
    noise = relative_error(other, exact, mask)
    error = float("inf")
    for segments in candidates:
        mesh = mi.render(scene_at(segments), spp=spp, seed=seed, integrator=mesh_integrator).numpy()
        error = relative_error(mesh, exact, mask)
        if error <= noise:
            return segments, error, noise
    return None, error, noise


_COLD_RENDER = """
import json, sys, time
import drjit as dr
import mitsuba as mi
from lathe_shape.cli.common import select_variant
from lathe_shape.tools.scenes import load_scene
select_variant(sys.argv[1])
scene = load_scene(sys.argv[2], dict(arg.split("=", 1) for arg in sys.argv[3:]))
dr.set_flag(dr.JitFlag.KernelHistory, True)
dr.kernel_history()
start = time.perf_counter()
mi.render(scene).numpy()
seconds = time.perf_counter() - start
kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
print(json.dumps({"seconds": seconds, "operations": [k["operation_count"] for k in kernels],
                  **{key: sum(k[key + "_time"] for k in kernels) / 1000
                     for key in ("codegen", "backend", "execution")}}))
"""


def cold_first_render(scene_file: str | Path, integrator: str, variant: str,
                      defines: dict[str, str]) -> float:
    """Seconds of the first render of ``scene_file`` with ``integrator`` (a
    plugin name, set through the scene's ``integrator`` default, as the
    example scenes declare it) in a fresh process with an empty Dr.Jit
    kernel cache (a new home folder), as a user meets it on a new machine:
    JIT compilation included, scene loading excluded."""
    return cold_first_render_parts(scene_file, integrator, variant, defines)["seconds"]


def cold_first_render_parts(scene_file: str | Path, integrator: str, variant: str,
                            defines: dict[str, str]) -> dict:
    """:func:`cold_first_render` with where its time went: ``seconds`` (the
    render), and over its JIT kernels (Dr.Jit's kernel history) the seconds
    of ``codegen`` (IR assembly), ``backend`` (compilation, LLVM or the CUDA
    driver) and ``execution``, and ``operations`` (IR operations per
    kernel). The rest of ``seconds`` is Python tracing and scene
    preparation."""
    import json
    import os
    import subprocess
    import sys
    import tempfile

    values = {**defines, "integrator": integrator}
    with tempfile.TemporaryDirectory() as home:
        command = [sys.executable, "-c", _COLD_RENDER, variant, str(scene_file),
                   *(f"{key}={value}" for key, value in values.items())]
        result = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "HOME": home})
    if result.returncode != 0:
        raise RuntimeError(f"cold render of {scene_file} failed: {result.stderr.strip()[-500:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def square_side(text: str) -> int:
    """A square benchmark's ``--resolution``: ``N`` or ``NxN`` (an
    ``argparse`` type: a bad value is a usage error naming it)."""
    from ..cli.common import CliError, parse_resolution

    try:
        width, height = parse_resolution(text)
    except CliError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    if width != height:
        raise argparse.ArgumentTypeError(f"the frames are square: give N or NxN, got {text!r}")
    return width
