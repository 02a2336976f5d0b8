"""``lathe-sweep``: render a scene once per combination of ``-D`` values
(and per ``--profile`` file of its first lathe), on a Dask cluster
(``--scheduler``, ``--workers``; the optional extra ``lathe_shape[cluster]``)
or one after another in this process, writing ``sweep_0000.exr``, ... (all
the film's channels, the render's values in the header) and the CSV index
``sweep.csv`` (one row per render: file, the values, render seconds, worker).

``-D key=v1,v2,...`` gives a key several values (split at commas; a value
that holds commas itself, such as a colour, goes in parentheses:
``-D "sigma_t=(0.5, 0.5, 0.5),(1, 1, 1)"``; a key given once is the same in
every render); the renders are every combination, the
last key varying fastest, and each ``--profile`` file with each of them.
Each EXR is written whole or not at all; the index is written last.

Example::

    lathe-sweep scenes/wine_glass.xml -D mesh_segments=32,128,512 -D max_depth=4,16 --workers 2
    lathe-sweep scenes/wine_glass.xml --profile a.csv --profile b.csv --scheduler tcp://head:8786
"""

from __future__ import annotations

import argparse
import csv
import io
import os
import re
import sys
import time

from . import interrupts
from .cluster import add_cluster_options, check_cluster_options, uses_cluster, worker_threads
from .common import (
    CliError,
    ProgressBar,
    add_output_option,
    add_render_options,
    check_at_least,
    command_parser,
    is_interrupt,
    run_command,
)

__all__ = ["INDEX", "MAX_RENDERS", "build_parser", "main", "parse_grid"]

PROG = "lathe-sweep"
#: The CSV index in the output folder.
INDEX = "sweep.csv"
#: Most renders in one sweep.
MAX_RENDERS = 100_000


class _RenderBar(ProgressBar):
    """The progress bar, counting renders."""

    def line(self) -> str:
        return super().line().replace(" frames ", " renders ", 1)


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(
        PROG,
        "Render a Mitsuba 3 scene with lathe shapes once per combination of -D values (-D key=v1,v2,...) "
        "and --profile files, on a Dask cluster (--scheduler, --workers) or in this process; writes "
        f"sweep_0000.exr, ... and the index {INDEX} to the output folder.",
    )
    add_output_option(parser, what=f"sweep_NNNN.exr and {INDEX}",
                      default_help="SCENE_sweep in the current folder")
    add_render_options(parser, defines=False)
    parser.add_argument(
        "-D", dest="defines", action="append", metavar="KEY=V1,V2,...",
        help="set an XML <default> parameter to each of the comma-separated values in turn (repeatable: "
        "every combination is rendered); a value holding commas (a colour) goes in parentheses: "
        "'key=(0.5, 0.5, 0.5),(1, 1, 1)'")
    parser.add_argument(
        "--profile", action="append", metavar="FILE",
        help="render with FILE (CSV/JSON profile) as the first lathe's profile (repeatable)")
    parser.add_argument("--threads", type=int, metavar="N",
                        help="Dr.Jit threads per render (per worker; default: all cores, shared out "
                        "among --workers)")
    add_cluster_options(parser)
    return parser


def parse_grid(items: list[str] | None) -> dict[str, list[str]]:
    """``["key=v1,v2", ...]`` -> ``{key: [v1, v2]}`` (:class:`CliError` on
    a malformed item, an empty value list or a key given twice)."""
    grid: dict[str, list[str]] = {}
    for item in items or []:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise CliError(f"-D expects key=v1,v2,..., got {item!r}")
        if key in grid:
            raise CliError(f"-D {key} is given twice: list its values once, separated by commas")
        grid[key] = _sweep_values(key, values, item)
    return grid


