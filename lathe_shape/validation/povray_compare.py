"""Rendering one scene with POV-Ray and with ``lathe_whitted`` at the same
resolution, antialiasing and threads, and comparing them (the library side
of ``scripts/compare_povray.py``).

Antialiasing: POV-Ray's non-adaptive supersampling (``+A0.0 +AM1 +R n``,
the threshold 0 supersamples every pixel with an n x n grid) against
``n * n`` samples per pixel in Mitsuba. Threads: POV-Ray's ``+WT`` is set
to every core, as Dr.Jit's LLVM backend uses by default. Times: POV-Ray's
wall time (parsing included, a few milliseconds for these scenes), and
Mitsuba's render after one warm-up render that compiles (or loads) the
kernels.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["POVRAY", "Comparison", "aa_grid", "compare_scene", "render_povray", "render_whitted"]

#: The POV-Ray executable (Debian's ``povray`` package).
POVRAY = "povray"


@dataclass
class Comparison:
    """Both images (linear RGB), their times and the difference."""

    povray: np.ndarray
    whitted: np.ndarray
    povray_seconds: float
    whitted_seconds: float
    errors: dict[str, float]
    #: lathe_whitted's first render, kernel compilation (or cache load) included.
    whitted_first_seconds: float = float("nan")

    @property
    def ratio(self) -> float:
        """lathe_whitted time / POV-Ray time."""
        return self.whitted_seconds / self.povray_seconds

    def summary(self) -> str:
        """The last line the script prints."""
        return (f"povray {self.povray_seconds:.2f} s, lathe_whitted {self.whitted_seconds:.2f} s, "
                f"ratio {self.ratio:.2f}x")


def aa_grid(spp: int) -> int:
    """POV-Ray's ``+R n`` for about ``spp`` samples per pixel (n * n)."""
    return max(1, round(math.sqrt(spp)))


def render_povray(pov_file: str | os.PathLike, size: tuple[int, int], grid: int,
                  threads: int | None = None) -> tuple[np.ndarray, float]:
    """Render ``pov_file`` to an EXR next to it: (linear RGB image, wall seconds)."""
    import mitsuba as mi

    if shutil.which(POVRAY) is None:
        raise FileNotFoundError("povray not found on PATH (Debian: apt-get install povray)")
    pov_file = Path(pov_file)
    output = pov_file.with_suffix(".exr")
    threads = threads or os.cpu_count() or 1
    aa = ["+A0.0", "+AM1", f"+R{grid}"] if grid > 1 else ["-A"]
    # (bare names: it runs in their folder, and POV-Ray splits its options at spaces)
    command = [POVRAY, f"+I{pov_file.name}", f"+O{output.name}", "+FE", f"+W{size[0]}", f"+H{size[1]}",
               *aa, f"+WT{threads}", "-D", "-P", "-V", "-GA"]
    start = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True, cwd=pov_file.parent)
    seconds = time.perf_counter() - start
    if proc.returncode != 0 or not output.is_file():
        raise RuntimeError(f"povray failed on {pov_file} (exit {proc.returncode}): {proc.stderr[-2000:]}")
    image = np.array(mi.Bitmap(str(output)).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float32,
                                                    srgb_gamma=False))
    return image, seconds


def render_whitted(scene, spp: int, seed: int = 0, max_depth: int = 10) -> tuple[np.ndarray, float, float]:
    """Render with ``lathe_whitted`` (``filtered`` shadows, as POV-Ray's):
    (image, seconds of a render after a warm-up render, seconds of the
    warm-up render itself, which compiles or loads the kernels)."""
    import mitsuba as mi

    integrator = mi.load_dict({"type": "lathe_whitted", "max_depth": max_depth, "shadows": "filtered"})
    start = time.perf_counter()
    mi.render(scene, spp=spp, seed=(seed + 1) % 2**32, integrator=integrator).numpy()
    first = time.perf_counter() - start
    start = time.perf_counter()
    image = mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy()
    return image[..., :3], time.perf_counter() - start, first


def compare_scene(scene, folder: str | os.PathLike, spp: int, max_depth: int = 10,
                  seed: int = 0) -> Comparison:
    """Export ``scene`` to ``folder/scene.pov``, render both, compare
    (``max_depth`` is ``lathe_whitted``'s; POV-Ray's ``max_trace_level``
    is one less, at least 1)."""
    from ..tools.images import image_errors
    from ..tools.povray_export import scene_to_pov

    folder = Path(folder)
    pov_file = folder / "scene.pov"
    # lathe_whitted's max_depth counts the segment to the light too (1: only
    # emitters seen directly); POV-Ray's max_trace_level counts traced rays
    # (1: direct light): depth d + 1 is POV-Ray's level d
    pov_file.write_text(scene_to_pov(scene, max_trace_level=max(1, max_depth - 1)), encoding="utf-8")
    grid = aa_grid(spp)
    size = tuple(int(v) for v in scene.sensors()[0].film().size())
    povray, povray_seconds = render_povray(pov_file, size, grid)
    whitted, whitted_seconds, first_seconds = render_whitted(scene, grid * grid, seed, max_depth)
    return Comparison(povray, whitted, povray_seconds, whitted_seconds, image_errors(whitted, povray),
                      first_seconds)
