"""``lathe-compare``: render a scene exactly (``lathe_path``) and as the
reference mesh (stock ``path``) with the same seed, and show the difference
(``lathe_volpath`` and ``volpath`` for a scene with participating media).

Example::

    lathe-compare scenes/wine_glass.xml -o out/compare --spp 64 --resolution 256x256

(without ``-o``: the folder ``wine_glass_compare`` in the current folder).

Both renders use the same sampler, seed and max_depth, and ``lathe_path``
runs with ``normal_check none`` and without ``caustics``, which draws random
numbers exactly as ``path`` does: the two images' noise is correlated and
the difference shows the geometry (exact surface vs tessellation), not the
noise. The scene's own integrator (``-D integrator``) is not used. Writes
``exact.exr/png``, ``mesh.exr/png`` and ``diff.png`` (signed luminance
difference mesh - exact in a blue-white-red map with a colour bar) and prints
the relative mean absolute error, the relative RMSE and the largest
difference.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

import numpy as np

from .common import (
    CliError,
    add_output_option,
    add_render_options,
    check_at_least,
    command_parser,
    parse_defines,
    run_command,
)

__all__ = ["main", "build_parser", "diverging_map", "difference_image"]

PROG = "lathe-compare"

#: The files written, in the output folder.
FILES = ("exact.exr", "exact.png", "mesh.exr", "mesh.png", "diff.png")


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(
        PROG,
        "Render a scene with exact lathes (lathe_path) and as the reference mesh "
        "(path), same seed, and write both plus a false-colour difference.",
    )
    add_output_option(parser, what=", ".join(FILES), default_help="SCENE_compare in the current folder")
    add_render_options(parser)
    parser.add_argument("--mesh-segments", type=int, metavar="N",
                        help="azimuthal steps of the reference mesh: sets every lathe's mesh_segments "
                             "parameter to N, whatever the scene file says (and -D mesh_segments=N "
                             "where the scene declares or uses $mesh_segments, which reaches included "
                             "files; a literal value in an included file is refused)")
    return parser


def diverging_map(x: np.ndarray) -> np.ndarray:
    """Blue-white-red map of ``x`` in [-1, 1] -> float RGB in [0, 1]
    (linear blend: -1 blue (0.23, 0.30, 0.75), 0 white, +1 red (0.71, 0.02, 0.15))."""
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=np.float64)), -1.0, 1.0)[..., None]
    blue = np.array([0.23, 0.30, 0.75])
    red = np.array([0.71, 0.02, 0.15])
    white = np.ones(3)
    return np.where(x < 0, white + (blue - white) * (-x), white + (red - white) * x)


def _colour(image: np.ndarray) -> np.ndarray:
    """The colour channels of a rendered image: R, G, B of an RGB(A) film,
    Y of a luminance one (``*_mono`` variants), without alpha."""
    return image[..., :3] if image.shape[-1] >= 3 else image[..., :1]


def _luminance(image: np.ndarray) -> np.ndarray:
    colour = _colour(image)
    return colour[..., 0] if colour.shape[-1] == 1 else colour @ np.array([0.2126, 0.7152, 0.0722])


def difference_image(exact: np.ndarray, mesh: np.ndarray, scale: float | None = None,
                     bar: bool = True) -> tuple[np.ndarray, float]:
    """8-bit false-colour image of the luminance difference ``mesh - exact``,
    ``+-scale`` mapping to full red/blue (default: the 99th percentile of
    ``|difference|``), with a colour bar below when ``bar``. Returns
    (uint8 image, scale)."""
    diff = _luminance(mesh) - _luminance(exact)
    if scale is None:
        scale = float(np.percentile(np.abs(diff), 99.0))
    scale = scale if scale > 0 else 1.0
    rgb = diverging_map(diff / scale)
    if bar:
        h, w = diff.shape
        bar_h = max(6, h // 16)
        ramp = np.linspace(-1.0, 1.0, w)[None, :].repeat(bar_h, axis=0)
        rgb = np.concatenate([rgb, np.ones((2, w, 3)), diverging_map(ramp)], axis=0)
        # Ticks at -scale, 0, +scale: dark marks on the bar.
        for x in (0, w // 2, w - 1):
            rgb[h + 2:, x] = 0.0
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), scale


#: ``max_depth`` in an integrator's description: ``max_depth = 16,`` on a
#: line of its own (Mitsuba's integrators), ``[max_depth=16, ...`` (ours).
_MAX_DEPTH = re.compile(r"(?<!\w)max_depth\s*=\s*(-?\d+)")


def _printed_max_depth(integrator) -> int | None:
    """``max_depth`` from the integrator's description, if it says."""
    match = _MAX_DEPTH.search(str(integrator))
    return int(match.group(1)) if match else None