def _sweep_values(key: str, values: str, item: str) -> list[str]:
    """The comma-separated values of ``-D key=values``; a value that holds
    commas itself (an RGB triple) is written in parentheses, which are
    taken off: ``(0.5, 0.5, 0.5),(1, 1, 1)``. :class:`CliError` on an empty
    value, unbalanced parentheses or a value listed twice."""
    parts, depth, current = [], 0, ""
    for char in values:
        depth += (char == "(") - (char == ")")
        if depth < 0:
            break
        if char == "," and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += char
    if depth != 0:
        raise CliError(f"-D {item}: unbalanced parentheses")
    parts.append(current)
    out = []
    for part in parts:
        part = part.strip()
        if part.startswith("(") and part.endswith(")"):
            part = part[1:-1].strip()
        out.append(part)
    if not all(out):
        raise CliError(f"-D {item}: a value is empty")
    for value in out:
        if out.count(value) > 1:
            hint = ""
            if len(out) == 3:  # (a colour's three components, most likely)
                hint = ("; a value that holds commas (a colour) goes in parentheses: "
                        f"-D '{key}=({values.strip()})'")
            raise CliError(f"-D {key} lists the value {value!r} {out.count(value)} times{hint}")
    return out


def _renders(args: argparse.Namespace) -> list[tuple[dict[str, str], str | None]]:
    """(``-D`` values, profile or None) of every render, in order."""
    from ..distributed import product

    grid = parse_grid(args.defines)
    combos = product(grid) if grid else [{}]
    profiles = args.profile or [None]
    for profile in profiles:
        if profile is not None and not os.path.isfile(profile):
            raise CliError(f"--profile {profile}: no such file")
    renders = [(values, profile) for profile in profiles for values in combos]
    if len(renders) > MAX_RENDERS:
        raise CliError(f"the sweep has {len(renders)} renders, more than {MAX_RENDERS}")
    return renders


def _check(args: argparse.Namespace, renders: list[tuple[dict[str, str], str | None]]) -> None:
    """Load the first render's scene here: a scene error is reported before
    any worker starts."""
    from .common import check_render_budget, check_render_options, check_sensor, open_scene

    check_render_options(args)
    check_at_least("--threads", args.threads, 1)
    values, profile = renders[0]
    from ..distributed import _profile_edit
    from ..tools.scenes import SceneError

    def load(values: dict[str, str], profile: str | None):
        return open_scene(args.scene, _client_variant(args), [f"{k}={v}" for k, v in values.items()],
                          args.resolution, edit=None if profile is None else _profile_edit(profile))

    scene = load(values, profile)
    width, height, spp = check_sensor(scene, args.scene, args.spp)
    check_render_budget(width, height, spp)
    # Every other value of each key, and every profile, once (with the
    # first render's other values): a value the scene cannot take is an
    # error before anything is rendered or written
    tried = {(key, value) for key, value in values.items()} | {("--profile", profile)}
    for other, other_profile in renders[1:]:
        for key, value in [*other.items(), ("--profile", other_profile)]:
            if (key, value) in tried:
                continue
            tried.add((key, value))
            trial = {**values, key: value} if key != "--profile" else values
            try:
                load(trial, other_profile if key == "--profile" else profile)
            except (SceneError, CliError) as e:
                what = f"--profile {value}" if key == "--profile" else f"-D {key}={value}"
                raise CliError(f"{what}: {e}") from None


def _client_variant(args: argparse.Namespace) -> str:
    from .cluster import client_args

    return client_args(args).variant


def _write(out_dir: str, name: str, render, args: argparse.Namespace) -> None:
    from ..tools.images import write_exr
    from .common import write_staged

    metadata = {**{f"D.{k}": v for k, v in render.defines.items()}, "seed": int(args.seed),
                "variant": args.variant, "scene": os.path.abspath(args.scene),
                "render_seconds": float(render.seconds)}
    if "profile" in render.variation and not render.defines.get("profile"):
        metadata["profile"] = os.path.abspath(render.variation["profile"])
    if args.spp is not None:
        metadata["spp"] = int(args.spp)

    def write(stem: str) -> list[str]:
        write_exr(stem + ".exr", render.image, metadata, channels=render.channels)
        return [stem + ".exr"]

    write_staged(out_dir, [(write, name)])


def _index_text(renders: list[tuple[dict[str, str], str | None]], done: dict[int, object], names: list[str]
                ) -> str:
    keys = list(dict.fromkeys(k for values, _ in renders for k in values))
    profiles = any(profile is not None for _, profile in renders)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["file", *keys, *(["profile"] if profiles else []), "render_seconds", "worker"])
    for position, (values, profile) in enumerate(renders):
        render = done[position]
        writer.writerow([names[position] + ".exr", *(values.get(k, "") for k in keys),
                         *([profile or ""] if profiles else []), f"{render.seconds:.4f}", render.worker])
    return out.getvalue()


