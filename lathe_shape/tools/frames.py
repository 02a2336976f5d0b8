"""The frames of a turntable on disk: which file holds which frame, whether a
frame is already done (to resume an interrupted or sharded job), and writes
that never leave a half-written file under a final name.

Frame ``k`` of a ``count``-frame turn shows the turn at ``360 * k / count``
degrees, is sampled with seed ``seed + k`` and is stored as
``frame_000k.exr`` (linear, half float, with the job's metadata in the
header) and ``frame_000k.png`` (sRGB preview).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from .images import read_exr, write_exr, write_png

__all__ = [
    "JOB_KEYS",
    "Frame",
    "atomic_path",
    "frame_angle",
    "frame_pngs",
    "frame_state",
    "frame_stem",
    "plan_frames",
    "write_frame",
]

#: Header attributes a finished frame must match to be skipped on resume.
JOB_KEYS = ("count", "angle_deg", "mode", "object", "spp", "seed", "integrator")


@dataclass(frozen=True)
class Frame:
    """One frame of the turn: index, angle, sampler seed and output files."""

    index: int
    count: int
    angle_deg: float
    seed: int
    exr: str
    png: str


def frame_angle(index: int, count: int) -> float:
    """Angle of frame ``index`` of a full turn in ``count`` frames, in degrees."""
    return 360.0 * index / count


def frame_stem(index: int, count: int) -> str:
    """``frame_0007``: four digits, more when the turn needs them."""
    digits = max(4, len(str(count - 1)))
    return f"frame_{index:0{digits}d}"


def plan_frames(count: int, frames: Sequence[int], out_dir: str | os.PathLike, seed: int = 0) -> list[Frame]:
    """The :class:`Frame` list for ``frames`` (indices) of a ``count``-frame
    turn written to ``out_dir``; frame ``k`` is sampled with seed ``seed + k``."""
    out_dir = os.fspath(out_dir)
    plan = []
    for index in frames:
        stem = os.path.join(out_dir, frame_stem(index, count))
        angle = frame_angle(index, count)
        plan.append(Frame(index, count, angle, seed + index, stem + ".exr", stem + ".png"))
    return plan


def frame_state(
    frame: Frame, expect: dict[str, object] | None = None, size: tuple[int, int] | None = None
) -> str:
    """Is ``frame`` already on disk? ``"missing"`` (no complete EXR + PNG
    pair, or an unreadable EXR), ``"stale"`` (a readable frame of another
    job: a header attribute differs from ``expect``, or the image from
    ``size`` = (width, height)) or ``"done"``."""
    if not (os.path.isfile(frame.exr) and os.path.isfile(frame.png)):
        return "missing"
    try:
        pixels, header = read_exr(frame.exr)
    except Exception:  # truncated or foreign file: render it again
        return "missing"
    if size is not None and tuple(pixels.shape[:2]) != (size[1], size[0]):
        return "stale"
    for key, value in (expect or {}).items():
        if key not in header or not _same(header[key], value):
            return "stale"
    return "done"


def _same(stored: object, value: object) -> bool:
    """Header value equality; floats to round-off (they went through text
    or float32 in some writers)."""
    if isinstance(value, float):
        try:
            return math.isclose(float(stored), value, rel_tol=1e-6, abs_tol=1e-9)
        except (TypeError, ValueError):
            return False
    return stored == value


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """A temporary name to write ``path`` under: renamed to ``path`` when the
    ``with`` block completes, removed when it fails. The name is hidden,
    unique to this process and keeps the extension (Mitsuba and imageio pick
    the format from it)."""
    folder, name = os.path.split(os.fspath(path))
    stem, ext = os.path.splitext(name)
    tmp = os.path.join(folder, f".{stem}.{os.getpid()}.tmp{ext}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def write_frame(frame: Frame, rgb: np.ndarray, metadata: dict[str, object]) -> None:
    """Write a frame's half-float EXR (with ``metadata``) and sRGB PNG
    atomically, the EXR last: a frame whose EXR exists is complete."""
    with atomic_path(frame.exr) as tmp_exr:
        with atomic_path(frame.png) as tmp_png:
            write_png(tmp_png, rgb)
            write_exr(tmp_exr, rgb, metadata, half=True)


def frame_pngs(out_dir: str | os.PathLike, count: int) -> list[str]:
    """PNGs of all frames of a ``count``-frame turn present in ``out_dir``,
    in frame order."""
    out_dir = os.fspath(out_dir)
    pattern = re.compile(r"frame_(\d+)\.png")
    found = []
    for name in os.listdir(out_dir):
        match = pattern.fullmatch(name)
        if match and int(match.group(1)) < count and name == frame_stem(int(match.group(1)), count) + ".png":
            found.append((int(match.group(1)), os.path.join(out_dir, name)))
    return [path for _, path in sorted(found)]
