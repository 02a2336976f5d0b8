"""White-furnace energy table for the `normal_check` policies (eq. 11).

A dielectric glass lathe under a uniform white environment: with nothing lost
every pixel is 1.0. Prints, per policy, the mean over the glass (energy loss =
1 - mean), the pixel standard deviation and the share of speckles (pixels off
by more than 20 %); then the same for stock `path` on the reference mesh and
for the exact lathe with flat normals.

    python scripts/furnace.py [--spp 256] [--resolution 128x128] [--seed 0] [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import argparse
import sys

from lathe_shape.cli.common import (
    add_render_options,
    check_at_least,
    parse_resolution,
    run_command,
    select_variant,
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="furnace.py", description=__doc__.splitlines()[0])
    add_render_options(parser, spp_default=256, resolution_default="128x128", defines=False)
    return parser


def furnace(args: argparse.Namespace) -> int:
    check_at_least("--spp", args.spp, 1)
    width, height = parse_resolution(args.resolution)
    select_variant(args.variant)
    from lathe_shape.validation.furnace import furnace_table

    print(f"furnace: {width}x{height}, {args.spp} spp, max_depth -1, dielectric int_ior 1.5")
    print(f"{'normal_check':<14}{'mean':>10}{'energy loss':>13}{'std':>10}{'speckles':>10}")
    for label, r in furnace_table((width, height), args.spp, args.seed):
        print(f"{label:<14}{r.mean:>10.4f}{r.loss:>+13.4f}{r.std:>10.4f}{r.speckle:>10.2%}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(run_command("furnace.py", build_parser(), furnace))
