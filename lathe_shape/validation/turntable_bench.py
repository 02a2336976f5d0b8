"""Measurements of turntables (the library behind
``scripts/bench_turntable.py``): the per-frame cost of ``lathe-turntable``
against a bare ``mi.render`` loop over the same poses, the error of noisy
and denoised frames on the lathe's pixels against a high-spp reference, and
the frame-to-frame flicker of the seeding policies.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import tempfile
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from ..tools.denoise import Denoiser
from ..tools.images import image_errors, relative_error
from ..tools.turntable import Turntable
from .bench import square_side

__all__ = [
    "bench_parser", "compared_frames", "denoise_errors", "flicker", "frame_times", "lathe_mask", "run_bench",
]


def lathe_mask(turntable: Turntable) -> np.ndarray:
    """(H, W) bool: the pixels whose centre ray hits the turntable's lathe
    (exactly) before anything else."""
    from .furnace import first_hit_mask

    return first_hit_mask(turntable.scene, turntable.sensor, [turntable.lathe])


def frame_times(scene_path: str, variant: str, frames: int, spp: int, resolution: int,
                defines: list[str], extra: list[str] = (), rounds: int = 3) -> dict[str, float]:
    """Seconds per frame: ``lathe-turntable`` in-process (posing, render,
    transfer, denoising and writes) and a bare ``mi.render`` loop over the
    same orbit poses, alternating ``rounds`` times after one uncounted round
    (it compiles the kernels of both: a first pose alone does not, the
    turned transforms make kernels of their own), the median of the rounds
    for each (timings on a shared machine drift); ``ratio`` is the first
    over the second. A failing ``lathe-turntable`` raises its message."""
    from ..cli.common import CliError
    from ..cli.turntable import main
    from ..tools.scenes import load_scene

    define_args = [a for d in defines for a in ("-D", d)]
    values = dict(d.split("=", 1) for d in defines)
    turntable = Turntable(load_scene(scene_path, values, (resolution, resolution)))
    cli, bare = [], []
    with tempfile.TemporaryDirectory() as folder:
        job = [scene_path, "--variant", variant, "--count", str(frames), "--spp", str(spp),
               "--resolution", f"{resolution}x{resolution}", "-o", folder, "--force", *define_args, *extra]
        for counted in [False] + [True] * rounds:
            output, errors = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(output), contextlib.redirect_stderr(errors):
                status = main(job)
            if status != 0:
                raise CliError(errors.getvalue().strip().splitlines()[-1] if errors.getvalue().strip()
                               else f"lathe-turntable exited with status {status}")
            start = time.perf_counter()
            for k in range(frames):
                turntable.pose(360.0 * k / frames)
                dr.eval(mi.render(turntable.scene, spp=spp, seed=0, integrator=turntable.integrator))
                dr.sync_thread()
            if counted:
                bare.append((time.perf_counter() - start) / frames)
                # The command's own time for its frame loop (writes included).
                cli.append(float(re.findall(r" in ([0-9.]+) s", output.getvalue())[-1]) / frames)
    cli_s, bare_s = float(np.median(cli)), float(np.median(bare))
    return {"turntable_s": cli_s, "render_s": bare_s, "ratio": cli_s / bare_s}


def compared_frames(turntable: Turntable, angle: float, spp: int, high_spp: int, reference: np.ndarray,
                    seed: int = 0, backend: str | None = "oidn",
                    stratified: Turntable | None = None) -> dict[str, np.ndarray]:
    """The (H, W, 3) frames :func:`denoise_errors` compares, by name: an
    ``spp`` frame noisy and denoised (with the integrator's guides, the
    albedo guide only, no guides, the converged guides of the
    ``reference`` render: what better guides could give at most, the
    reference's albedo guide with the frame's own normals, and the albedo
    guide of the ``high_spp`` render with the frame's normals: how clean
    the albedo guide must be), a frame of 4 x ``spp`` denoised and a
    ``high_spp`` frame; with ``backend``
    None (no denoiser), the noisy frames only. A ``stratified`` turntable
    (the same scene, sampled as by ``lathe-turntable --multijitter``, see
    :func:`~lathe_shape.tools.denoise.multijitter_xml`) adds its ``spp``
    frame noisy and denoised (names ending ``_multijitter``)."""
    image = turntable.render(angle, spp=spp, seed=seed)
    rgb, albedo = image[..., :3], image[..., 3:6]
    high_image = turntable.render(angle, spp=high_spp, seed=seed + 2)
    high = high_image[..., :3]
    denoise = Denoiser(backend) if backend is not None else None

    def guided(frame: np.ndarray) -> np.ndarray:  # denoised with its own guides
        return denoise(frame[..., :3], frame[..., 3:6], frame[..., 6:9])

    frames = {}
    if stratified is not None:
        other = stratified.render(angle, spp=spp, seed=seed)
        frames[f"noisy_{spp}spp_multijitter"] = other[..., :3]
        if denoise is not None:
            frames[f"denoised_{spp}spp_multijitter"] = guided(other)
            frames[f"denoised_{spp}spp_multijitter_reference_guides"] = denoise(
                other[..., :3], reference[..., 3:6], reference[..., 6:9])
    if denoise is None:
        return {f"noisy_{spp}spp": rgb, f"noisy_{high_spp}spp": high, **frames}
    more = turntable.render(angle, spp=4 * spp, seed=seed + 3)
    return {
        f"noisy_{spp}spp": rgb,
        f"denoised_{spp}spp": guided(image),
        f"denoised_{spp}spp_albedo_only": denoise(rgb, albedo),
        f"denoised_{spp}spp_no_guides": denoise(rgb),
        f"noisy_{high_spp}spp": high,
        f"denoised_{spp}spp_reference_guides": denoise(rgb, reference[..., 3:6], reference[..., 6:9]),
        f"denoised_{spp}spp_reference_albedo": denoise(rgb, reference[..., 3:6], image[..., 6:9]),
        f"denoised_{spp}spp_{high_spp}spp_albedo": denoise(rgb, high_image[..., 3:6], image[..., 6:9]),
        f"denoised_{4 * spp}spp": guided(more),
        **frames,
    }


def denoise_errors(turntable: Turntable, angle: float, spp: int, high_spp: int, reference_spp: int,
                   seed: int = 0, clean_spp: int = 0, backend: str | None = "oidn",
                   stratified: Turntable | None = None) -> dict[str, float]:
    """Relative error on the lathe's pixels against a ``reference_spp``
    render of the :func:`compared_frames` (the turntable needs guides), of a
    second, independent ``reference_spp`` render (the reference's own noise,
    part of every error) and, with a nonzero ``clean_spp``, of the same
    frames against a ``clean_spp`` render (names ending ``_vs_<clean_spp>spp``);
    ``denoised_<spp>spp_brightness``: the denoised frame's mean on the lathe
    over the reference's, minus one (and ``..._multijitter_brightness``
    with a ``stratified`` turntable, see :func:`compared_frames`).
    ``backend``: the denoiser (None: the noisy frames only)."""
    turntable.pose(angle)
    mask = lathe_mask(turntable)
    reference = turntable.render(angle, spp=reference_spp, seed=seed + 1)
    frames = compared_frames(turntable, angle, spp, high_spp, reference, seed, backend, stratified)
    second = turntable.render(angle, spp=reference_spp, seed=seed + 4)
    frames[f"second_reference_{reference_spp}spp"] = second[..., :3]
    errors: dict[str, float] = {
        name: relative_error(image, reference[..., :3], mask) for name, image in frames.items()
    }
    errors["glass_pixels"] = int(mask.sum())
    for name in (f"denoised_{spp}spp", f"denoised_{spp}spp_multijitter"):
        if name in frames:
            errors[f"{name}_brightness"] = image_errors(frames[name], reference[..., :3], mask)["bias"]
    if clean_spp:
        clean = turntable.render(angle, spp=clean_spp, seed=seed + 5)[..., :3]
        for name, image in frames.items():
            errors[f"{name}_vs_{clean_spp}spp"] = relative_error(image, clean, mask)
    return errors


def flicker(turntable: Turntable, angles: list[float], spp: int, reference_spp: int,
            denoise: bool = False, backend: str = "oidn") -> dict[str, float]:
    """Frame-to-frame flicker of each seeding policy over ``angles``: the
    mean absolute difference between consecutive frames' changes and the
    changes of ``reference_spp`` renders of the same poses (what the motion
    itself changes), relative to the mean of the references; ``denoise``
    compares frames denoised by ``backend``."""
    denoiser = Denoiser(backend) if denoise else None

    def frame(angle: float, seed: int, count: int) -> np.ndarray:
        image = turntable.render(angle, spp=count, seed=seed)
        if denoiser is None:
            return image[..., :3]
        return denoiser(image[..., :3], image[..., 3:6], image[..., 6:9])

    reference = np.stack([turntable.render(a, spp=reference_spp, seed=99)[..., :3] for a in angles])
    motion = np.diff(reference, axis=0)
    result = {}
    for policy in ("frame", "same"):
        frames = np.stack([frame(a, k if policy == "frame" else 0, spp) for k, a in enumerate(angles)])
        result[policy] = float(np.abs(np.diff(frames, axis=0) - motion).mean() / reference.mean())
    return result


def run_bench(argv: list[str] | None = None) -> int:
    """``scripts/bench_turntable.py``: print the frame times, the masked
    denoise errors and the flicker of both seeding policies; any error is
    one line (``bench_turntable.py: error: ...``). Returns the exit status."""
    from ..cli.common import run_command

    return run_command("bench_turntable.py", bench_parser(), _bench, argv)


def _bench(args: argparse.Namespace) -> int:
    """The body of :func:`run_bench`."""
    from ..cli.common import select_variant
    from ..tools.denoise import DenoiseError, box_filter_xml, choose_backend, multijitter_xml
    from ..tools.scenes import load_string_in, set_film_size

    _check_counts(args)
    defines = args.defines or ["integrator=lathe_path", "max_depth=8"]
    select_variant(args.variant)
    try:
        backend, note = choose_backend(args.variant)
    except DenoiseError as e:
        backend, note = None, f"{e}: the denoised measurements are skipped"
    print(f"denoiser: {backend or 'none'}" + (f" ({note})" if note else ""))
    job = (args.scene, args.variant, args.frames, args.spp, args.resolution, defines)
    times = frame_times(*job, rounds=args.rounds)
    print(f"per frame, {args.resolution}x{args.resolution} {args.spp} spp ({args.variant}): lathe-turntable "
          f"{times['turntable_s'] * 1e3:.1f} ms, bare mi.render {times['render_s'] * 1e3:.1f} ms, "
          f"ratio {times['ratio']:.2f}; {args.frames} frames in {times['turntable_s'] * args.frames:.2f} s")
    if backend is not None:
        for extra in (["--denoise"], ["--denoise", "--multijitter"]):
            times = frame_times(*job, extra, rounds=args.rounds)
            print(f"  with {' '.join(extra)}: {times['turntable_s'] * 1e3:.1f} ms per frame, "
                  f"ratio {times['ratio']:.2f}")
    with open(args.scene, encoding="utf-8") as f:
        text = set_film_size(box_filter_xml(f.read()), (args.resolution, args.resolution))
    folder = os.path.dirname(os.path.abspath(args.scene))
    values = dict(d.split("=", 1) for d in defines)
    turntable = Turntable(load_string_in(folder, text, **values), guides=True)
    # The same frame sampled as by lathe-turntable --multijitter.
    stratified = Turntable(load_string_in(folder, multijitter_xml(text), **values), guides=True)
    errors = denoise_errors(turntable, 30.0, args.spp, args.high_spp, args.reference_spp,
                            clean_spp=args.clean_spp, backend=backend, stratified=stratified)
    suffix = f"_vs_{args.clean_spp}spp"
    print("relative error on the glass pixels against", args.reference_spp, "spp (box filter):")
    for name, value in errors.items():
        if not name.endswith(suffix):
            print(f"  {name}: {value:.4f}" if isinstance(value, float) else f"  {name}: {value}")
    if args.clean_spp:
        print(f"the same against {args.clean_spp} spp (less of the reference's own noise):")
        for name, value in errors.items():
            if name.endswith(suffix):
                print(f"  {name.removesuffix(suffix)}: {value:.4f}")
    world = Turntable(load_string_in(folder, text, **values), "world", guides=True)
    angles = [2.0 * k for k in range(8)]
    for denoise in (False, True) if backend is not None else (False,):
        result = flicker(world, angles, args.spp, args.high_spp, denoise, backend or "oidn")
        print(f"flicker of a world turn (2 deg steps, {args.spp} spp{', denoised' if denoise else ''}): "
              + ", ".join(f"seeds={k} {v:.4f}" for k, v in result.items()))
    return 0


def _check_counts(args: argparse.Namespace) -> None:
    """The counts of frames, rounds and samples, each at least 1 (``--clean-spp``: 0)."""
    from ..cli.common import check_at_least

    for option, minimum in [("--frames", 1), ("--rounds", 1), ("--spp", 1), ("--high-spp", 1),
                            ("--reference-spp", 1), ("--clean-spp", 0)]:
        check_at_least(option, getattr(args, option[2:].replace("-", "_")), minimum)


#: The default scene: the wine glass in the repository's scenes folder,
#: found from any current folder.
DEFAULT_SCENE = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                             "scenes", "wine_glass.xml")


def _scene_file(path: str) -> str:
    """``--scene``: a readable, well-formed scene file with a lathe shape,
    else the parser's one-line error naming the file and the problem."""
    from ..tools.scenes import SceneError, lathe_ids, read_scene_text

    try:
        if not lathe_ids(read_scene_text(path), path):
            raise SceneError(f"{path}: the scene has no <shape type=\"lathe\"> to turn")
    except SceneError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    return path


