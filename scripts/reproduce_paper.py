#!/usr/bin/env python3
"""Reproduce the paper's figures 8a, 8b, 9, 10a and 10b (method.md, "The
paper's results") and measure them.

    python scripts/reproduce_paper.py                   # 512x512, 64 spp (the scenes' defaults)
    python scripts/reproduce_paper.py --quick           # 48x48, 4 spp: a CI smoke run (< 60 s)
    python scripts/reproduce_paper.py --out out/paper --res 256 --spp 32
    python scripts/reproduce_paper.py --make            # regenerate scenes/paper/ (profiles + XML)

For every figure it renders the scene in ``scenes/paper/`` with the exact
``lathe_path`` integrator (``normal_check none``, the scene's max_depth),
times it (after one warm-up render that compiles the kernels), and compares
it with an exact, higher-spp reference of the *same object*:

* figs. 8a, 8b: the exact 12-segment cubic B-spline glass (fig. 8b's curve)
  rendered with ``--ref-spp`` samples (the row for 8b is then the noise
  floor: same geometry, fewer samples);
* figs. 9, 10a, 10b (arc-built polylines): the same arcs divided at 0.5
  degree steps (thousands of segments, i.e. the exact arcs to within 1e-5 of
  their radius), rendered with ``--ref-spp`` samples.

It prints a table (figure, method, segments, time, spline/polyline time
ratio, relative mean absolute error and RMSE against the reference) and
writes ``figNN.exr/png``, the references and ``sheet_fig8a_8b_9.png`` (8a, 8b
and 9 side by side, full and a 3x zoom on the bowl, where the careless
polyline distorts the checkered floor) into ``--out``.

The profiles: fig. 8b's glass is a hand-placed open B-spline (11 control
points, 12 segments); fig. 8a samples it uniformly in the spline parameter
(32 points, 31 segments, no care); fig. 9 is a wine glass built with
:mod:`lathe_shape.profiles.arcs` (arcs divided equally, concentric inner wall,
42 segments), 10a a sundae cup (58) and 10b a brandy bottle (86), built the
same way. ``--make`` rewrites them (deterministic).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenes" / "paper"
sys.path.insert(0, str(ROOT))

# ---------------------------------------------------------------------------
# The objects
# ---------------------------------------------------------------------------

#: Fig. 8b: open uniform cubic B-spline, 11 control points -> 12 segments
#: (both ends on the axis, ends tripled; see lathe_shape.profiles.bspline). Foot,
#: stem, bowl, rim, inner wall, inner bottom.
GLASS_BSPLINE = np.array([
    [0.0, 0.0], [3.7, 0.0], [3.6, 0.55], [0.4, 0.45], [0.3, 6.2], [5.7, 6.9],
    [4.0, 15.6], [3.35, 18.5], [4.3, 12.6], [2.6, 7.6], [0.0, 7.8],
])


def glass_spec() -> dict:
    """Fig. 9: a wine glass from arcs (42 segments): foot with a round edge,
    stem, fillet, spherical bowl, inward-leaning upper wall, round rim; wall
    0.18, inner wall concentric (method.md section 2.3)."""
    s, f = 0.35, 0.8          # stem radius, stem-to-bowl fillet radius
    zc, R = 11.0, 4.0         # bowl sphere centre height and outer radius
    top, up_R, t = 18.0, 30.0, 0.18
    # Fillet circle: tangent to the stem line r = s and (externally) to the bowl.
    cz = zc - math.sqrt((R + f) ** 2 - (s + f) ** 2)
    fil_end = math.degrees(math.atan2(zc - cz, -(s + f)))
    phi = math.degrees(math.asin((top - zc) / up_R))
    return {
        "description": "Fig. 9 wine glass: arcs divided equally, concentric inner wall (42 segments)",
        "start": [0.0, 0.0], "heading_deg": 0.0, "max_step_deg": 10.0, "thickness": t,
        "base": [
            {"line": {"to": [3.4, 0.0]}},
            {"arc": {"radius": 0.15, "sweep": 180.0, "segments": 4}},
            {"line": {"to": [1.15, 0.3]}},
            {"arc": {"radius": 0.8, "sweep": -90.0, "segments": 4}},
            {"line": {"to": [s, round(cz, 12)]}},
            {"arc": {"radius": f, "sweep": round(fil_end - 180.0, 12), "segments": 4}},
        ],
        "wall": [
            {"arc": {"center": [0.0, zc], "end_angle": 0.0, "segments": 8}},
            {"arc": {"radius": up_R, "sweep": round(phi, 12), "segments": 2}},
        ],
        "rim": {"type": "round", "segments": 5},
        "bottom": "axis",
    }


def sundae_spec() -> dict:
    """Fig. 10a: a sundae cup from arcs (58 segments): foot, stem, flat-bottomed
    wide bowl with a quarter-circle side and an outward flare, wall 0.25."""
    return {
        "description": "Fig. 10a sundae cup: arcs divided equally, concentric inner wall (58 segments)",
        "start": [0.0, 0.0], "heading_deg": 0.0, "max_step_deg": 7.5, "thickness": 0.25,
        "base": [
            {"line": {"to": [3.4, 0.0]}},
            {"arc": {"radius": 0.15, "sweep": 180.0, "segments": 4}},
            {"line": {"to": [1.2, 0.3]}},
            {"arc": {"radius": 0.7, "sweep": -90.0, "segments": 4}},
            {"line": {"to": [0.5, 5.6]}},
            {"arc": {"radius": 0.6, "sweep": -90.0, "segments": 4}},
        ],
        "wall": [
            {"line": {"to": [2.2, 6.2]}},
            {"arc": {"radius": 4.5, "sweep": 90.0}},
            {"arc": {"radius": 2.0, "sweep": -38.0, "segments": 5}},
        ],
        "rim": {"type": "round", "segments": 6},
        "bottom": "flat",
    }


def bottle_spec() -> dict:
    """Fig. 10b: a brandy bottle from arcs (86 segments): punt dome, heel,
    cylindrical body, shoulder, concave neck fillet, neck, flat-cut lip; the
    whole wall (base included) 0.3 thick and concentric."""
    Rd, Rh, punt = 6.0, 1.0, 0.9
    # Dome (centre on the axis) then heel turning left; the heel's lowest
    # point at z = 0: (Rd + Rh) cos(a) = Rd - punt + Rh.
    alpha = math.degrees(math.acos((Rd - punt + Rh) / (Rd + Rh)))
    body_r = (Rd + Rh) * math.sin(math.radians(alpha)) + Rh
    Rs, Rf, neck_r = 3.0, 1.2, 1.3
    theta = math.degrees(math.acos(1.0 - (body_r - neck_r) / (Rs + Rf)))
    return {
        "description": "Fig. 10b brandy bottle: arcs divided equally, concentric inner wall (86 segments)",
        "start": [0.0, punt], "heading_deg": 0.0, "max_step_deg": 7.5, "thickness": 0.3,
        "wall": [
            {"arc": {"radius": Rd, "sweep": -round(alpha, 12)}},
            {"arc": {"radius": Rh, "sweep": round(90.0 + alpha, 12)}},
            {"line": {"length": 10.0}},
            {"arc": {"radius": Rs, "sweep": round(theta, 12), "segments": 10}},
            {"arc": {"radius": Rf, "sweep": -round(theta, 12), "segments": 10}},
            {"line": {"to": [neck_r, 19.0]}},
        ],
        "rim": {"type": "flat", "segments": 2},
        "bottom": "axis",
    }


def fine_spec(spec: dict, step_deg: float = 0.5) -> dict:
    """The same arcs divided at ``step_deg`` (a near-exact reference)."""
    out = copy.deepcopy(spec)
    out["max_step_deg"] = step_deg
    for key in ("base", "wall"):
        for element in out.get(key, []):
            for body in element.values():
                body.pop("segments", None)
                body.pop("max_step_deg", None)
    if isinstance(out.get("rim"), dict) and out["rim"].get("type") == "round":
        out["rim"] = {"type": "round", "max_step_deg": 4 * step_deg}
    return out


#: figure -> (title, method, template scene, lathe file(s), expected segments)
FIGURES = {
    "fig8a": ("glass, no care", "polyline", "wine_glass", "glass_fig8a.csv", 31),
    "fig8b": ("glass, exact", "bspline", "wine_glass", "glass_bspline.csv", 12),
    "fig9": ("glass, with care", "polyline", "wine_glass", "glass_fig9.json", 42),
    "fig10a": ("sundae cup", "polyline", "sundae_cup", "sundae_cup.json", 58),
    "fig10b": ("brandy bottle", "polyline", "brandy_bottle", "brandy_bottle.json", 86),
}
SPECS = {"glass_fig9": glass_spec, "sundae_cup": sundae_spec, "brandy_bottle": bottle_spec}
PAPER_TIMES = {"fig8a": "1 min 40 s", "fig8b": "31 min", "fig9": "-", "fig10a": "2 min", "fig10b": "3 min"}


def write_profiles(folder: Path = PAPER) -> None:
    """Write the profile files of scenes/paper (deterministic)."""
    from lathe_shape.profiles import bspline as B
    from lathe_shape.profiles.arcs import build_from_spec, profile_to_csv

    folder.mkdir(parents=True, exist_ok=True)
    for name, make in SPECS.items():
        spec = make()
        (folder / f"{name}.json").write_text(json.dumps(spec, indent=2) + "\n")
        pts, sharp = build_from_spec(spec, name)
        (folder / f"{name}.csv").write_text(profile_to_csv(
            pts, sharp, f"{name}: polyline equivalent of {name}.json\n"
            "generated by scripts/reproduce_paper.py --make"))
        fine, fsharp = build_from_spec(fine_spec(spec), name)
        (folder / f"{name}_fine.csv").write_text(profile_to_csv(
            fine, fsharp, f"{name}: the arcs of {name}.json divided at 0.5 degrees (reference)\n"
            "generated by scripts/reproduce_paper.py --make"))
    header = ("fig. 8b glass: open uniform cubic B-spline control points (12 segments)\n"
              "generated by scripts/reproduce_paper.py --make")
    (folder / "glass_bspline.csv").write_text(
        "\n".join(f"# {h}" for h in header.splitlines()) + "\nr,z\n"
        + "".join(f"{r:.9g},{z:.9g}\n" for r, z in GLASS_BSPLINE))
    seg = B.bspline_segments(GLASS_BSPLINE, "glass_bspline")
    poly = B.to_polyline(seg, 32, "uniform")
    (folder / "glass_fig8a.csv").write_text(profile_to_csv(
        poly, np.zeros(len(poly), bool),
        "fig. 8a glass: 32 points uniform in t on the fig. 8b B-spline (31 segments, no care)\n"
        "generated by scripts/reproduce_paper.py --make"))


def scene_xml(fig: str, filename: str | None = None, kind: str | None = None) -> str:
    """Scene text of a figure: the template scene's camera, floor and
    lights with the figure's lathe."""
    title, method, template, lathe_file, segments = FIGURES[fig]
    filename = filename or lathe_file
    kind = kind or method
    text = (ROOT / "scenes" / f"{template}.xml").read_text()
    body = text[text.index("<scene"):]
    start = body.index('<shape type="lathe"')
    end = body.index("</shape>", start) + len("</shape>")
    lathe = body[start:end]
    old_file = lathe[lathe.index('<string name="filename"'):]
    old_file = old_file[:old_file.index("/>") + 2]
    new = f'<string name="filename" value="{filename}"/>'
    if kind == "bspline":
        new += '\n        <string name="kind" value="bspline"/>'
    lathe = lathe.replace(old_file, new).replace(f'id="{template}"', f'id="{fig}"')
    header = (f"<!--\n    Horiuchi, Yokoi & Toriwaki (1987), Fig. {fig[3:]}: {title}, "
              f"{method}, {segments} segments.\n"
              f"    Camera, floor and lights as scenes/{template}.xml; generated by\n"
              f"    scripts/reproduce_paper.py (option make; no double dash in XML comments).\n\n"
              f"    lathe-render scenes/paper/{fig}.xml -D integrator=lathe_path\n-->\n")
    return header + body[:start] + lathe + body[end:]