def _integrator_max_depth(integrator) -> int | None:
    """``max_depth`` of ``integrator``: its attribute (the package's Python
    integrators), its parameter (``mi.traverse``), else its description."""
    import mitsuba as mi

    depth = getattr(integrator, "max_depth", None)
    if isinstance(depth, int) and not isinstance(depth, bool):
        return depth
    params = mi.traverse(integrator)
    return int(params["max_depth"]) if "max_depth" in params else _printed_max_depth(integrator)


def _scene_max_depth(scene) -> int | None:
    """max_depth of the scene's integrator, if it has one (-1: no limit)."""
    integrator = scene.integrator()
    if integrator is None:
        return None
    depth = _integrator_max_depth(integrator)
    # Mitsuba keeps max_depth as a 32-bit unsigned integer: the -1 (no limit)
    # of the scene file reads back as 4294967295. Print it as the file says.
    return -1 if depth is not None and depth >= 2**31 else depth


def open_comparison(args: argparse.Namespace) -> tuple[object, int, str, int]:
    """Check the options, load the scene (which must have a sensor and a
    lathe, and fit the limits of :func:`~.common.check_render_budget`) and
    create the output folder; returns (scene, number of lathes, folder,
    spp)."""
    from .common import check_render_budget, check_render_options, check_sensor, open_scene, output_folder

    check_render_options(args)
    check_at_least("--mesh-segments", args.mesh_segments, 3)
    extra, edit = {}, None
    if args.mesh_segments is not None:
        if _uses_mesh_segments(args.scene):  # (Mitsuba refuses a define that nothing uses)
            extra = {"mesh_segments": str(args.mesh_segments)}

        def edit(xml_text: str, path: str) -> str:
            from ..tools.scenes import set_mesh_segments

            return set_mesh_segments(xml_text, args.mesh_segments, path)
    scene = open_scene(args.scene, args.variant, args.defines, args.resolution, extra, edit)
    from ..plugin.shape import scene_lathes  # (needs the variant open_scene selected)

    width, height, spp = check_sensor(scene, args.scene, args.spp)
    lathes = len(scene_lathes(scene))
    if not lathes:
        raise CliError(f"{args.scene}: the scene has no lathe shape to compare")
    if args.mesh_segments is not None:
        _check_mesh_segments(args.scene, scene_lathes(scene), args.mesh_segments)
    check_render_budget(width, height, spp)
    stem = os.path.splitext(os.path.basename(args.scene))[0]
    return scene, lathes, output_folder(args.output or f"{stem}_compare"), spp


def _uses_mesh_segments(scene_file: str, depth: int = 0) -> bool:
    """Whether the scene file or a file it includes uses ``$mesh_segments``."""
    from ..tools.scenes import blank_comments, read_scene_text

    text = blank_comments(read_scene_text(scene_file).encode("utf-8")).decode("utf-8")
    if re.search(r"\$mesh_segments(?!\w)", text):
        return True
    folder = os.path.dirname(os.path.abspath(scene_file))
    included = re.findall(r"<include\s+filename=[\"']([^\"']+)[\"']", text)
    return depth < 8 and any(
        _uses_mesh_segments(os.path.join(folder, name), depth + 1)
        for name in included if os.path.isfile(os.path.join(folder, name)))


def _check_mesh_segments(scene_file: str, lathes: list, steps: int) -> None:
    """Refuse a comparison whose lathes did not all get ``--mesh-segments``
    (a literal value in an included file is out of the edit's reach)."""
    for lathe in lathes:
        if lathe.reference == "mesh" and lathe.mesh_segments != steps:
            name = f"lathe '{lathe.id()}'" if lathe.id() else "a lathe"
            raise CliError(
                f"{scene_file}: --mesh-segments {steps}: {name} keeps mesh_segments "
                f"{lathe.mesh_segments} (set in an included file?); --mesh-segments sets the lathes "
                "of the scene file itself, and those of included files through $mesh_segments"
            )


#: The two renders: name -> integrator (``max_depth`` added from the scene).
#: ``caustics`` off: its light-traced paths are drawn apart from the camera
#: samples, so the difference would show their noise, not the mesh's error
#: (at 512 segments 35x the error measured without them).
RUNS = {"exact": {"type": "lathe_path", "normal_check": "none", "caustics": False}, "mesh": {"type": "path"}}

