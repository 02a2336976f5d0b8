"""Speed of the exact polyline lathe, as ratios measured in one run.

1. `lathe_path` (exact) against stock `path` on the reference mesh
   (mesh_segments 2048), same scene, spp and max_depth: target <= 1.0x.
2. `lathe_path` on a 300-segment profile against a 31-segment profile of the
   same goblet in the same scene: target <= 1.3x.

Each time is the best of --repeat renders after one warm-up render (which
pays the JIT compilation).

    python scripts/bench_polyline.py [--resolution 256x256] [--spp 16] [--max-depth 8] [--repeat 3]
                                     [--seed 0] [--variant llvm_ad_rgb] [-D KEY=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from lathe_shape.tools.bench import bench_arguments, bench_scene, best_render_time

ROOT = Path(__file__).resolve().parents[1]


def goblet_profile(segments: int) -> np.ndarray:
    """A goblet of about 18 x 8 with a 0.25 wall whose profile has exactly
    ``segments`` segments (both ends on the axis)."""
    height, wall, base = 18.0, 0.25, 6.0
    n_out = (segments - 2) // 2
    n_in = segments - 2 - n_out

    def radius(z: np.ndarray) -> np.ndarray:
        stem = 0.35 + 3.3 * np.exp(-np.square(z / 0.6))              # foot flaring into the stem
        x = np.clip((z - base) / (height - base), 0, 1)          # 0 at the bowl bottom, 1 at the rim
        bowl = 3.8 * np.sqrt(x) * (1.0 - 0.12 * x**2)
        return np.maximum(stem, bowl)

    z_out = np.linspace(0.0, height, n_out + 1)
    outer = np.stack([radius(z_out), z_out], axis=1)
    z_in = np.linspace(height, base + 0.6, n_in)
    inner = np.stack([np.maximum(radius(z_in) - wall, 0.05), z_in], axis=1)
    return np.vstack([[[0.0, 0.0]], outer, inner, [[0.0, base + 0.6]]])


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0])
    from lathe_shape.plugin.shape import scene_lathes

    width, height = args.size
    path_int = mi.load_dict({"type": "path", "max_depth": args.max_depth})
    exact_int = mi.load_dict({"type": "lathe_path", "max_depth": args.max_depth})
    print(f"variant {args.variant}, {width}x{height}, {args.spp} spp, max_depth {args.max_depth}, "
          f"best of {args.repeat}")

    print("\n1) exact lathe vs reference mesh (mesh_segments 2048)")
    print(f"{'scene':<15}{'segments':>9}{'mesh path [s]':>15}{'lathe_path [s]':>16}{'exact/mesh':>12}")
    for name in ("wine_glass", "sundae_cup", "brandy_bottle"):
        scene = bench_scene(args, ROOT / "scenes" / f"{name}.xml", mesh_segments="2048")
        lathe = scene_lathes(scene)[0]
        t_mesh, _ = best_render_time(scene, path_int, args.spp, args.repeat, args.seed)
        t_exact, _ = best_render_time(scene, exact_int, args.spp, args.repeat, args.seed)
        print(f"{name:<15}{lathe.profile.segment_count:>9}{t_mesh:>15.3f}{t_exact:>16.3f}"
              f"{t_exact / t_mesh:>11.2f}x", flush=True)

    print("\n2) exact lathe: segment count scaling (goblet in the wine_glass scene)")
    print(f"{'segments':>9}{'lathe_path [s]':>16}{'vs 31':>9}")
    base = None
    for segments in (31, 86, 300, 1000):
        scene = bench_scene(args, ROOT / "scenes" / "wine_glass.xml", goblet_profile(segments),
                            mesh_segments="64")
        t_exact, _ = best_render_time(scene, exact_int, args.spp, args.repeat, args.seed)
        base = base or t_exact
        print(f"{segments:>9}{t_exact:>16.3f}{t_exact / base:>8.2f}x", flush=True)


if __name__ == "__main__":
    main()