def write_scenes(folder: Path = PAPER) -> None:
    for fig in FIGURES:
        (folder / f"{fig}.xml").write_text(scene_xml(fig))


def check_segments() -> dict[str, int]:
    """Load every paper scene's profile and return its segment counts."""
    import mitsuba as mi

    counts = {}
    for fig in FIGURES:
        scene = mi.load_file(str(PAPER / f"{fig}.xml"), res="8", spp="1")
        lathe = [s for s in scene.shapes() if hasattr(s, "profile")][0]
        counts[fig] = lathe.profile.segment_count
    return counts


# ---------------------------------------------------------------------------
# Rendering and measuring
# ---------------------------------------------------------------------------

def render(path: Path, res: int, spp: int, seed: int, max_depth: int | None = None,
           filename: str | None = None, warm: bool = False) -> tuple[np.ndarray, float]:
    """Render a paper scene exactly (lathe_path, normal_check none); returns
    (image, seconds). ``filename`` swaps the lathe's profile file; ``warm``
    renders once first so the time excludes JIT compilation."""
    import mitsuba as mi

    from lathe_shape.tools.scenes import load_scene, load_string_in

    defines = {"res": str(res), "spp": str(spp)}
    if max_depth is not None:
        defines["max_depth"] = str(max_depth)
    if filename is None:
        scene = load_scene(path, defines)
    else:
        text = path.read_text()
        old = text[text.index('<string name="filename"'):]
        old = old[:old.index("/>") + 2]
        text = text.replace(old, f'<string name="filename" value="{filename}"/>')
        text = text.replace('<string name="kind" value="bspline"/>', "")
        scene = load_string_in(path.parent, text, **defines)
    depth = max_depth if max_depth is not None else scene_max_depth(scene)
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": depth, "normal_check": "none"})
    if warm:
        mi.render(scene, spp=spp, seed=seed + 1000, integrator=integrator).numpy()
    t0 = time.perf_counter()
    image = mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy()
    return image, time.perf_counter() - t0


