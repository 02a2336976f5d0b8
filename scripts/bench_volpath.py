"""Speed of lathe_volpath (exact lathe in a medium) against Mitsuba's volpath
on the scene's own reference mesh (512 steps), on the green bottle: the
brandy bottle of scenes/brandy_bottle.xml with an absorbing interior medium
(sigma_t 0.05, 0.02, 0.3; albedo 0), and optionally the milky (scattering)
bottle and the filled wine glass.

Times are medians of --repeat interleaved renders (A B A B ...) after a
warm-up render of each (which pays the JIT compilation), with their min-max
spread; the ratio is lathe_volpath's median over volpath's. (docs/media.md's
measurement used --max-depth 16.)

    python scripts/bench_volpath.py [--resolution 256x256] [--spp 16] [--max-depth 8] [--repeat 5]
                                    [--seed 0] [--variant llvm_ad_rgb] [-D KEY=VALUE ...] [--all]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi

from lathe_shape.tools.scenes import load_string_in, set_film_size
from lathe_shape.validation.bench import bench_arguments, interleaved_render_times, median_spread

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"

#: Interior media of the bottle scenes.
MEDIA = {
    "green bottle": '<medium type="homogeneous" name="interior"><rgb name="sigma_t" value="0.05, 0.02, 0.3"/>'
                    '<float name="albedo" value="0"/></medium>',
    "milky bottle": '<medium type="homogeneous" name="interior"><rgb name="sigma_t" value="0.8, 0.8, 0.8"/>'
                    '<float name="albedo" value="0.9"/></medium>',
}


def scene_text(name: str, size: tuple[int, int]) -> str:
    """The scene XML of case ``name`` at ``size``."""
    if name in MEDIA:
        text = (SCENES / "brandy_bottle.xml").read_text()
        tag = '<shape type="lathe" id="brandy_bottle">'
        text = text.replace(tag, tag + MEDIA[name])
    else:
        text = (SCENES / "wine_glass_filled.xml").read_text()
    return set_film_size(text, size)


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0], repeat=5, extra=lambda parser: parser.add_argument(
        "--all", action="store_true", help="also the milky bottle and the filled wine glass"))
    width, height = args.size
    print(f"variant {args.variant}, {width}x{height}, {args.spp} spp, max_depth {args.max_depth}, "
          f"median (min-max) of {args.repeat} interleaved renders")
    names = ["green bottle"] + (["milky bottle", "filled wine glass"] if args.all else [])
    print(f"{'scene':<20}{'volpath, 512-step mesh [s]':>30}{'lathe_volpath [s]':>26}{'ratio':>9}")
    for name in names:
        text = scene_text(name, args.size)
        cases = {}
        for integrator in ("volpath", "lathe_volpath"):
            values = {"spp": str(args.spp), "max_depth": str(args.max_depth), "mesh_segments": "512",
                      "integrator": integrator, **args.define_values}
            scene = load_string_in(SCENES, text, **values)
            cases[integrator] = (scene, scene.integrator())
        times = interleaved_render_times(cases, args.spp, args.repeat, args.seed)

        def timing(values: list[float]) -> str:
            median, low, high = median_spread(values)
            return f"{median:.3f} ({low:.3f}-{high:.3f})"

        ratio = median_spread(times["lathe_volpath"])[0] / median_spread(times["volpath"])[0]
        print(f"{name:<20}{timing(times['volpath']):>30}{timing(times['lathe_volpath']):>26}{ratio:>8.2f}x",
              flush=True)


if __name__ == "__main__":
    mi.set_log_level(mi.LogLevel.Error)
    main()
