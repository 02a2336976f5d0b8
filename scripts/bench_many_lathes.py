"""Scenes of many lathes: load time, peak memory and exact render time
against the lathe count, with the full reference mesh and with the proxy.

A grid of wine glasses (scenes/wine_glass.csv, mesh_segments 512) on a floor
under a constant sky, rendered with ``lathe_path``. Every case runs in a
fresh process, so its peak memory (ru_maxrss) is its own; the render time is
the median of the renders after the first (which pays the JIT compilation:
its time less the median is printed as the compile time), with their
spread, and the median CPU time of the process per render (all its threads:
steadier than the wall time when other jobs share the cores; the ratios use
it). A last line per reference and integrator gives the render-time
ratio of the largest count to 256 lathes (the target of scenes of many
lathes: at most 1.2 for ``lathe_path``); ``--integrators lathe_path path``
adds Mitsuba's stock ``path`` on the same scenes (it traces the proxies).
Scenes load through `tools.scenes.load_string_in`, which loads them
sequentially (see `tools.scenes.PARALLEL_LOAD`).

    python scripts/bench_many_lathes.py [--counts 1 64 256 1000] [--references mesh proxy] [--buried]
                                        [--integrators lathe_path path]
                                        [--resolution 128x128] [--spp 4] [--repeats 3]
                                        [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "scenes" / "wine_glass.csv"


def glass_text(i: int, reference: str, buried: bool, shared: bool = True) -> str:
    """Glass ``i`` of the grid: 32 to a row, 12 units apart; ``buried``: 8
    rows, and the glasses after the 256th 100 units under the floor;
    ``shared``: the glass material is one BSDF referenced by every glass
    (else each glass has its own)."""
    bsdf = '<ref id="glass"/>' if shared else '<bsdf type="dielectric"/>'

    x, row = (i % 32) * 12 - 186, i // 32
    y, z = (row % 8 * 12, -100 * (i // 256)) if buried else (row * 12, 0)
    return (f'<shape type="lathe" id="glass_{i}"><string name="filename" value="{PROFILE}"/>'
            f'<string name="reference" value="{reference}"/><integer name="mesh_segments" value="512"/>'
            f'<transform name="to_world"><translate x="{x}" y="{y}" z="{z}"/></transform>'
            f'{bsdf}</shape>')


def scene_text(count: int, reference: str, width: int, height: int, buried: bool = False,
               shared: bool = True) -> str:
    """A grid of ``count`` glasses (:func:`glass_text`; ``buried``: the image
    of 256 glasses at the cost of ``count`` lathes) on a floor."""
    glasses = "\n".join(glass_text(i, reference, buried, shared) for i in range(count))
    return f"""<scene version="3.0.0">
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,-80,90" target="0,60,0" up="0,0,1"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="{width}"/><integer name="height" value="{height}"/>
        </film>
    </sensor>
    <bsdf type="dielectric" id="glass"/>
    <emitter type="constant"/>
    <shape type="rectangle"><transform name="to_world"><scale value="400"/></transform></shape>
    {glasses}