def bench_parser() -> argparse.ArgumentParser:
    """Options of ``scripts/bench_turntable.py``."""
    from ..cli.common import DEFAULT_VARIANT

    parser = argparse.ArgumentParser(
        prog="bench_turntable.py",
        description="Turntables measured: the per-frame cost of lathe-turntable against a bare mi.render "
                    "loop over the same poses, the error of noisy and denoised frames on the lathe's pixels "
                    "against a high-spp reference, and the frame-to-frame flicker of the seeding policies.")
    parser.add_argument("--scene", type=_scene_file, default=DEFAULT_SCENE,
                        help="Mitsuba XML scene with a lathe "
                             "(default: the repository's scenes/wine_glass.xml)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help=f"Mitsuba variant (default: {DEFAULT_VARIANT})")
    parser.add_argument("--resolution", type=square_side, default=128, metavar="NxN",
                        help="frame size, NxN or N (default: 128x128)")
    parser.add_argument("--frames", type=int, default=8, help="frames of the timing run (default: 8)")
    parser.add_argument("--rounds", type=int, default=3,
                        help="alternating timing runs of the turntable and the bare loop, whose medians "
                             "are compared (default: 3)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel of the frames (default: 16)")
    parser.add_argument("--high-spp", type=int, default=256,
                        help="samples per pixel of the high-spp frame and of the flicker run's motion "
                             "reference (default: 256)")
    parser.add_argument("--reference-spp", type=int, default=1024,
                        help="samples per pixel of the reference (default: 1024)")
    parser.add_argument("--clean-spp", type=int, default=4096,
                        help="a second, cleaner reference for the denoise errors (0: none; default: 4096)")
    parser.add_argument("-D", dest="defines", action="append", default=None, metavar="KEY=VALUE",
                        help="XML defaults (default: integrator=lathe_path, max_depth=8)")
    return parser
