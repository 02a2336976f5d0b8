"""The frames of a turntable on disk: which file holds which frame, whether a
frame is already done (to resume an interrupted or sharded job), and writes
that never leave a half-written file under a final name.

Frame ``k`` of a ``count``-frame turn shows the turn at ``360 * k / count``
degrees, is sampled with seed ``seed + k`` and is stored as
``frame_000k.exr`` (linear, half float, with the job's metadata in the
header) and ``frame_000k.png`` (sRGB preview). A denoised frame's EXR holds
the denoised image as RGB and the noisy one as the layer ``noisy``
(channels ``noisy.R``, ``noisy.G``, ``noisy.B``); its PNG shows the
denoised image.

With ``same_seed`` every frame is sampled with ``seed`` itself: the noise
then stays put on the screen from frame to frame instead of flickering
(the CLI's default; see ``lathe-turntable --seeds``).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from .images import read_exr, write_images

__all__ = [
    "JOB_KEYS",
    "Frame",
    "inputs_digest",
    "FramePlan",
    "frame_angle",
    "frame_pngs",
    "frame_state",
    "frame_stem",
    "plan_frames",
    "png_complete",
    "write_frame",
]

#: Header attributes a finished frame must match to be skipped on resume
#: (``defines``: the -D values; ``inputs``: :func:`inputs_digest`).
JOB_KEYS = ("count", "angle_deg", "mode", "object", "spp", "seed", "integrator", "denoiser", "sampler",
            "variant", "defines", "inputs")


def inputs_digest(scene_path: str, profile_files: list[str]) -> str:
    """A digest (16 hex digits of SHA-256) of the scene file's bytes and of
    its lathes' profile files (``profile_files``, those that exist): an
    edited scene or profile makes the frames another job's."""
    import hashlib

    digest = hashlib.sha256()
    for path in [scene_path, *sorted(set(profile_files))]:
        if os.path.isfile(path):
            digest.update(os.path.abspath(path).encode() + b"\0")
            with open(path, "rb") as f:
                digest.update(hashlib.sha256(f.read()).digest())
    return digest.hexdigest()[:16]


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


class FramePlan(Sequence[Frame]):
    """The frames ``frames`` (indices) of a ``count``-frame turn, made when
    asked for (a plan holds its indices, not a :class:`Frame` per index: a
    turn may have a million frames). ``plan[k]`` is the k-th frame of the
    plan, :meth:`frame` the frame of a given index."""

    def __init__(self, count: int, frames: Sequence[int], out_dir: str | os.PathLike, seed: int = 0,
                 same_seed: bool = False) -> None:
        self.count, self.indices, self.out_dir = count, frames, os.fspath(out_dir)
        self.seed, self.same_seed = seed, same_seed

    def frame(self, index: int) -> Frame:
        """Frame ``index`` of the turn."""
        stem = os.path.join(self.out_dir, frame_stem(index, self.count))
        frame_seed = self.seed if self.same_seed else self.seed + index
        return Frame(index, self.count, frame_angle(index, self.count), frame_seed, stem + ".exr",
                     stem + ".png")

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, position):  # (int -> Frame; slice -> FramePlan)
        if isinstance(position, slice):
            return FramePlan(self.count, self.indices[position], self.out_dir, self.seed, self.same_seed)
        return self.frame(self.indices[position])

    def __iter__(self) -> Iterator[Frame]:
        return (self.frame(index) for index in self.indices)


def plan_frames(count: int, frames: Sequence[int], out_dir: str | os.PathLike, seed: int = 0,
                same_seed: bool = False) -> FramePlan:
    """The :class:`Frame` sequence (a :class:`FramePlan`, made lazily) for
    ``frames`` (indices) of a ``count``-frame turn written to ``out_dir``;
    frame ``k`` is sampled with seed ``seed + k`` (``seed`` for all frames
    with ``same_seed``)."""
    return FramePlan(count, frames, out_dir, seed, same_seed)


#: The last chunk of every PNG file: length 0, ``IEND``, its CRC-32.
_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def png_complete(path: str | os.PathLike, width: int, height: int) -> bool:
    """Whether ``path`` looks like a whole ``width`` x ``height`` PNG: the
    PNG signature, an ``IHDR`` chunk of that size, and the ``IEND`` chunk at
    the very end (a truncated or foreign file lacks one of them). Reads 33
    bytes at the start and 12 at the end, not the image."""
    try:
        with open(path, "rb") as f:
            head = f.read(33)
            if len(head) < 33 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[8:16] != b"\x00\x00\x00\x0dIHDR":
                return False
            if (int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")) != (width, height):
                return False
            f.seek(-len(_PNG_END), os.SEEK_END)
            return f.read() == _PNG_END
    except OSError:
        return False


def frame_state(
    frame: Frame, expect: dict[str, object] | None = None, size: tuple[int, int] | None = None
) -> str:
    """Is ``frame`` already on disk? ``"missing"`` (no complete EXR + PNG
    pair: an unreadable EXR, or a PNG that is not whole or not of the EXR's
    size, see :func:`png_complete`), ``"stale"`` (a readable frame of
    another job: a header attribute differs from ``expect``, or the image
    from ``size`` = (width, height)) or ``"done"``."""
    if not (os.path.isfile(frame.exr) and os.path.isfile(frame.png)):
        return "missing"
    try:
        pixels, header = read_exr(frame.exr)
    except Exception:  # truncated or foreign file: render it again
        return "missing"
    if not png_complete(frame.png, pixels.shape[1], pixels.shape[0]):
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


def write_frame(frame: Frame, rgb: np.ndarray, metadata: dict[str, object],
                noisy: np.ndarray | None = None) -> None:
    """Write a frame's half-float EXR (with ``metadata``; ``noisy``, when
    given, as the layer ``noisy``) and sRGB PNG atomically, the EXR last: a
    frame whose EXR exists is complete. The PNG takes zlib's fastest level:
    a turntable writes hundreds of them."""
    write_images(os.path.splitext(frame.exr)[0], rgb, metadata, half=True,
                 layers=None if noisy is None else {"noisy": noisy}, png_compression=1)


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
