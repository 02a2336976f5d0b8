"""Helpers of the benchmark scripts: best-of-N render timing and scenes whose
lathe profile is replaced inline."""

from __future__ import annotations

import time
from pathlib import Path

import mitsuba as mi
import numpy as np

from .scenes import load_string_in, replace_profile

__all__ = ["bench_arguments", "best_render_time", "load_with_profile"]


def bench_arguments(description: str):
    """The benchmark scripts' shared options, parsed; selects the variant."""
    import argparse

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--res", type=int, default=256)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    args = parser.parse_args()
    mi.set_variant(args.variant)
    return args


def load_with_profile(scene_file: str | Path, points: np.ndarray, kind: str = "polyline",
                      **defines: str) -> mi.Scene:
    """Load a scene whose lathe's profile is replaced by the inline profile
    ``points`` of the given ``kind``."""
    scene_file = Path(scene_file)
    text = replace_profile(scene_file.read_text(), points=points, kind=kind, source=str(scene_file))
    return load_string_in(scene_file.parent, text, **defines)


def best_render_time(scene: mi.Scene, integrator: mi.Integrator, spp: int,
                     repeat: int) -> tuple[float, np.ndarray]:
    """Best wall time of ``repeat`` renders after a warm-up render (which
    pays the JIT compilation), and the last image."""
    image = mi.render(scene, spp=spp, seed=0, integrator=integrator).numpy()
    times = []
    for k in range(repeat):
        start = time.perf_counter()
        image = mi.render(scene, spp=spp, seed=k + 1, integrator=integrator).numpy()
        times.append(time.perf_counter() - start)
    return min(times), image