</scene>"""


def measure(count: int, reference: str, size: tuple[int, int], spp: int, variant: str,
            repeats: int, buried: bool = False, shared: bool = True, integrator: str = "lathe_path") -> dict:
    """One case, in this process: load time, first render time, median and
    spread of ``repeats`` further renders with ``integrator`` (max_depth 6),
    peak RSS."""
    import resource

    import mitsuba as mi

    from lathe_shape.cli.common import select_variant
    from lathe_shape.tools.scenes import load_string_in

    select_variant(variant)
    start = time.perf_counter()
    scene = load_string_in(ROOT, scene_text(count, reference, *size, buried, shared))
    load = time.perf_counter() - start
    renderer = mi.load_dict({"type": integrator, "max_depth": 6})
    times, cpu = [], []
    for seed in range(1 + repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        mi.render(scene, spp=spp, seed=seed, integrator=renderer).numpy()
        times.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    later = sorted(times[1:])
    return {"load": load, "first": times[0], "render": float(statistics.median(later)),
            "spread": (later[0], later[-1]), "cpu": float(statistics.median(cpu[1:])), "peak_mb": peak}


def main() -> None:
    from lathe_shape.cli.common import add_render_options, parse_resolution

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 64, 256, 1000],
                        help="lathe counts to measure (default: 1 64 256 1000)")
    parser.add_argument("--references", nargs="+", default=["mesh", "proxy"], choices=["mesh", "proxy"],
                        help="the lathes' stand-ins in Mitsuba's scene (default: mesh proxy)")
    add_render_options(parser, spp_default=4, resolution_default="128x128", defines=False)
    parser.add_argument("--integrators", nargs="+", default=["lathe_path"], choices=["lathe_path", "path"],
                        help="integrators to time (default: lathe_path; path: Mitsuba's own, on the proxies)")
    parser.add_argument("--repeats", type=int, default=3, help="renders timed after the first (default: 3)")
    parser.add_argument("--buried", action="store_true",
                        help="glasses after the 256th under the floor: the image of 256, the cost of more")
    parser.add_argument("--own-bsdfs", action="store_true",
                        help="one dielectric BSDF per glass instead of one shared material (a <ref>): "
                             "Mitsuba's BSDF calls then dispatch over every instance")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # internal: run one case, print JSON
    args = parser.parse_args()
    size = parse_resolution(args.resolution)
    if args.case:
        count, reference, integrator = args.case.split(":")
        print(json.dumps(measure(int(count), reference, size, args.spp, args.variant, args.repeats,
                                 args.buried, not args.own_bsdfs, integrator)))
        return
    print(f"variant {args.variant}, {size[0]}x{size[1]}, {args.spp} spp, max_depth 6, "
          f"one process per case{', glasses after the 256th buried' if args.buried else ''}, "
          f"{'a BSDF per glass' if args.own_bsdfs else 'one shared glass BSDF'}")
    print(f"{'integrator':>11}{'lathes':>7}{'reference':>10}{'load [s]':>10}{'peak [MB]':>11}"
          f"{'compile [s]':>13}{'render [s]':>12}{'(min-max)':>14}{'cpu [s]':>9}{'vs 256':>8}")
    for reference in args.references:
        for integrator in args.integrators:
            run_series(args, reference, integrator)


def run_series(args: argparse.Namespace, reference: str, integrator: str) -> None:
    """Print one line per lathe count (each in a fresh process) and the
    ratio of the largest count to 256."""
    renders = {}
    for count in args.counts:
        command = [sys.executable, __file__, "--case", f"{count}:{reference}:{integrator}", "--resolution",
                   args.resolution, "--spp", str(args.spp), "--repeats", str(args.repeats),
                   "--variant", args.variant] + (["--buried"] if args.buried else []) \
            + (["--own-bsdfs"] if args.own_bsdfs else [])
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            error = result.stderr.strip().splitlines()[-1:]
            print(f"{integrator:>11}{count:>7}{reference:>10}  failed: {error}")
            continue
        r = json.loads(result.stdout.strip().splitlines()[-1])
        renders[count] = r["cpu"]
        ratio = f"{r['cpu'] / renders[256]:7.2f}x" if 256 in renders else "      -"
        spread = f"({r['spread'][0]:.2f}-{r['spread'][1]:.2f})"
        print(f"{integrator:>11}{count:>7}{reference:>10}{r['load']:>10.2f}{r['peak_mb']:>11.0f}"
              f"{r['first'] - r['render']:>13.2f}{r['render']:>12.3f}{spread:>14}{r['cpu']:>9.3f}{ratio:>8}",
              flush=True)
    largest = max(renders, default=None)
    if 256 in renders and largest != 256:
        print(f"{integrator} {reference}: render CPU time {largest} / 256 lathes = "
              f"{renders[largest] / renders[256]:.2f}x (target for lathe_path: at most 1.2x)")


if __name__ == "__main__":
    main()
