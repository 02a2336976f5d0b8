"""``lathe-turntable``: render a full turn about a lathe (the camera orbits
it, the world turns about it, or the lathe spins) as numbered EXR + PNG
frames, optionally denoised, optionally assembled into a GIF or MP4.

Frame ``k`` of ``--count N`` shows the turn at ``360 * k / N`` degrees and is
sampled with seed ``--seed`` (``--seeds same``, the default: the noise stays
put instead of flickering) or ``--seed + k`` (``--seeds frame``), so the job
can be split with ``--frames`` across processes or machines, and an
interrupted run resumes where it stopped (finished frames are skipped).
Frame ``k`` is denoised and written by a background thread while frame
``k + 1`` renders. A run registers itself in the output folder
(:mod:`.folder_lock`): a second run of another job there, or of the same
job on frames the first renders, is refused while the first runs; shards
of one job (other ``--frames``) may run side by side. ``--count`` is at
most :data:`MAX_COUNT`; resume reads only the frames whose two files exist,
and a frame counts as done when its EXR reads and its PNG is whole.

Example::

    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --spp 64 --gif
    lathe-turntable scenes/wine_glass.xml -o turn --mode world --denoise -D integrator=lathe_path
    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --frames 0:18   # machine 1
    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --frames 18:36  # machine 2
    lathe-turntable scenes/wine_glass.xml -o turn --count 36 --workers 2     # local Dask cluster
    lathe-turntable scenes/wine_glass.xml -o turn --scheduler tcp://head:8786

``--scheduler`` / ``--workers`` render the frames as tasks on a Dask cluster
(:mod:`.cluster`; the optional extra ``lathe_shape[cluster]``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import sys
import time
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from . import interrupts
from .common import (
    CliError,
    ProgressBar,
    add_output_option,
    add_render_options,
    check_at_least,
    command_parser,
    is_interrupt,
    parse_defines,
    run_command,
)

if TYPE_CHECKING:  # imported where needed: --help needs no Mitsuba variant
    import numpy as np

    from ..tools.denoise import Denoiser
    from ..tools.frames import Frame, FramePlan
    from ..tools.turntable import Turntable

__all__ = ["main", "build_parser", "parse_frames"]

PROG = "lathe-turntable"

#: The animations ``--gif`` / ``--mp4`` write into the output folder.
VIDEOS = ("gif", "mp4")

#: Seeding policies: one seed for all frames, or ``--seed + k`` for frame k.
SEED_POLICIES = ("same", "frame")

#: Most frames in a turn (``--count``): a million frames play for 23 hours
#: at 12 fps; checking which are done on resume takes about a second.
MAX_COUNT = 1_000_000


def build_parser() -> argparse.ArgumentParser:
    parser = command_parser(
        PROG,
        "Render a 360-degree turntable of a Mitsuba 3 scene with lathe shapes: the camera orbits "
        "the lathe's axis (default), the world turns about it (--mode world), or the lathe spins "
        "(--mode spin, for textured lathes). Writes frame_0000.exr (linear, half float) + "
        "frame_0000.png (sRGB), ... to the output folder; finished frames are skipped, so re-running "
        "an interrupted job resumes it.",
    )
    add_output_option(parser, what="frame_NNNN.exr/.png, turntable.gif/.mp4",
                      default_help="SCENE_turntable in the current folder")
    parser.add_argument("--count", type=int, default=36, metavar="N",
                        help=f"frames in the full turn, at most {MAX_COUNT} (default: 36)")
    parser.add_argument(
        "--frames", metavar="START:STOP",
        help="render only frames START to STOP-1 (half-open, like a Python slice; either end may be "
        "left out) to split a job across processes or machines (default: all)",
    )
    parser.add_argument("--object", metavar="ID",
                        help="id of the lathe to turn or orbit (default: the first lathe in the scene)")
    add_mode_options(parser)
    add_render_options(parser, seed_help="sampler seed (default: 0); see --seeds")
    parser.add_argument(
        "--seeds", choices=SEED_POLICIES, default="same",
        help="'same': every frame uses SEED, so the noise stays put on screen instead of flickering "
        "(default); 'frame': frame k uses SEED + k (independent noise, e.g. to average frames)",
    )
    parser.add_argument(
        "--threads", type=int, metavar="N",
        help="Dr.Jit worker threads, and at most as many frame writers (default: all cores); 1 makes LLVM "
        "renders bit-reproducible also with "
        "reconstruction filters wider than a pixel (e.g. gaussian), whose splats are summed in thread order",
    )
    parser.add_argument("--force", action="store_true", help="render finished frames again")
    for fmt in VIDEOS:
        parser.add_argument(f"--{fmt}", action="store_true",
                            help=f"assemble all frames present into the output folder's turntable.{fmt}")
    parser.add_argument("--fps", type=float, default=12.0, help="GIF/MP4 frame rate (default: 12)")
    from .cluster import add_cluster_options

    add_cluster_options(parser, collect=True)
    return parser


def add_mode_options(parser: argparse.ArgumentParser) -> None:
    """``--mode``, its alias ``--orbit``, ``--denoise`` and ``--multijitter``."""
    from ..tools.poses import DEFAULT_MODE, MODES

    parser.add_argument(
        "--mode", choices=MODES, default=None,
        help=f"how the turn is shown (default: {DEFAULT_MODE}): 'orbit' moves the camera (the first "
        "sensor) about the lathe's axis; 'world' keeps camera and lathe and turns the environment, the "
        "emitters and the other shapes about the axis; 'spin' turns the lathe itself, which only shows "
        "for a textured lathe",
    )
    parser.add_argument("--orbit", dest="mode", action="store_const", const="orbit",
                        help="same as --mode orbit")
    parser.add_argument(
        "--denoise", action="store_true",
        help="denoise every frame (Intel Open Image Denoise, pip install lathe_shape[denoise]; OptiX on "
        "CUDA variants whose driver ships its weights), guided by albedo and normals; the EXR keeps the "
        "noisy image as the layer 'noisy'",
    )
    parser.add_argument(
        "--multijitter", action="store_true",
        help="sample with Mitsuba's multijitter sampler where the scene's is independent (its default): "
        "pixel positions and BSDF choices stratified within each pixel, so less noise, and with --denoise "
        "less noisy guides behind glass and a denoised image closer to the converged one; the sample count "
        "may round up (10 to 12; squares stay)",
    )


def parse_frames(text: str | None, count: int) -> range:
    """``--frames`` -> the half-open range of frame indices to render.

    ``"START:STOP"`` as in a Python slice (either end may be left out:
    ``":12"``, ``"12:"``), or a single index ``"K"`` (that frame only).
    ``STOP`` past the end is clipped to ``count``, so fixed-size shards such
    as ``0:10 10:20 20:30`` cover 24 frames. Negative indices, steps and empty
    ranges are errors (:class:`CliError`).
    """
    check_at_least("--count", count, 1)
    if text is None:
        return range(count)
    parts = text.strip().split(":")
    if len(parts) > 2:
        raise CliError(f"--frames expects START:STOP (no step), got {text!r}")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise CliError(f"--frames expects integers START:STOP, e.g. 0:12, got {text!r}") from None
    if len(values) == 1:
        if values[0] is None:
            raise CliError(f"--frames expects START:STOP, e.g. 0:12, got {text!r}")
        start, stop = values[0], values[0] + 1
    else:
        start = 0 if values[0] is None else values[0]
        stop = count if values[1] is None else values[1]
    if start < 0 or stop < 0:
        raise CliError(f"--frames {text}: frame indices must not be negative")
    stop = min(stop, count)
    if start >= stop:
        raise CliError(
            f"--frames {text} selects no frame (the turn has frames 0 to {count - 1}; "
            "the range is half-open: START:STOP renders START to STOP-1)"
        )
    return range(start, stop)


@dataclass
class Job:
    """What one run renders: the posed scene and the settings every frame's
    metadata records."""

    args: argparse.Namespace
    turntable: Turntable
    indices: range
    out_dir: str
    spp: int
    size: tuple[int, int]
    integrator: str
    #: The frames' denoiser (None without --denoise) and what to tell about it.
    denoiser: Denoiser | None = None
    notes: tuple[str, ...] = ()
    #: Digest of the scene file and its lathes' profile files
    #: (:func:`~lathe_shape.tools.frames.inputs_digest`).
    inputs: str = ""

    def metadata(self, frame: Frame) -> dict[str, object]:
        """The EXR header of ``frame`` (without its render time)."""
        return {
            "frame": frame.index,
            "count": self.args.count,
            "angle_deg": float(frame.angle_deg),
            "spp": int(self.spp),
            "integrator": self.integrator,
            "seed": int(frame.seed),
            "mode": self.turntable.mode,
            "object": self.turntable.object_id,
            "denoiser": "none" if self.denoiser is None else self.denoiser.backend,
            # (e.g. "MultijitterSampler": --multijitter frames are not another job's)
            "sampler": str(self.turntable.sensor.sampler()).split("[", 1)[0],
            "variant": self.args.variant,
            "scene": os.path.abspath(self.args.scene),
            # (-D values and the files' contents: frames of another look are another job's)
            "defines": "; ".join(f"{k}={v}" for k, v in sorted(parse_defines(self.args.defines).items()))
            or "none",
            "inputs": self.inputs,
        }


def open_job(args: argparse.Namespace) -> Job:
    """Check the options, load and pose the scene, create the output folder
    (last: a failed job leaves nothing behind)."""
    from ..tools.denoise import Denoiser, choose_backend, rendered_spp
    from ..tools.frames import inputs_digest
    from ..tools.scenes import integrator_name
    from ..tools.turntable import Turntable
    from ..tools.video import require_video
    from .common import (
        UINT32_MAX,
        check_between,
        check_render_budget,
        check_render_options,
        check_sensor,
        open_scene,
        output_folder,
    )

    check_between("--count", args.count, 1, MAX_COUNT)
    check_render_options(args)
    if args.seeds == "frame":
        check_between("--seed", args.seed + args.count - 1, 0, UINT32_MAX)  # the last frame's seed
    check_at_least("--threads", args.threads, 1)
    if not args.fps > 0:
        raise CliError(f"--fps must be positive, got {args.fps:g}")
    indices = parse_frames(args.frames, args.count)
    for fmt in VIDEOS:
        if getattr(args, fmt):
            require_video(fmt, what=f"--{fmt}")
    backend, note = choose_backend(args.variant) if args.denoise else ("", "")
    scene = open_scene(args.scene, args.variant, args.defines, args.resolution,
                       edit=scene_edit(args))
    *_, spp = check_sensor(scene, args.scene, args.spp)
    colours = scene.sensors()[0].film().base_channels_count()
    if args.denoise and colours < 3:  # (the denoisers take RGB with RGB albedo guides)
        why = f"variant {args.variant} renders luminance only" if "_mono" in args.variant else \
            "its pixel_format is not rgb or rgba"
        raise CliError(f"{args.scene}: --denoise needs an RGB film, and the film has {colours} "
                       f"channel(s) ({why})")
    turntable = Turntable(scene, args.mode, args.object, scene_path=args.scene, guides=args.denoise)
    sensor = turntable.sensor
    size = tuple(int(v) for v in sensor.film().size())
    notes = tuple(turntable.warnings) + ((note,) if note else ())
    rounded = rendered_spp(sensor.sampler(), spp) if args.multijitter else spp
    if rounded != spp:
        notes += (f"the {sensor.sampler().class_name()} takes {rounded} samples per pixel for --spp {spp}",)
        spp = rounded
    check_render_budget(*size, spp)
    stem = os.path.splitext(os.path.basename(args.scene))[0]
    out_dir = output_folder(args.output or f"{stem}_turntable")
    denoiser = None
    if backend:
        denoiser = Denoiser(backend, to_sensor=sensor.world_transform().inverse())
    from ..plugin.shape import scene_lathes  # (the variant is set: the scene is loaded)

    profiles = [str(lathe.profile.source) for lathe in scene_lathes(scene)]
    return Job(args, turntable, indices, out_dir, spp, size, integrator_name(turntable.integrator),
               denoiser, notes, inputs_digest(args.scene, profiles))


def scene_edit(args: argparse.Namespace) -> Callable[[str, str], str] | None:
    """The edit of the scene's text (``edit(text, path)``) for ``--denoise``
    (box filters) and ``--multijitter``, or None."""
    from ..tools.denoise import box_filter_xml, multijitter_xml

    edits = [edit for edit, wanted in ((box_filter_xml, args.denoise), (multijitter_xml, args.multijitter))
             if wanted]
    if not edits:
        return None
    return lambda text, path: functools.reduce(lambda done, edit: edit(done, path), edits, text)


def describe(job: Job) -> None:
    """Print what the job renders."""
    args = job.args
    for note in job.notes:
        print(f"{PROG}: warning: {note}", file=sys.stderr, flush=True)
    what = job.turntable.describe()
    seeds = "" if args.seeds == "same" else " + frame"
    denoised = "" if job.denoiser is None else f", denoised ({job.denoiser.backend})"
    if args.multijitter:
        denoised = f", sampler {job.turntable.sensor.sampler().class_name()}{denoised}"
    shard = "" if len(job.indices) == args.count else f", frames {job.indices.start}:{job.indices.stop}"
    threads = "" if args.threads is None else f", {args.threads} thread(s)"
    print(
        f"{PROG}: {args.scene} -> {job.out_dir}{os.sep}\n"
        f"  {what}: {args.count} frames of {360.0 / args.count:g} deg{shard}\n"
        f"  {job.size[0]}x{job.size[1]}, {job.spp} spp, integrator {job.integrator}, variant {args.variant}, "
        f"seed {args.seed}{seeds}{threads}{denoised}",
        flush=True,
    )
    from .mesh_note import mesh_note

    note = mesh_note(job.turntable.scene, job.turntable.integrator)
    if note:
        print(f"  {note}", flush=True)


def _expected(job: Job, frame: Frame) -> dict[str, object]:
    """The header values a finished frame of this job must carry."""
    from ..tools.frames import JOB_KEYS

    return {k: v for k, v in job.metadata(frame).items() if k in JOB_KEYS}


def job_identity(job: Job) -> dict[str, object]:
    """The settings that make two runs one job (those that decide whether a
    frame on disk is this job's, see :func:`_expected`, and the image
    size), for the output folder's lock."""
    from ..tools.frames import plan_frames

    first = plan_frames(job.args.count, job.indices, job.out_dir, job.args.seed)[0]
    same = {k: v for k, v in _expected(job, first).items() if k not in ("angle_deg", "seed")}
    return {**same, "seed": int(job.args.seed), "seeds": job.args.seeds, "size": list(job.size)}


