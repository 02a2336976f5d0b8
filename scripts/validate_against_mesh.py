"""Exact lathe renders against stock `path` on ever finer reference meshes.

For each scene, renders once with `lathe_path` (normal_check none, caustics
off: the same estimator and the same random-number use as Mitsuba's `path`,
so with one seed the two renders are correlated) and with stock `path` on the reference
tessellation at increasing `mesh_segments`, and prints the image error
(`lathe_shape.tools.images.image_errors`), which must fall toward zero as the
mesh converges to the exact surface.

    python scripts/validate_against_mesh.py [--spp 64] [--resolution 128x128] [--max-depth 8] [--seed 11]
        [--segments 256 1024 4096] [--scenes wine_glass sundae_cup brandy_bottle] [--variant llvm_ad_rgb]
        [-D KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lathe_shape.cli.common import (
    add_render_options,
    check_at_least,
    open_scene,
    parse_resolution,
    run_command,
)

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="validate_against_mesh.py", description=__doc__.splitlines()[0])
    add_render_options(parser, spp_default=64, resolution_default="128x128", seed_default=11,
                       seed_help="sampler seed of every render (default: 11)")
    parser.add_argument("--max-depth", type=int, default=8,
                        help="path depth of both integrators (default: 8)")
    parser.add_argument("--segments", type=int, nargs="+", default=[256, 1024, 4096], metavar="N",
                        help="mesh_segments of the reference meshes (default: 256 1024 4096)")
    parser.add_argument("--scenes", nargs="+", default=["wine_glass", "sundae_cup", "brandy_bottle"],
                        metavar="SCENE", help="scene names in scenes/, or XML files "
                        "(default: wine_glass sundae_cup brandy_bottle)")
    return parser


def validate(args: argparse.Namespace) -> int:
    check_at_least("--spp", args.spp, 1)
    for segments in args.segments:
        check_at_least("--segments", segments, 3)
    import mitsuba as mi

    from lathe_shape.tools.images import image_errors

    def load(scene: str, segments: int) -> mi.Scene:
        path = scene if scene.endswith(".xml") else SCENES / f"{scene}.xml"
        values = {"mesh_segments": str(segments), "spp": str(args.spp), "max_depth": str(args.max_depth)}
        return open_scene(path, args.variant, args.defines, args.resolution, values)

    start = time.perf_counter()
    width, height = parse_resolution(args.resolution)
    print(f"{width}x{height}, {args.spp} spp, max_depth {args.max_depth}, variant {args.variant}")
    print("relative error = mean |mesh - exact| / mean exact; bias = (mean mesh - mean exact) / mean exact")
    print(f"{'scene':<15}{'mesh_segments':>14}{'rel. error':>12}{'rel. RMSE':>12}{'bias':>10}")
    exact_integrator = exact = None
    for name in args.scenes:
        for k, segments in enumerate(args.segments):
            scene = load(name, segments)
            if k == 0:  # the exact surface does not depend on mesh_segments
                exact_integrator = exact_integrator or mi.load_dict(
                    {"type": "lathe_path", "max_depth": args.max_depth, "normal_check": "none",
                     "caustics": False})  # (paired samples: see the module docstring)
                exact = mi.render(scene, spp=args.spp, seed=args.seed, integrator=exact_integrator).numpy()
            mesh_integrator = mi.load_dict({"type": "path", "max_depth": args.max_depth})
            mesh = mi.render(scene, spp=args.spp, seed=args.seed, integrator=mesh_integrator).numpy()
            err = image_errors(mesh, exact)
            print(f"{Path(name).stem:<15}{segments:>14}{err['rel_mae']:>12.4f}{err['rel_rmse']:>12.4f}"
                  f"{err['bias']:>+10.4f}", flush=True)
    print(f"done in {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(run_command("validate_against_mesh.py", build_parser(), validate))
