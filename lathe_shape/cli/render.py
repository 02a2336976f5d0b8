"""``lathe-render``: render a Mitsuba scene with lathes to a linear EXR and an
sRGB PNG preview.

The EXR holds every channel of the film under Mitsuba's names (``R``, ``G``,
``B``, ``A`` for an ``rgba`` film, ``Y`` for a ``luminance`` one or a
``*_mono`` variant, then the integrator's AOVs, e.g. ``albedo.R`` or
``nn.X``); the PNG shows the image itself (gray for one channel), without
the AOVs.

Example::

    lathe-render scenes/brandy_bottle.xml -o out --spp 64 -D integrator=lathe_path

writes ``out/brandy_bottle.exr`` and ``out/brandy_bottle.png``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .common import (
    add_output_option,
    add_render_options,
    check_render_budget,
    check_render_options,
    check_sensor,
    command_parser,
    open_scene,
    output_folder,
    render_film,
    run_command,
    write_staged,
)

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(
        "lathe-render",
        "Render a Mitsuba 3 scene containing lathe shapes to EXR (+ PNG preview), "
        "named after the scene file.",
    )
    add_output_option(parser, default=".", what="SCENE.exr and SCENE.png")
    add_render_options(parser)
    parser.add_argument("--no-png", action="store_true", help="do not write the PNG preview")
    return parser


def render(args: argparse.Namespace) -> int:
    # Imported here so that --help works without touching the JIT backends.
    from ..tools.images import write_images
    from ..tools.scenes import integrator_name, scene_integrator
    from .mesh_note import mesh_note

    check_render_options(args)
    scene = open_scene(args.scene, args.variant, args.defines, args.resolution)
    width, height, spp = check_sensor(scene, args.scene, args.spp)
    check_render_budget(width, height, spp)
    name = os.path.splitext(os.path.basename(args.scene))[0]
    folder = output_folder(args.output)
    stem = os.path.join(folder, name)
    integrator = scene_integrator(scene)
    print(
        f"lathe-render: {args.scene} -> {stem}.exr\n"
        f"  {width}x{height}, {spp} spp, integrator {integrator_name(integrator)}, "
        f"variant {args.variant}, seed {args.seed}",
        flush=True,
    )
    note = mesh_note(scene, integrator)
    if note:
        print(f"  {note}", flush=True)
    start = time.perf_counter()
    image, channels = render_film(scene, spp, args.seed, integrator)
    elapsed = time.perf_counter() - start
    metadata = {
        "spp": int(spp),
        "integrator": integrator_name(integrator),
        "variant": args.variant,
        "seed": int(args.seed),
        "scene": os.path.abspath(args.scene),
        "render_seconds": float(elapsed),
    }
    written = write_staged(folder, [(lambda staged: write_images(staged, image, metadata, png=not args.no_png,
                                                                 channels=channels), name)])
    print(f"  rendered in {elapsed:.2f} s; wrote {', '.join(written)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command("lathe-render", build_parser(), render, argv)


if __name__ == "__main__":
    sys.exit(main())