#: A render's file in the output folder.
_RENDER_FILE = re.compile(r"sweep_\d+\.exr")


def sweep(args: argparse.Namespace) -> int:
    from ..distributed import variation_spec
    from .common import output_folder
    from .folder_lock import FolderLock

    check_cluster_options(args)
    renders = _renders(args)
    _check(args, renders)
    threads = worker_threads(args)
    specs = [(values, variation_spec(args.scene, args.variant, values, profile, args.spp, args.resolution,
                                     threads)) for values, profile in renders]
    stem = os.path.splitext(os.path.basename(args.scene))[0]
    out_dir = output_folder(args.output or f"{stem}_sweep")
    digits = max(4, len(str(len(renders) - 1)))
    names = [f"sweep_{k:0{digits}d}" for k in range(len(renders))]
    where = ("in this process" if not uses_cluster(args) else
             f"on the Dask cluster at {args.scheduler}" if args.scheduler else
             f"on a local Dask cluster of {args.workers} worker process(es)")
    with FolderLock(out_dir, {"sweep run": os.getpid()}, range(len(renders)), PROG):
        return _sweep_into(args, renders, specs, out_dir, names, where)


def _sweep_into(args: argparse.Namespace, renders: list, specs: list, out_dir: str, names: list[str],
                where: str) -> int:
    """The sweep's renders into ``out_dir``, whose lock this run holds."""
    from ..distributed import (
        ClusterError,
        cluster_client,
        iter_renders,
        local_worker_pids,
        stop_local_workers,
    )
    from ..tools.images import atomic_path

    # An earlier sweep's index would describe files this one overwrites
    if os.path.exists(os.path.join(out_dir, INDEX)):
        os.remove(os.path.join(out_dir, INDEX))
    print(f"{PROG}: {args.scene} -> {out_dir}{os.sep}\n  {len(renders)} render(s) {where}", flush=True)
    progress = _RenderBar(len(renders))
    done: dict[int, object] = {}
    state: dict[str, object] = {}

    def interrupted() -> str:
        return f"{PROG}: interrupted after {len(done)} of {len(renders)} render(s)"

    def on_ctrl_c() -> None:  # (the watcher's clean-up, in a command process, before children end)
        if "client" in state and not args.scheduler:
            stop_local_workers(state["client"], local_worker_pids(state["client"]))

    start = time.perf_counter()
    try:
        with interrupts.message(lambda: ("\n" if progress.interactive else "") + interrupted()), \
                interrupts.on_interrupt(on_ctrl_c, first=True):
            progress.show()
            if uses_cluster(args):
                with cluster_client(args.scheduler, args.workers) as client:
                    state["client"] = client
                    for render in iter_renders(specs, client, args.seed):
                        _write(out_dir, names[render.index], render, args)
                        done[render.index] = render
                        progress.advance(render.seconds)
            else:
                for render in iter_renders(specs, None, args.seed):
                    _write(out_dir, names[render.index], render, args)
                    done[render.index] = render
                    progress.advance(render.seconds)
            with atomic_path(os.path.join(out_dir, INDEX)) as tmp, open(tmp, "w", encoding="utf-8") as f:
                f.write(_index_text(renders, done, names))
            current = {name + ".exr" for name in names}
            stale = sorted(name for name in os.listdir(out_dir)
                           if _RENDER_FILE.fullmatch(name) and name not in current)
            for name in stale:  # (an earlier, longer sweep's: not in the index)
                os.remove(os.path.join(out_dir, name))
            if stale:
                print(f"  removed {len(stale)} render(s) of an earlier sweep ({stale[0]} ...)", flush=True)
    except ClusterError as e:
        progress.close()
        raise CliError(str(e)) from None
    except BaseException as e:
        progress.close()
        if not is_interrupt(e):
            raise
        interrupts.print_message(interrupted())
        return 130
    progress.close()
    print(f"  wrote {len(done)} render(s) and {INDEX} in {time.perf_counter() - start:.2f} s; "
          f"output folder {out_dir}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(PROG, build_parser(), sweep, argv)


if __name__ == "__main__":
    sys.exit(main())