#: The same for scenes with participating media.
MEDIA_RUNS = {"exact": {"type": "lathe_volpath", "caustics": False}, "mesh": {"type": "volpath"}}


def comparison_runs(scene) -> dict[str, dict]:
    """:data:`RUNS`, or :data:`MEDIA_RUNS` when a shape of ``scene`` bounds
    a medium or the sensor sits in one."""
    media = any(shape.interior_medium() is not None or shape.exterior_medium() is not None
                for shape in scene.shapes())
    return MEDIA_RUNS if media or scene.sensors()[0].get_medium() is not None else RUNS


def render_both(args: argparse.Namespace, scene, spp: int, depth: int,
                runs: dict[str, dict]) -> dict[str, tuple[np.ndarray, float, list[str]]]:
    """Render ``exact`` (lathe_path, normal_check none, or lathe_volpath)
    and ``mesh`` (path, or volpath) as ``runs`` (:func:`comparison_runs`)
    says, with the same seed; returns name -> (image, seconds, channel
    names)."""
    import mitsuba as mi

    from .common import render_film

    images = {}
    for name, integrator in runs.items():
        start = time.perf_counter()
        image, channels = render_film(scene, spp, args.seed, mi.load_dict({**integrator, "max_depth": depth}))
        images[name] = image, time.perf_counter() - start, channels
        print(f"  {name:<5} ({runs[name]['type']}) rendered in {images[name][1]:.2f} s", flush=True)
    return images


def write_comparison(args: argparse.Namespace, out: str, spp: int,
                     images: dict[str, tuple[np.ndarray, float, list[str]]],
                     runs: dict[str, dict] = RUNS) -> float:
    """Write ``exact`` and ``mesh`` (EXR + PNG) and ``diff.png`` in a staging
    folder, and move the five files into ``out`` at once when all are
    complete (:func:`~.common.write_staged`); returns the difference's
    scale."""
    import mitsuba as mi

    from ..tools.images import write_images
    from .common import write_staged

    def image_writer(name: str):
        image, seconds, channels = images[name]
        metadata = {"spp": int(spp), "integrator": runs[name]["type"], "seed": int(args.seed),
                    "variant": args.variant, "scene": os.path.abspath(args.scene),
                    "render_seconds": float(seconds)}
        return lambda stem: write_images(stem, image, metadata, channels=channels)

    diff_png, scale = difference_image(images["exact"][0], images["mesh"][0])

    def write_diff(stem: str) -> list[str]:
        mi.Bitmap(diff_png, pixel_format=mi.Bitmap.PixelFormat.RGB).write(stem + ".png")
        return [stem + ".png"]

    write_staged(out, [*((image_writer(name), name) for name in images), (write_diff, "diff")])
    return scale


def compare(args: argparse.Namespace) -> int:
    from ..tools.images import image_errors

    scene, lathes, out, spp = open_comparison(args)
    width, height = scene.sensors()[0].film().size()
    depth = _scene_max_depth(scene)
    depth = -1 if depth is None else depth
    print(
        f"{PROG}: {args.scene} -> {out}\n"
        f"  {width}x{height}, {spp} spp, max_depth {depth}, seed {args.seed}, variant {args.variant}, "
        f"{lathes} lathe(s)",
        flush=True,
    )
    runs = comparison_runs(scene)
    if "integrator" in parse_defines(args.defines):
        print(f"  note: -D integrator is not used: {PROG} renders {runs['exact']['type']} against "
              f"{runs['mesh']['type']}", flush=True)
    if runs is MEDIA_RUNS:
        print("  note: the scene has media: lathe_volpath and volpath draw their samples apart, so the "
              "difference holds their noise too (render both at more spp to see the mesh's error)",
              flush=True)
    images = render_both(args, scene, spp, depth, runs)
    scale = write_comparison(args, out, spp, images, runs)
    err = image_errors(_colour(images["mesh"][0]), _colour(images["exact"][0]))
    print(f"  mesh vs exact: relative mean abs error {err['rel_mae']:.4f}, relative RMSE "
          f"{err['rel_rmse']:.4f}, max abs difference {err['max_abs']:.4f}, bias {err['bias']:+.4f}")
    print(f"  diff.png: luminance mesh - exact, blue -{scale:.3g} .. white 0 .. red +{scale:.3g} "
          f"(colour bar below the image)")
    print(f"  wrote {', '.join(os.path.join(out, f) for f in FILES)}")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(PROG, build_parser(), compare, argv)


if __name__ == "__main__":
    sys.exit(main())
