"""Animations from PNG frames: a looping GIF (imageio + pillow) or an H.264
MP4 (imageio-ffmpeg), both optional dependencies (``lathe_shape[video]``).
Files are written under a temporary name and renamed when complete."""

from __future__ import annotations

import importlib
import os
from collections.abc import Sequence
from types import ModuleType

import numpy as np

from .images import atomic_path

__all__ = ["FORMATS", "VideoError", "require_video", "write_video"]

#: The animation formats and the modules each one's writer imports.
FORMATS = {"gif": ("imageio.v3", "PIL"), "mp4": ("imageio_ffmpeg",)}


class VideoError(RuntimeError):
    """An animation cannot be written; the message says why."""


def require_video(fmt: str, what: str | None = None) -> list[ModuleType]:
    """Import the modules the ``fmt`` writer needs (to check up front, before
    hours of rendering); ``what`` names the request in the error message
    (default: "GIF output")."""
    modules = []
    for name in FORMATS[fmt]:
        try:
            modules.append(importlib.import_module(name))
        except ImportError as e:
            raise VideoError(
                f"{what or fmt.upper() + ' output'} needs the optional video dependencies "
                f"(missing: {e.name or name}): pip install lathe_shape[video]"
            ) from None
    return modules


def _read_pngs(pngs: Sequence[str], fmt: str) -> list[np.ndarray]:
    """The frames as (H, W, 3) uint8 arrays, all of one size."""
    import mitsuba as mi

    if not pngs:
        raise VideoError(f"no frames to put in the {fmt.upper()}")
    rgb8 = (mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, True)
    images = [np.asarray(mi.Bitmap(p).convert(*rgb8)) for p in pngs]
    shapes = {im.shape for im in images}
    if len(shapes) > 1:
        raise VideoError(
            "the frames have different sizes (" + ", ".join(f"{s[1]}x{s[0]}" for s in sorted(shapes))
            + "); render them all at the same resolution"
        )
    return images


def _write_gif(modules: list[ModuleType], images: list[np.ndarray], path: str, fps: float) -> None:
    iio = modules[0]
    # Pillow's GIF durations are whole milliseconds.
    iio.imwrite(path, np.stack(images), extension=".gif", plugin="pillow",
                duration=int(round(1000.0 / fps)), loop=0)


def _write_mp4(modules: list[ModuleType], images: list[np.ndarray], path: str, fps: float) -> None:
    # yuv420p needs even sizes: odd ones are padded by one pixel.
    height, width = images[0].shape[:2]
    pad = ((0, height % 2), (0, width % 2), (0, 0))
    writer = modules[0].write_frames(
        path, (width + width % 2, height + height % 2), fps=fps, codec="libx264",
        pix_fmt_in="rgb24", pix_fmt_out="yuv420p", macro_block_size=1, quality=8,
        ffmpeg_log_level="error",
    )
    writer.send(None)  # start ffmpeg
    try:
        for image in images:
            writer.send(np.ascontiguousarray(np.pad(image, pad, mode="edge")))
    finally:
        writer.close()


_WRITERS = {"gif": _write_gif, "mp4": _write_mp4}


def write_video(pngs: Sequence[str], path: str | os.PathLike, fps: float, fmt: str | None = None) -> None:
    """Assemble the PNG frames ``pngs`` into the animation ``path`` at ``fps``
    frames per second; ``fmt`` ("gif" or "mp4") defaults to the extension."""
    path = os.fspath(path)
    fmt = fmt or os.path.splitext(path)[1].lstrip(".").lower()
    if fmt not in _WRITERS:
        raise VideoError(f"'{path}': unknown animation format (expected one of: {', '.join(FORMATS)})")
    modules = require_video(fmt)
    images = _read_pngs(pngs, fmt)
    try:
        with atomic_path(path) as tmp:
            _WRITERS[fmt](modules, images, tmp, fps)
    except (OSError, RuntimeError) as e:
        raise VideoError(f"could not write '{path}': {e}") from None
