"""``lathe-turntable``: render a full turn of a lathe (or of the camera about
it) as numbered EXR + PNG frames, optionally assembled into a GIF or MP4.

Frame ``k`` of ``--count N`` shows the turn at ``360 * k / N`` degrees and is
sampled with seed ``--seed + k``, so the job can be split with ``--frames``
across processes or machines, and an interrupted run resumes where it
stopped (finished frames are skipped).

Example::

    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --spp 64 --gif
    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --frames 0:18   # machine 1
    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --frames 18:36  # machine 2
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from .common import is_interrupt

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lathe-turntable",
        description=(
            "Render a 360-degree turntable of a Mitsuba 3 scene with lathe shapes: the lathe spins "
            "about its own axis (or, with --orbit, the camera orbits it). Writes frame_0000.exr "
            "(linear, half float) + frame_0000.png (sRGB), ... to OUTDIR; finished frames are "
            "skipped, so re-running an interrupted job resumes it."
        ),
    )
    parser.add_argument("scene", help="Mitsuba XML scene file")
    parser.add_argument(
        "-o", "--output", metavar="OUTDIR",
        help="output folder, created if missing (default: SCENE_turntable next to the scene)",
    )
    parser.add_argument(
        "--count", type=int, default=36, metavar="N", help="frames in the full turn (default: 36)"
    )
    parser.add_argument(
        "--frames", metavar="START:STOP",
        help="render only frames START to STOP-1 (half-open, like a Python slice; either end may be "
        "left out) to split a job across processes or machines (default: all)",
    )
    parser.add_argument(
        "--object", metavar="ID",
        help="id of the lathe to turn or orbit (default: the first lathe in the scene)",
    )
    parser.add_argument(
        "--orbit", action="store_true",
        help="orbit the camera (the first sensor) about the lathe's axis instead of spinning the lathe",
    )
    parser.add_argument("--spp", type=int, help="samples per pixel (default: the scene's sampler)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    parser.add_argument("--resolution", metavar="WxH", help="override the film resolution, e.g. 640x480")
    parser.add_argument(
        "--seed", type=int, default=0, help="base sampler seed; frame k uses SEED + k (default: 0)"
    )
    parser.add_argument(
        "-D", dest="defines", action="append", metavar="KEY=VALUE",
        help="set an XML <default> parameter, e.g. -D integrator=lathe_path (repeatable)",
    )
    parser.add_argument(
        "--threads", type=int, metavar="N",
        help="Dr.Jit worker threads (default: all cores); 1 makes LLVM renders bit-reproducible also with "
        "reconstruction filters wider than a pixel (e.g. gaussian), whose splats are summed in thread order",
    )
    parser.add_argument("--force", action="store_true", help="render finished frames again")
    parser.add_argument(
        "--gif", action="store_true", help="assemble all frames present into OUTDIR/turntable.gif"
    )
    parser.add_argument(
        "--mp4", action="store_true", help="assemble all frames present into OUTDIR/turntable.mp4"
    )
    parser.add_argument("--fps", type=float, default=12.0, help="GIF/MP4 frame rate (default: 12)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except (KeyboardInterrupt, RuntimeError) as e:
        if not is_interrupt(e):
            raise
        print("lathe-turntable: interrupted", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    # Imported here so that --help works without touching the JIT backends.

    from ..tools.scenes import SceneError
    from ..tools.turntable import (
        JOB_KEYS,
        Frame,
        Turntable,
        TurntableError,
        assemble_gif,
        assemble_mp4,
        frame_pngs,
        frame_state,
        integrator_name,
        parse_frames,
        plan_frames,
        require_video,
        write_frame,
    )
    from .common import CliError, ProgressBar, format_duration, open_scene, root_message
    from .common import output_folder as check_output_folder

    def fail(message: str) -> int:
        print(f"lathe-turntable: error: {message}", file=sys.stderr)
        return 2

    if args.count < 1:
        return fail(f"--count must be at least 1, got {args.count}")
    if args.spp is not None and args.spp < 1:
        return fail(f"--spp must be at least 1, got {args.spp}")
    if args.threads is not None and args.threads < 1:
        return fail(f"--threads must be at least 1, got {args.threads}")
    if not args.fps > 0:
        return fail(f"--fps must be positive, got {args.fps:g}")
    mode = "orbit" if args.orbit else "rotate"
    output = args.output or os.path.splitext(args.scene)[0] + "_turntable"
    try:
        indices = parse_frames(args.frames, args.count)
        require_video(args.gif, args.mp4)
        scene = open_scene(args.scene, args.variant, args.defines, args.resolution)
        turntable = Turntable(scene, mode, args.object, scene_path=args.scene)
        out_dir = check_output_folder(output)
    except (SceneError, CliError, TurntableError, RuntimeError, ImportError) as e:
        return fail(str(e))

    sensor = turntable.sensor
    width, height = (int(v) for v in sensor.film().size())
    spp = args.spp or sensor.sampler().sample_count()
    integrator = integrator_name(turntable.integrator)
    label = f"'{turntable.object_id}'" if turntable.object_id else "(without id)"
    if mode == "rotate":
        what = f"lathe {label} spins about its axis"
    elif turntable.lathe is not None:
        what = f"camera orbits lathe {label}"
    else:
        what = "camera orbits the world z axis (no lathe in the scene)"
    shard = "" if len(indices) == args.count else f", frames {indices.start}:{indices.stop}"
    print(
        f"lathe-turntable: {args.scene} -> {out_dir}{os.sep}\n"
        f"  {what}: {args.count} frames of {360.0 / args.count:g} deg{shard}\n"
        f"  {width}x{height}, {spp} spp, integrator {integrator}, variant {args.variant}, "
        f"seed {args.seed} + frame" + ("" if args.threads is None else f", {args.threads} thread(s)"),
        flush=True,
    )

    def job_metadata(frame: Frame) -> dict[str, object]:
        return {
            "frame": frame.index,
            "count": args.count,
            "angle_deg": float(frame.angle_deg),
            "spp": int(spp),
            "integrator": integrator,
            "seed": int(frame.seed),
            "mode": mode,
            "object": turntable.object_id,
            "variant": args.variant,
            "scene": os.path.abspath(args.scene),
        }

    frames = plan_frames(args.count, indices, out_dir, args.seed)
    todo, stale = [], 0
    for frame in frames:
        expect = {k: v for k, v in job_metadata(frame).items() if k in JOB_KEYS}
        state = "missing" if args.force else frame_state(frame, expect, (width, height))
        if state != "done":
            todo.append((frame, expect))
        stale += state == "stale"
    skipped = len(frames) - len(todo)
    if skipped or stale:
        notes = [f"{skipped} finished frame(s) skipped"] if skipped else []
        if stale:
            notes.append(f"{stale} frame(s) of a different job (count, spp, seed, ...) rendered again")
        print("  " + "; ".join(notes), flush=True)

    import drjit as dr

    threads = dr.thread_count()
    if args.threads is not None:
        dr.set_thread_count(args.threads)  # restored below: main() may be called in-process
    start = time.perf_counter()
    rendered = 0
    progress = ProgressBar(len(frames), done=skipped)
    try:
        if todo:
            progress.show()
        for frame, expect in todo:
            # Another process working on the same folder may have finished it.
            if not args.force and frame_state(frame, expect, (width, height)) == "done":
                skipped += 1
                progress.advance(None)
                continue
            t0 = time.perf_counter()
            rgb = turntable.render(frame.angle_deg, spp=spp, seed=frame.seed)
            seconds = time.perf_counter() - t0
            write_frame(frame, rgb, {**job_metadata(frame), "render_seconds": float(seconds)})
            rendered += 1
            progress.advance(seconds)
    except (KeyboardInterrupt, RuntimeError) as e:
        progress.close()
        if not is_interrupt(e):
            return fail(root_message(e))
        print(
            f"lathe-turntable: interrupted after {rendered} rendered frame(s); "
            "run the same command again to resume",
            file=sys.stderr,
        )
        return 130
    except OSError as e:
        progress.close()
        return fail(f"cannot write frame: {e}")
    finally:
        if args.threads is not None:
            dr.set_thread_count(threads)
    progress.close()
    elapsed = time.perf_counter() - start
    print(
        f"  rendered {rendered} frame(s), skipped {skipped} already done, "
        f"in {elapsed:.2f} s{'' if elapsed < 60 else ' (' + format_duration(elapsed) + ')'}; "
        f"output folder {out_dir}",
        flush=True,
    )

    for wanted, name, assemble in ((args.gif, "turntable.gif", assemble_gif),
                                   (args.mp4, "turntable.mp4", assemble_mp4)):
        if not wanted:
            continue
        pngs = frame_pngs(out_dir, args.count)
        path = os.path.join(out_dir, name)
        try:
            assemble(pngs, path, args.fps)
        except TurntableError as e:
            return fail(str(e))
        partial = "" if len(pngs) == args.count else f" of {args.count}"
        print(f"  wrote {path} ({len(pngs)}{partial} frames, {args.fps:g} fps)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
