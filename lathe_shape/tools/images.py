"""Image files (linear EXR through the OpenEXR package, sRGB PNG previews)
and the one image-error metric every tool, script and test uses."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext

import numpy as np
import OpenEXR

__all__ = [
    "atomic_path",
    "image_errors",
    "read_exr",
    "relative_error",
    "to_srgb8",
    "write_exr",
    "write_images",
    "write_png",
]


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


def write_exr(
    path: str | os.PathLike,
    rgb: np.ndarray,
    metadata: dict[str, object] | None = None,
    half: bool = False,
    layers: dict[str, np.ndarray] | None = None,
) -> None:
    """Write an (H, W, 3) linear RGB image as a ZIP-compressed scanline EXR.

    ``metadata`` entries (str, int, float) become EXR header attributes;
    ``half`` stores 16-bit floats; each (H, W, 3) image of ``layers`` is
    stored as ``NAME.R``, ``NAME.G``, ``NAME.B``.
    """
    dtype = np.float16 if half else np.float32
    channels = {name: np.ascontiguousarray(np.asarray(image)[..., :3], dtype=dtype)
                for name, image in {"RGB": rgb, **(layers or {})}.items()}
    header: dict[str, object] = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
    }
    for key, value in (metadata or {}).items():
        header[key] = value if isinstance(value, (int, float)) else str(value)
    with OpenEXR.File(header, channels) as exr:
        exr.write(os.fspath(path))


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, object]]:
    """Read an RGB EXR written by :func:`write_exr`: (pixels float32, header)."""
    with OpenEXR.File(os.fspath(path)) as exr:
        header = dict(exr.header())
        channels = exr.channels()
        if "RGB" in channels:
            pixels = channels["RGB"].pixels
        else:
            pixels = np.stack([channels[c].pixels for c in "RGB"], axis=-1)
    return np.asarray(pixels, dtype=np.float32), header


def to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (IEC 61966-2-1 transfer curve), clipped."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64)[..., :3]), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def write_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write a linear RGB image as an sRGB 8-bit PNG preview."""
    import mitsuba as mi

    mi.Bitmap(to_srgb8(rgb), pixel_format=mi.Bitmap.PixelFormat.RGB).write(os.fspath(path))


def write_images(stem: str, rgb: np.ndarray, metadata: dict[str, object] | None = None,
                 png: bool = True, half: bool = False,
                 layers: dict[str, np.ndarray] | None = None) -> list[str]:
    """Write ``STEM.exr`` (with ``metadata``) and, when ``png``, the sRGB
    preview ``STEM.png``, each under a temporary name renamed when both are
    complete (the EXR last), so that an interrupted write leaves no partial
    file; returns the paths written. ``half`` and ``layers`` as in
    :func:`write_exr`."""

    paths = [stem + ".exr", stem + ".png"] if png else [stem + ".exr"]
    with atomic_path(paths[0]) as tmp_exr, (atomic_path(paths[1]) if png else nullcontext()) as tmp_png:
        if tmp_png:
            write_png(tmp_png, rgb)
        write_exr(tmp_exr, rgb, metadata, half, layers)
    return paths


def image_errors(
    image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None
) -> dict[str, float]:
    """Error of ``image`` against ``reference`` (same shape), over the pixels
    of ``mask`` (an (H, W) boolean array) when given.

    ``rel_mae``: mean absolute difference / mean of the reference (the
    project's "relative error"); ``rel_rmse``: RMS difference / mean of the
    reference; ``bias``: (mean image - mean reference) / mean reference;
    ``max_abs``: largest absolute difference; ``mean_reference``.
    """
    image = np.asarray(image, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if image.shape != reference.shape:
        raise ValueError(f"image_errors: shapes differ, {image.shape} vs {reference.shape}")
    if mask is not None:
        image, reference = image[mask], reference[mask]
    diff = image - reference
    mean = float(reference.mean()) or 1.0
    return {
        "rel_mae": float(np.abs(diff).mean() / mean),
        "rel_rmse": float(np.sqrt(np.square(diff).mean()) / mean),
        "bias": float(diff.mean() / mean),
        "max_abs": float(np.abs(diff).max()),
        "mean_reference": float(reference.mean()),
    }


def relative_error(image: np.ndarray, reference: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean absolute difference divided by the reference's mean (the
    ``rel_mae`` of :func:`image_errors`)."""
    return image_errors(image, reference, mask)["rel_mae"]
