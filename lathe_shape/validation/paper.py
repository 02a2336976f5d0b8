"""The paper's figures 8a-10b as data, and what the scripts that render and
measure them share (docs/method.md, "The paper's results").

``scenes/paper/figures.json`` holds the figure table (scene, profile, method,
expected segment count, the paper's time, which reference), the references
(the exact object of each figure: the B-spline itself, or the same arcs
divided at 0.5 degrees), how the derived profile files are made from their
sources (arc specs, the fig. 8b control points), the contact sheet and the
objects of the open-problems study. :func:`load_paper` reads it;
:func:`render_exact` renders a figure with the exact ``lathe_whitted``
(the paper's Whitted ray tracing) or ``lathe_path`` integrator, optionally
with another profile file.
"""

from __future__ import annotations

import os
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..profiles import bspline as bs
from ..profiles import build_from_spec, read_points, spec_with_step, write_profile_csv
from ..profiles.arcs import read_profile_spec

__all__ = [
    "PAPER_INTEGRATORS",
    "PAPER_SCENES",
    "Figure",
    "Paper",
    "Reference",
    "arc_spec",
    "glass_control_points",
    "load_paper",
    "render_exact",
    "render_size",
    "script_parser",
    "segment_counts",
    "write_derived_profiles",
    "write_sheet",
]

#: The folder of the paper's scenes and profiles in the repository.
PAPER_SCENES = Path(__file__).resolve().parents[2] / "scenes" / "paper"


@dataclass(frozen=True)
class Figure:
    """One of the paper's figures: its scene ``<name>.xml`` in the paper
    folder renders ``profile_file`` with ``method`` (``segments`` of them)."""

    name: str
    title: str
    method: str
    profile_file: str
    segments: int
    paper_time: str
    reference: str


@dataclass(frozen=True)
class Reference:
    """The exact object of a figure: the scene of ``figure`` with the
    profile file ``profile_file`` (None: the scene's own), described by ``text``."""

    name: str
    figure: str
    profile_file: str | None
    text: str


@dataclass(frozen=True)
class Paper:
    """``figures.json`` read (see the module docstring)."""

    folder: Path
    figures: dict[str, Figure]
    references: dict[str, Reference]
    derived_profiles: dict[str, dict]
    sheet: dict
    open_problems: dict

    def scene(self, figure: str) -> Path:
        """The scene file of a figure."""
        return self.folder / f"{figure}.xml"


def load_paper(folder: str | os.PathLike = PAPER_SCENES) -> Paper:
    """Read ``folder/figures.json``."""
    import json

    folder = Path(folder)
    table = json.loads((folder / "figures.json").read_text(encoding="utf-8"))
    figures = {name: Figure(name=name, **entry) for name, entry in table["figures"].items()}
    references = {
        name: Reference(name=name, figure=entry["figure"], profile_file=entry.get("profile_file"),
                        text=entry["text"])
        for name, entry in table["references"].items()
    }
    return Paper(folder, figures, references, table["derived_profiles"], table["sheet"],
                 table["open_problems"])


def script_parser(prog: str, doc: str, output: str, what: str, seed: int, quick: str, defaults: str):
    """The options of the paper scripts (the cli.common convention): ``-o``,
    ``--spp``, ``--resolution``, ``--seed`` (default ``seed``),
    ``--variant``, ``-D`` and ``--quick`` (a smoke run, ``quick`` says
    what); ``defaults`` names the resolution and spp used without options."""
    import argparse

    from ..cli.common import add_output_option, add_render_options

    epilog = f"Without --resolution and --spp: {defaults}; with --quick: {quick}."
    parser = argparse.ArgumentParser(prog=prog, description=doc.splitlines()[0], epilog=epilog)
    add_output_option(parser, default=output, what=what)
    add_render_options(parser, seed_help=f"sampler seed (default: {seed})",
                       spp_help="see below", resolution_help="see below")
    parser.set_defaults(seed=seed)
    parser.add_argument("--quick", action="store_true", help=quick)
    return parser


def render_size(resolution: str | None, side: int) -> tuple[int, int]:
    """``--resolution WxH`` when given, else a ``side`` x ``side`` square."""
    from ..cli.common import parse_resolution

    return parse_resolution(resolution) if resolution else (side, side)


def glass_control_points(paper: Paper) -> np.ndarray:
    """Fig. 8b: the open uniform cubic B-spline control points of the glass."""
    return read_points(paper.folder / paper.figures["fig8b"].profile_file)[0]


def arc_spec(paper: Paper, figure: str) -> dict:
    """The arc spec (a dict) of an arc-built figure."""
    return read_profile_spec(paper.folder / paper.figures[figure].profile_file)