def pending_frames(job: Job, frames: FramePlan) -> array:
    """The indices of the frames still to render (all with ``--force``);
    says how many were skipped as finished or are rendered again as another
    job's. Only frames whose two files are in the folder are read."""
    from ..tools.frames import frame_state, frame_stem

    present = set() if job.args.force else set(os.listdir(job.out_dir))
    todo, stale = array("q"), 0
    for index in frames.indices:
        stem = frame_stem(index, frames.count)
        if stem + ".exr" not in present or stem + ".png" not in present:
            todo.append(index)
            continue
        frame = frames.frame(index)
        state = frame_state(frame, _expected(job, frame), job.size)
        if state != "done":
            todo.append(index)
        stale += state == "stale"
    skipped = len(frames) - len(todo)
    notes = [f"{skipped} finished frame(s) skipped"] if skipped else []
    if stale:
        notes.append(f"{stale} frame(s) of a different job (count, spp, seed, -D values, scene or "
                     f"profile files, ...) rendered again")
        # The animations in the folder show that job's frames: gone, unless
        # this run writes them anew
        for fmt in VIDEOS:
            name = f"turntable.{fmt}"
            if name in present and not getattr(job.args, fmt):
                os.remove(os.path.join(job.out_dir, name))
                notes.append(f"{name} of that job removed")
    if notes:
        print("  " + "; ".join(notes), flush=True)
    return todo


