"""Speed of the exact polyline lathe against the mesh a user would render,
as ratios measured in one run.

1. Per scene and max_depth: `lathe_path` (exact) against stock `path` on the
   reference mesh at the scene's own `mesh_segments` (512), and against the
   coarsest mesh whose render agrees with the exact one within noise on the
   glass pixels (found first, see `validation.bench.coarsest_agreeing_mesh`).
2. `lathe_path` on goblet profiles of 31 ... 1000 segments in one scene.
3. The first render in a fresh process with an empty kernel cache (JIT
   compilation included), `path` on the mesh against `lathe_path`:
   --repeat interleaved processes each, with the median split of the time
   into IR assembly (codegen), compilation (backend) and execution.

Times are medians of --repeat interleaved renders (A B C A B C ...) after a
warm-up render of each case, with their min-max spread. `lathe_path` runs
with `caustics` false, as stock `path` has no light-traced caustic paths:
the ratios compare the intersections; what the caustic paths cost and gain
is `scripts/bench_caustics.py`'s.

    python scripts/bench_polyline.py [--resolution 256x256] [--spp 16] [--max-depth 8 16] [--repeat 5]
                                     [--seed 0] [--variant llvm_ad_rgb] [-D KEY=VALUE ...] [--no-cold]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from lathe_shape.validation.bench import (
    bench_arguments,
    bench_scene,
    coarsest_agreeing_mesh,
    cold_first_render_parts,
    interleaved_render_times,
    median_spread,
)

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


SCENES = ("wine_glass", "sundae_cup", "brandy_bottle")


def timing(times: list[float]) -> str:
    median, low, high = median_spread(times)
    return f"{median:.3f} ({low:.3f}-{high:.3f})"


def exact_against_meshes(args, name: str, max_depth: int) -> None:
    """Section 1 for one scene and depth."""
    from lathe_shape.plugin.shape import scene_lathes

    scene_file = ROOT / "scenes" / f"{name}.xml"
    depth = {"max_depth": str(max_depth)}
    scene = bench_scene(args, scene_file, **depth)  # the scene's own mesh_segments
    coarse, error, noise = coarsest_agreeing_mesh(
        lambda n: bench_scene(args, scene_file, mesh_segments=str(n), **depth), scene, max_depth,
        args.spp, args.seed)
    cases = {
        "default": (scene, mi.load_dict({"type": "path", "max_depth": max_depth})),
        "exact": (scene, mi.load_dict({"type": "lathe_path", "max_depth": max_depth, "caustics": False})),
    }
    if coarse is not None:
        coarse_scene = bench_scene(args, scene_file, mesh_segments=str(coarse), **depth)
        cases["coarse"] = (coarse_scene, cases["default"][1])
    times = interleaved_render_times(cases, args.spp, args.repeat, args.seed)
    exact = median_spread(times["exact"])[0]
    row = (f"{name:<14}{max_depth:>6}{scene_lathes(scene)[0].mesh_segments:>7}{timing(times['default']):>24}"
           f"{timing(times['exact']):>24}{exact / median_spread(times['default'])[0]:>8.2f}x")
    if coarse is None:
        row += f"{'none agrees':>14}"
    else:
        row += f"{coarse:>6} ({error:.4f}<{noise:.4f}){timing(times['coarse']):>24}"
        row += f"{exact / median_spread(times['coarse'])[0]:>8.2f}x"
    print(row, flush=True)


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0], repeat=5, depths=(8, 16), extra=lambda parser: (
        parser.add_argument("--no-cold", action="store_true", help="skip the cold-cache first renders")))
    width, height = args.size
    print(f"variant {args.variant}, {width}x{height}, {args.spp} spp, median (min-max) of {args.repeat} "
          "interleaved renders")

    print("\n1) exact lathe vs stock path on the scene's mesh and on the coarsest mesh within noise")
    print(f"{'scene':<14}{'depth':>6}{'mesh':>7}{'path, scene mesh [s]':>24}{'lathe_path [s]':>24}"
          f"{'ratio':>9}{'coarsest (err<noise)':>24}{'path, coarsest [s]':>20}{'ratio':>9}")
    for max_depth in args.max_depths:
        for name in SCENES:
            exact_against_meshes(args, name, max_depth)

    print("\n2) exact lathe: segment count scaling (goblet in the wine_glass scene)")
    cases = {}
    for segments in (31, 86, 300, 1000):
        scene = bench_scene(args, ROOT / "scenes" / "wine_glass.xml", goblet_profile(segments),
                            mesh_segments="64", max_depth=str(args.max_depths[0]))
        cases[segments] = (scene, mi.load_dict({"type": "lathe_path", "max_depth": args.max_depths[0],
                                                "caustics": False}))
    times = interleaved_render_times(cases, args.spp, args.repeat, args.seed)
    base = median_spread(times[31])[0]
    print(f"{'segments':>9}{'lathe_path [s]':>24}{'vs 31':>9}")
    for segments, values in times.items():
        print(f"{segments:>9}{timing(values):>24}{median_spread(values)[0] / base:>8.2f}x", flush=True)

    if args.no_cold:
        return
    print("\n3) first render from an empty kernel cache (fresh process, brandy bottle)")
    defines = {"res": str(width), "spp": str(args.spp), "max_depth": str(args.max_depths[0])}
    scene_file = ROOT / "scenes" / "brandy_bottle.xml"
    parts = {"path": [], "lathe_path": []}
    for _ in range(args.repeat):  # interleaved, as the warm renders
        for name, runs in parts.items():
            runs.append(cold_first_render_parts(scene_file, name, args.variant, defines))
    for name, runs in parts.items():
        split = ", ".join(f"{key} {np.median([run[key] for run in runs]) * 1e3:.0f} ms"
                          for key in ("codegen", "backend", "execution"))
        ops = int(np.median([sum(run["operations"]) for run in runs]))
        print(f"{name:<12}{timing([run['seconds'] for run in runs]):>24}   ({split}; {ops} IR operations)")
    ratio = (median_spread([run["seconds"] for run in parts["lathe_path"]])[0]
             / median_spread([run["seconds"] for run in parts["path"]])[0])
    print(f"lathe_path / path: {ratio:.2f}x")


if __name__ == "__main__":
    main()