def write_derived_profiles(paper: Paper) -> list[str]:
    """Regenerate the profile files that ``derived_profiles`` describes
    (deterministic); returns their names."""
    for name, recipe in paper.derived_profiles.items():
        note = "generated by scripts/reproduce_paper.py --make"
        if "spec" in recipe:
            spec = read_profile_spec(paper.folder / recipe["spec"])
            stem = recipe["spec"].rsplit(".", 1)[0]
            if "step_deg" in recipe:
                spec = spec_with_step(spec, recipe["step_deg"])
                what = f"the arcs of {recipe['spec']} divided at {recipe['step_deg']:g} degrees (reference)"
            else:
                what = f"polyline equivalent of {recipe['spec']}"
            points, sharp = build_from_spec(spec, stem)
            header = f"{stem}: {what}\n{note}"
        else:
            controls = read_points(paper.folder / recipe["bspline"])[0]
            segments = bs.bspline_segments(controls, recipe["bspline"])
            points = bs.to_polyline(segments, recipe["points"], recipe["placement"])
            sharp, header = np.zeros(len(points), bool), f"{recipe['header']}\n{note}"
        write_profile_csv(paper.folder / name, points, sharp, header)
    return list(paper.derived_profiles)


def segment_counts(paper: Paper) -> dict[str, int]:
    """Load every figure's scene; the segment count of its lathe."""
    from ..plugin.shape import scene_lathes
    from ..tools.scenes import load_scene

    counts = {}
    for name in paper.figures:
        scene = load_scene(paper.scene(name), {"res": "8", "spp": "1"})
        counts[name] = scene_lathes(scene)[0].profile.segment_count
    return counts


def _declared_default(path: Path, name: str) -> str | None:
    """The value of the scene's ``<default name=...>``, if it declares one."""
    root = ET.parse(path).getroot()
    node = next((d for d in root.findall("default") if d.get("name") == name), None)
    return None if node is None else node.get("value")


def _load(path: Path, defines: dict[str, str], resolution: tuple[int, int] | None, profile_file: str | None):
    """The scene, its lathe reading ``profile_file`` (a polyline file; relative to
    the scene's folder) when given."""
    from ..tools.scenes import load_scene, replace_profile

    if profile_file is None:
        return load_scene(path, defines, resolution)
    profile_path = path.parent / profile_file  # an absolute profile_file stays absolute
    text = replace_profile(path.read_text(encoding="utf-8"), filename=str(profile_path.resolve()),
                           kind="polyline", source=str(path))
    with tempfile.TemporaryDirectory(prefix="lathe_paper_") as folder:
        copy = Path(folder) / path.name
        copy.write_text(text, encoding="utf-8")
        return load_scene(copy, defines, resolution)


#: The integrators a paper figure can be rendered with: the paper's Whitted
#: ray tracing (the default, noise-free) or path tracing.
PAPER_INTEGRATORS = ("lathe_whitted", "lathe_path")


def render_exact(
    path: str | os.PathLike,
    spp: int,
    seed: int,
    resolution: tuple[int, int] | None = None,
    defines: dict[str, str] | None = None,
    profile_file: str | os.PathLike | None = None,
    warm: bool = False,
    integrator: str = "lathe_whitted",
) -> tuple[np.ndarray, float]:
    """Render a paper scene exactly with ``integrator`` (one of
    :data:`PAPER_INTEGRATORS`, ``normal_check none``, the scene's
    ``max_depth``); returns (image, seconds). ``profile_file`` swaps the
    lathe's profile file; ``warm`` renders once first so that the time
    excludes JIT compilation."""
    import mitsuba as mi

    if integrator not in PAPER_INTEGRATORS:
        raise ValueError(f"render_exact: unknown integrator '{integrator}' "
                         f"(expected one of: {', '.join(PAPER_INTEGRATORS)})")
    path = Path(path)
    defines = {"spp": str(spp), **(defines or {})}
    scene = _load(path, defines, resolution, profile_file)
    max_depth = int(defines.get("max_depth", _declared_default(path, "max_depth") or -1))
    renderer = mi.load_dict({"type": integrator, "max_depth": max_depth, "normal_check": "none"})
    if warm:
        mi.render(scene, spp=spp, seed=(seed + 1000) % 2**32, integrator=renderer).numpy()
    start = time.perf_counter()
    image = mi.render(scene, spp=spp, seed=seed, integrator=renderer).numpy()
    return image, time.perf_counter() - start


def write_sheet(path: str | os.PathLike, images: list[tuple[str, np.ndarray]],
                zoom_box: tuple[float, float, float, float]) -> None:
    """Side-by-side sheet: full images on top, a zoom (box = x0, y0, x1, y1
    as fractions of the image) below, labelled."""
    from PIL import Image, ImageDraw

    from ..tools.images import to_srgb8

    tiles = []
    for label, rgb in images:
        full = Image.fromarray(to_srgb8(rgb))
        w, h = full.size
        box = (int(zoom_box[0] * w), int(zoom_box[1] * h), int(zoom_box[2] * w), int(zoom_box[3] * h))
        # (at least one pixel: a 1x1 image's zoom box was empty, a division by zero)
        box = (min(box[0], w - 1), min(box[1], h - 1), max(box[2], min(box[0], w - 1) + 1),
               max(box[3], min(box[1], h - 1) + 1))
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
