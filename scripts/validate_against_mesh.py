"""Exact lathe renders against stock `path` on ever finer reference meshes.

For each scene, renders once with `lathe_path` (normal_check none: the same
estimator and the same random-number use as Mitsuba's `path`, so with one
seed the two renders are correlated) and with stock `path` on the reference
tessellation at increasing `mesh_segments`, and prints the image error, which
must fall toward zero as the mesh converges to the exact surface.

    python scripts/validate_against_mesh.py [--spp 64] [--res 128] [--segments 256 1024 4096]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import mitsuba as mi
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=64)
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--max-depth", type=int, default=8)
    parser.add_argument("--segments", type=int, nargs="+", default=[256, 1024, 4096])
    parser.add_argument("--variant", default="llvm_ad_rgb")
    parser.add_argument("--scenes", nargs="+", default=["wine_glass", "sundae_cup", "brandy_bottle"])
    args = parser.parse_args()
    mi.set_variant(args.variant)
    import lathe_shape  # noqa: F401  (registers the plugins)

    exact_integrator = mi.load_dict(
        {"type": "lathe_path", "max_depth": args.max_depth, "normal_check": "none"})
    print(f"{args.res}x{args.res}, {args.spp} spp, max_depth {args.max_depth}, variant {args.variant}")
    print("relative error = mean |mesh - exact| / mean exact; bias = (mean mesh - mean exact) / mean exact")
    print(f"{'scene':<15}{'mesh_segments':>14}{'rel. error':>12}{'rel. RMSE':>12}{'bias':>10}")
    for name in args.scenes:
        path = str(ROOT / "scenes" / f"{name}.xml")
        defines = {"res": str(args.res), "spp": str(args.spp), "max_depth": str(args.max_depth)}
        exact = None
        for segments in args.segments:
            scene = mi.load_file(path, mesh_segments=str(segments), **defines)
            if exact is None:
                exact = mi.render(scene, seed=11, integrator=exact_integrator).numpy()
            mesh = mi.render(scene, seed=11).numpy()
            scale = exact.mean()
            err = np.abs(mesh - exact).mean() / scale
            rmse = np.sqrt(np.square(mesh - exact).mean()) / scale
            bias = (mesh.mean() - exact.mean()) / scale
            print(f"{name:<15}{segments:>14}{err:>12.4f}{rmse:>12.4f}{bias:>+10.4f}", flush=True)


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"done in {time.perf_counter() - t0:.1f} s")