def scene_max_depth(scene) -> int:
    """The scene integrator's max_depth (default -1 when it has none)."""
    import mitsuba as mi

    params = mi.traverse(scene.integrator())
    for key in ("max_depth",):
        if key in params:
            return int(params[key])
    text = str(scene.integrator())
    for line in text.splitlines():
        if "max_depth" in line:
            digits = "".join(c for c in line.split("=")[-1] if c in "-0123456789")
            if digits:
                return int(digits)
    return -1


def image_error(image: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """(relative mean abs error, relative RMSE): divided by the reference's mean."""
    scale = float(reference.mean()) or 1.0
    diff = image.astype(np.float64) - reference
    return float(np.abs(diff).mean() / scale), float(np.sqrt(np.square(diff).mean()) / scale)


def write_sheet(path: Path, images: list[tuple[str, np.ndarray]],
                zoom_box: tuple[float, float, float, float]) -> None:
    """Side-by-side sheet: full images on top, a zoom (box = x0, y0, x1, y1
    as fractions of the image) below, labelled."""
    from PIL import Image, ImageDraw

    from lathe_shape.tools.images import to_srgb8

    tiles = []
    for label, rgb in images:
        full = Image.fromarray(to_srgb8(rgb))
        w, h = full.size
        box = (int(zoom_box[0] * w), int(zoom_box[1] * h), int(zoom_box[2] * w), int(zoom_box[3] * h))
        zoom = full.crop(box).resize((w, int(w * (box[3] - box[1]) / (box[2] - box[0]))), Image.NEAREST)
        tile = Image.new("RGB", (w, h + zoom.size[1] + 18), "white")
        tile.paste(full, (0, 18))
        tile.paste(zoom, (0, h + 18))
        ImageDraw.Draw(tile).text((4, 3), label, fill="black")
        tiles.append(tile)
    sheet = Image.new("RGB", (sum(t.size[0] for t in tiles) + 4 * (len(tiles) - 1),
                              max(t.size[1] for t in tiles)), "white")
    x = 0
    for tile in tiles:
        sheet.paste(tile, (x, 0))
        x += tile.size[0] + 4
    sheet.save(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "paper", help="output folder")
    parser.add_argument("--quick", action="store_true", help="48x48, 4 spp, reference 16 spp (CI)")
    parser.add_argument("--res", type=int, help="image size (default 512, quick 48)")
    parser.add_argument("--spp", type=int, help="samples per pixel (default 64, quick 4)")
    parser.add_argument("--ref-spp", type=int, help="reference spp (default 4x --spp)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    parser.add_argument("--make", action="store_true", help="regenerate scenes/paper/ and exit")
    args = parser.parse_args(argv)

    import mitsuba as mi

    mi.set_variant(args.variant)
    import lathe_shape  # noqa: F401  (registers the plugins)
    from lathe_shape.tools.images import write_exr, write_png

    if args.make:
        write_profiles()
        write_scenes()
        counts = check_segments()
        for fig, n in counts.items():
            print(f"{fig}: {n} segments (expected {FIGURES[fig][4]})")
        return 0 if all(counts[f] == FIGURES[f][4] for f in FIGURES) else 1

    res = args.res or (48 if args.quick else 512)
    spp = args.spp or (4 if args.quick else 64)
    ref_spp = args.ref_spp or (16 if args.quick else 4 * spp)
    args.out.mkdir(parents=True, exist_ok=True)
    counts = check_segments()
    t_start = time.perf_counter()
    print(f"{res}x{res}, {spp} spp (references {ref_spp} spp), lathe_path normal_check none, "
          f"variant {args.variant}, seed {args.seed}", flush=True)

    images, times, references = {}, {}, {}
    for fig in FIGURES:
        image, seconds = render(PAPER / f"{fig}.xml", res, spp, args.seed, warm=True)
        images[fig], times[fig] = image, seconds
        write_exr(args.out / f"{fig}.exr", image, {"spp": spp, "seconds": seconds})
        write_png(args.out / f"{fig}.png", image)
        print(f"  rendered {fig} in {seconds:.2f} s", flush=True)

    # References: the exact object of each figure, more samples.
    ref_of = {"fig8a": "glass", "fig8b": "glass", "fig9": "glass_fig9",
              "fig10a": "sundae_cup", "fig10b": "brandy_bottle"}
    for name in sorted(set(ref_of.values())):
        if name == "glass":
            image, _ = render(PAPER / "fig8b.xml", res, ref_spp, args.seed + 1)
        else:
            fig = next(f for f, n in ref_of.items() if n == name)
            image, _ = render(PAPER / f"{fig}.xml", res, ref_spp, args.seed + 1, filename=f"{name}_fine.csv")
        references[name] = image
        write_exr(args.out / f"reference_{name}.exr", image, {"spp": ref_spp})
        write_png(args.out / f"reference_{name}.png", image)

    rows = []
    header = (f"{'figure':<8}{'object':<17}{'method':<10}{'segments':>9}{'time [s]':>10}"
              f"{'ratio':>7}{'rel. MAE':>10}{'rel. RMSE':>11}  {'reference':<34}{'paper time':>11}")
    print(header)
    print("-" * len(header))
    for fig, (title, method, _, _, _) in FIGURES.items():
        ref_name = ref_of[fig]
        mae, rmse = image_error(images[fig], references[ref_name])
        ratio = f"{times['fig8b'] / times['fig8a']:.1f}x" if fig == "fig8b" else ""
        ref_text = ("exact B-spline" if ref_name == "glass" else "same arcs at 0.5 deg") + f", {ref_spp} spp"
        line = (f"{fig:<8}{title:<17}{method:<10}{counts[fig]:>9}{times[fig]:>10.2f}{ratio:>7}"
                f"{mae:>10.4f}{rmse:>11.4f}  {ref_text:<34}{PAPER_TIMES[fig]:>11}")
        rows.append(line)
        print(line, flush=True)
    print(f"spline/polyline time ratio (8b / 8a): {times['fig8b'] / times['fig8a']:.1f}x "
          f"(paper: intersection ~18x, total ~20x)")
    (args.out / "table.txt").write_text(header + "\n" + "\n".join(rows) + "\n")
    write_sheet(args.out / "sheet_fig8a_8b_9.png",
                [("8a: polyline 31, no care", images["fig8a"]), ("8b: B-spline 12, exact", images["fig8b"]),
                 ("9: polyline 42, with care", images["fig9"])],
                (0.30, 0.15, 0.70, 0.50))
    print(f"wrote {args.out} in {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