def clean_frame(job: Job, image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(image to show, noisy image or None): the rendered RGB denoised with
    its guides under --denoise, else as rendered."""
    rgb = image[..., :3]
    if job.denoiser is None:
        return rgb, None
    return job.denoiser(rgb, image[..., 3:6], image[..., 6:9]), rgb


def finish_frame(job: Job, frame: Frame, image: np.ndarray, seconds: float,
                 cleaned: tuple[np.ndarray, np.ndarray | None] | None = None,
                 staging: interrupts.Staging | None = None) -> None:
    """Denoise (unless ``cleaned`` already holds the result) and write one
    rendered frame; runs in the writer thread. With ``staging``, the frame
    is written there and its PNG and EXR moved into place together
    (:meth:`.interrupts.Staging.commit`); on Ctrl-C a write already running
    may finish (:func:`.interrupts.writing`)."""
    from ..tools.frames import write_frame

    with interrupts.writing():
        rgb, noisy = cleaned or clean_frame(job, image)
        names = [os.path.basename(frame.png), os.path.basename(frame.exr)]  # (the EXR last)
        staged = frame if staging is None else \
            dataclasses.replace(frame, png=staging.stage(names[0]), exr=staging.stage(names[1]))
        try:
            write_frame(staged, rgb, {**job.metadata(frame), "render_seconds": float(seconds)}, noisy=noisy)
            if staging is not None:
                staging.commit(names)
        except (OSError, RuntimeError) as e:  # (OpenEXR reports a failed write as RuntimeError)
            # The reason without the hidden temporary file's name when there is one.
            reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise CliError(f"cannot write frame {frame.index} to {os.path.dirname(frame.exr) or '.'}: "
                           f"{reason}") from None


def render_frames(job: Job, frames: FramePlan, todo: Sequence[int], progress: ProgressBar) -> None:
    """Render the frames of ``todo`` (indices into the turn of ``frames``),
    advancing ``progress`` (skipping those another process on the same
    folder finished meanwhile); a background thread denoises and writes
    frame k while frame k + 1 renders, in a staging folder from which each
    frame's two files move into place together."""
    from ..tools.frames import frame_state
    from ..tools.writer import FrameWriter, default_workers
    from .common import interruptible, one_render_thread

    if todo:
        progress.show()
    # Per frame a worker holds (one written, one queued): the rendered
    # float32 channels (RGB, with guides 9) and the denoised copy, and for
    # the frame being written the encoders' buffers (8-bit pixels and their
    # compressed copy, half-float EXR channels: ~24 bytes per pixel).
    frame_bytes = job.size[0] * job.size[1] * (4 * (12 if job.denoiser is not None else 3) + 24 // 2)
    workers = default_workers(frame_bytes)
    if job.args.threads is not None:  # (--threads caps the command's CPU use)
        workers = min(workers, job.args.threads)
    with interrupts.Staging(job.out_dir) as staging, one_render_thread(), \
            FrameWriter(workers=workers) as writer:
        for index in todo:
            frame = frames.frame(index)
            if not job.args.force and frame_state(frame, _expected(job, frame), job.size) == "done":
                progress.advance(None)
                continue
            start = time.perf_counter()
            # In a worker thread: Ctrl-C interrupts at once, even mid-kernel.
            image = interruptible(job.turntable.render, frame.angle_deg, job.spp, frame.seed)
            seconds = time.perf_counter() - start
            cleaned = None
            if job.denoiser is not None and job.denoiser.backend == "optix":
                # OptiX denoises here, on this thread's Dr.Jit (CUDA) state, where its
                # denoiser was made: never in a writer thread. (Untested on a GPU with
                # the OptiX weights: the one lent had none.)
                cleaned = clean_frame(job, image)
            writer.submit(functools.partial(finish_frame, job, frame, image, seconds, cleaned, staging))
            progress.advance(seconds)


def render_job(job: Job) -> int:
    """Render the job's pending frames with a progress bar and the requested
    thread count; returns 130 (with a one-line message) on Ctrl-C."""
    import drjit as dr

    from ..tools.frames import plan_frames

    frames = plan_frames(job.args.count, job.indices, job.out_dir, job.args.seed,
                         same_seed=job.args.seeds == "same")
    todo = pending_frames(job, frames)
    progress = ProgressBar(len(frames), done=len(frames) - len(todo))
    threads = dr.thread_count()
    if job.args.threads is not None:
        dr.set_thread_count(job.args.threads)  # restored below: main() may be called in-process

    def interrupted() -> str:
        return (f"{PROG}: interrupted after {progress.rendered} rendered frame(s); "
                "run the same command again to resume")

    start = time.perf_counter()
    try:
        # (the Ctrl-C watcher's message, in a command process: it ends the bar's line too)
        with interrupts.message(lambda: ("\n" if progress.interactive else "") + interrupted()):
            render_frames(job, frames, todo, progress)
    except BaseException as e:
        progress.close()  # end the bar's line before any message
        if not is_interrupt(e):
            raise
        interrupts.print_message(interrupted())
        return 130
    finally:
        if job.args.threads is not None:
            dr.set_thread_count(threads)
    progress.close()
    print_turn_summary(progress.rendered, len(frames), job.out_dir, start)
    return 0


def print_turn_summary(rendered: int, planned: int, out_dir: str, start: float) -> None:
    """The turn's last line: frames rendered and skipped, the time since
    ``start`` (``time.perf_counter``) and the output folder."""
    from .common import format_duration

    elapsed = time.perf_counter() - start
    print(
        f"  rendered {rendered} frame(s), skipped {planned - rendered} already done, "
        f"in {elapsed:.2f} s{'' if elapsed < 60 else ' (' + format_duration(elapsed) + ')'}; "
        f"output folder {out_dir}",
        flush=True,
    )


def write_videos(job: Job) -> None:
    """Assemble the frames present in the output folder into the requested
    animations."""
    from ..tools.frames import frame_pngs
    from ..tools.video import write_video

    for fmt in VIDEOS:
        if not getattr(job.args, fmt):
            continue
        pngs = frame_pngs(job.out_dir, job.args.count)
        path = os.path.join(job.out_dir, f"turntable.{fmt}")
        write_video(pngs, path, job.args.fps)
        partial = "" if len(pngs) == job.args.count else f" of {job.args.count}"
        print(f"  wrote {path} ({len(pngs)}{partial} frames, {job.args.fps:g} fps)", flush=True)


def turntable(args: argparse.Namespace) -> int:
    from .cluster import check_cluster_options, client_args, render_job_on_cluster, uses_cluster
    from .folder_lock import FolderLock

    check_cluster_options(args)
    job = open_job(client_args(args))
    job.args = args  # (the frames' metadata name the variant asked for)
    with FolderLock(job.out_dir, job_identity(job), job.indices, PROG):
        describe(job)
        status = render_job_on_cluster(job, PROG) if uses_cluster(args) else render_job(job)
        if status == 0:
            write_videos(job)
    return status


def main(argv: list[str] | None = None) -> int:
    return run_command(PROG, build_parser(), turntable, argv)


if __name__ == "__main__":
    sys.exit(main())
