"""The hollow-glass gradient check: forward-mode AD of one profile coordinate
against central finite differences at two step sizes, on the glass's
interior pixels.

The scene is ``lathe_shape.tools.diff_scenes.glass_scene``: the wine glass
of scenes/wine_glass.csv scaled to 2 units, a clear dielectric (IOR 1.5) in
front of a smooth emissive backdrop, rendered by ``lathe_prb``. Interior
pixels are those whose camera line meets the glass, eroded by two pixels
(no outline pixels; every one crosses four walls). Prints the interior sums
of AD and of each finite difference, the same on the left and right halves
of the image (a glass seen from the side gives a nearly antisymmetric
gradient image, whose whole sum is a small difference of two large ones),
the per-pixel correlation, and the pixels where AD and FD differ most.

    python scripts/hollow_glass_gradient.py [--vertex 30] [--coordinate r|z] [--spp 64]
                                            [--resolution 64] [--steps 0.018 0.036] [--seed 0]
                                            [--variant llvm_ad_rgb]

Vertices count along the profile as the lathe stores it (clockwise); 30
and 32 lie on the outer wall of the bowl. Steps are in profile units (the
profile file's: the glass is 18 of them tall).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from lathe_shape.cli.common import CliError, add_render_options, check_at_least, parse_resolution, run_command

PROG = "hollow_glass_gradient.py"
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--vertex", type=int, default=30, help="profile point to move (default: 30)")
    parser.add_argument("--coordinate", choices=("r", "z"), default="r", help="its coordinate (default: r)")
    parser.add_argument("--steps", type=float, nargs="+", default=[0.018, 0.036],
                        help="finite-difference steps in profile units (default: 0.018 0.036)")
    add_render_options(parser, spp_default=64, resolution_default="64", defines=False,
                       seed_help="seed of the pixel samples, the same for AD and each FD render (default: 0)")
    return parser


def check(args: argparse.Namespace) -> int:
    from lathe_shape.cli.common import select_variant

    check_at_least("--spp", args.spp, 1)
    width, height = parse_resolution(args.resolution)
    if width != height:
        raise CliError(f"--resolution must be square, got {args.resolution!r}")
    check_at_least("--resolution", width, 32)
    if not all(np.isfinite(h) and h > 0.0 for h in args.steps):
        raise CliError(f"--steps must be positive, got {' '.join(f'{h:g}' for h in args.steps)}")
    select_variant(args.variant)
    import mitsuba as mi

    from lathe_shape.tools.diff_scenes import glass_scene
    from lathe_shape.tools.gradients import finite_difference, glass_gradient, points_key

    scene = glass_scene(os.path.join(ROOT, "scenes", "wine_glass.csv"), resolution=width)
    (glass,) = [shape for shape in scene.shapes() if shape.id() == "glass"]
    key = points_key(mi.traverse(scene), glass)
    points = np.array(mi.traverse(scene)[key], dtype=np.float64).reshape(-1, 2)
    if not 0 <= args.vertex < len(points):
        raise CliError(f"--vertex must be in 0..{len(points) - 1} (the profile's points), got {args.vertex}")
    index = 2 * args.vertex + (args.coordinate == "z")
    r, z = points[args.vertex]
    print(f"vertex {args.vertex} at (r, z) = ({r:.3f}, {z:.3f}) profile units, coordinate {args.coordinate}; "
          f"{width}x{width}, {args.spp} spp, seed {args.seed}")

    first = glass_gradient(scene, glass, index, args.steps[0], args.spp, args.seed)
    fds = {args.steps[0]: first.fd}
    for h in args.steps[1:]:
        fds[h] = finite_difference(scene, key, index, h, args.spp, args.seed).sum(axis=2)
    interior = first.interior
    if interior.sum() < 2:
        raise CliError(f"at {width}x{width} the glass has {interior.sum()} interior pixels (its image eroded "
                       "by two pixels): use --resolution 32 or more")
    middle = width // 2
    left = np.zeros_like(interior)
    left[:, :middle] = True

    def sums(image: np.ndarray) -> str:
        return " / ".join(f"{image[interior & part].sum():+9.4g}" for part in (interior, left, ~left))

    print(f"{interior.sum()} interior pixels; sums: whole / left half / right half")
    print(f"  AD           {sums(first.ad)}")
    for h, fd in fds.items():
        a, f = first.ad[interior], fd[interior]
        correlation = f"{np.corrcoef(a, f)[0, 1]:.3f}" if a.std() > 0.0 and f.std() > 0.0 else "undefined"
        print(f"  FD h={h:<7g} {sums(fd)}   per-pixel correlation with AD {correlation}")
    fd = fds[args.steps[0]]
    worst = np.argsort(-np.abs(first.ad - fd)[interior])[:6]
    rows, cols = np.nonzero(interior)
    print(f"pixels where AD and FD (h={args.steps[0]:g}) differ most:")
    for k in worst:
        y, x = rows[k], cols[k]
        others = " / ".join(f"{image[y, x]:.3g}" for image in fds.values())
        print(f"  ({y:3d}, {x:3d})  AD {first.ad[y, x]:9.3g}  FD {others}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(PROG, build_parser(), check, argv)


if __name__ == "__main__":
    sys.exit(main())
