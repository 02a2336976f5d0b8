"""Image files (linear EXR through the OpenEXR package, sRGB PNG previews)
and the one image-error metric every tool, script and test uses."""

from __future__ import annotations

import os
import struct
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, nullcontext

import numpy as np
import OpenEXR

__all__ = [
    "DEFAULT_CHANNELS",
    "atomic_path",
    "encode_png",
    "channel_names",
    "image_channel_count",
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


#: Channel names of an image given without names, by its channel count
#: (Mitsuba's names for its films' pixel formats: luminance, luminance_alpha,
#: rgb, rgba).
DEFAULT_CHANNELS = {1: ("Y",), 2: ("Y", "A"), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}


def _channels(image: np.ndarray) -> np.ndarray:
    """``image`` as an (H, W, C) array (an (H, W) image has one channel)."""
    image = np.asarray(image)
    return image[..., None] if image.ndim == 2 else image


def channel_names(image: np.ndarray, channels: Sequence[str] | None = None) -> list[str]:
    """The names of ``image``'s channels: ``channels`` (checked against the
    channel count) or, when None, :data:`DEFAULT_CHANNELS`."""
    count = _channels(image).shape[-1]
    if channels is None:
        if count not in DEFAULT_CHANNELS:
            raise ValueError(f"an image of {count} channels needs channel names (1 to 4 have defaults)")
        return list(DEFAULT_CHANNELS[count])
    if len(channels) != count:
        raise ValueError(f"{len(channels)} channel names for an image of {count} channels")
    return list(channels)


def image_channel_count(channels: Sequence[str]) -> int:
    """How many leading ``channels`` are the image itself (R, G, B, A or Y,
    A): those before the first AOV, whose names hold a dot (``albedo.R``,
    as Mitsuba names an integrator's AOVs)."""
    count = 0
    while count < len(channels) and "." not in channels[count]:
        count += 1
    return count


def write_exr(
    path: str | os.PathLike,
    rgb: np.ndarray,
    metadata: dict[str, object] | None = None,
    half: bool = False,
    layers: dict[str, np.ndarray] | None = None,
    channels: Sequence[str] | None = None,
) -> None:
    """Write an (H, W, C) linear image as a ZIP-compressed scanline EXR, every
    channel under its name: ``channels`` (e.g. Mitsuba's film channels ``R``,
    ``G``, ``B``, ``A``, ``albedo.R``, ...), by default those of
    :data:`DEFAULT_CHANNELS` (``R``, ``G``, ``B`` for three channels).

    ``metadata`` entries (str, int, float) become EXR header attributes;
    ``half`` stores 16-bit floats; each image of ``layers`` (default channel
    names) is stored as ``NAME.R``, ``NAME.G``, ``NAME.B`` (``NAME.Y`` for one
    channel, ...).
    """
    dtype = np.float16 if half else np.float32
    stored = {}
    for prefix, image, names in [("", rgb, channels),
                                 *((f"{name}.", image, None) for name, image in (layers or {}).items())]:
        image = _channels(image)
        for index, name in enumerate(channel_names(image, names)):
            stored[prefix + name] = np.ascontiguousarray(image[..., index], dtype=dtype)
    header: dict[str, object] = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
    }
    for key, value in (metadata or {}).items():
        header[key] = value if isinstance(value, (int, float)) else str(value)
    with OpenEXR.File(header, stored) as exr:
        exr.write(os.fspath(path))


def read_exr(path: str | os.PathLike) -> tuple[np.ndarray, dict[str, object]]:
    """Read an EXR written by :func:`write_exr`: (pixels float32, header), the
    pixels (H, W, 3) RGB (alpha and AOV channels left out), or (H, W, 1) for
    a luminance (``Y``) image."""
    with OpenEXR.File(os.fspath(path)) as exr:
        header = dict(exr.header())
        channels = exr.channels()
        # OpenEXR groups R, G, B (and A) into one entry where it can
        grouped = next((name for name in ("RGB", "RGBA") if name in channels), None)
        if grouped is not None:
            pixels = channels[grouped].pixels[..., :3]
        elif "Y" in channels:
            luminance = channels["Y"].pixels
            pixels = luminance[..., None] if luminance.ndim == 2 else luminance[..., :1]
        else:
            pixels = np.stack([channels[c].pixels for c in "RGB"], axis=-1)
    return np.asarray(pixels, dtype=np.float32), header


def to_srgb8(rgb: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB (IEC 61966-2-1 transfer curve), clipped."""
    x = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float64)[..., :3]), 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    """One PNG chunk: length, type, data, CRC-32 of type and data."""
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


#: PNG colour types by channel count: gray, gray + alpha, RGB, RGBA.
_PNG_COLOUR_TYPES = {1: 0, 2: 4, 3: 2, 4: 6}
#: The chunks that mark a PNG as sRGB: ``sRGB`` (rendering intent
#: perceptual), and for readers that do not know it ``gAMA`` (1 / 2.2, in
#: units of 1e-5) and ``cHRM`` (the sRGB white point and primaries, x and y
#: in units of 1e-5), as the PNG specification recommends.
_PNG_SRGB_CHUNKS = [
    (b"sRGB", b"\x00"),
    (b"gAMA", struct.pack(">I", 45455)),
    (b"cHRM", struct.pack(">8I", 31270, 32900, 64000, 33000, 30000, 60000, 15000, 6000)),
]
#: Pixels :func:`write_png` converts at a time: its float64 temporaries then
#: take a few MB, not dozens of bytes per pixel of the whole image (a
#: turntable encodes several frames at once).
_PNG_BAND_PIXELS = 1 << 18


def encode_png(pixels: np.ndarray, compression: int = 6) -> bytes:
    """An (H, W, C) uint8 image (C = 1 to 4: gray, gray + alpha, RGB, RGBA;
    H, W at least 1) as the bytes of an 8-bit PNG file marked sRGB, its
    scanlines unfiltered and zlib-compressed at level ``compression`` (1:
    fastest; zlib releases the GIL, so frames encode in parallel threads)."""
    pixels = _channels(pixels)
    if pixels.dtype != np.uint8 or pixels.ndim != 3 or pixels.shape[2] not in _PNG_COLOUR_TYPES \
            or 0 in pixels.shape:
        raise ValueError(f"encode_png: need (H, W, 1..4) uint8 pixels, H and W at least 1, "
                         f"got {pixels.shape} {pixels.dtype}")
    height, width, count = pixels.shape
    rows = np.zeros((height, width * count + 1), dtype=np.uint8)  # a filter byte (0: none) per row
    rows[:, 1:] = pixels.reshape(height, width * count)
    header = struct.pack(">IIBBBBB", width, height, 8, _PNG_COLOUR_TYPES[count], 0, 0, 0)
    return b"".join([
        b"\x89PNG\r\n\x1a\n",
        _png_chunk(b"IHDR", header),
        *(_png_chunk(kind, data) for kind, data in _PNG_SRGB_CHUNKS),
        _png_chunk(b"IDAT", zlib.compress(rows, compression)),
        _png_chunk(b"IEND", b""),
    ])


def _png_pixels(image: np.ndarray) -> np.ndarray:
    """The 8-bit sRGB pixels of an (H, W, 1..4) linear image (see
    :func:`write_png`)."""
    count = image.shape[-1]
    colour = np.asarray(image[..., :3 if count >= 3 else 1], dtype=np.float64)
    if count not in (2, 4):
        return to_srgb8(colour)
    alpha = np.clip(np.nan_to_num(np.asarray(image[..., -1:], dtype=np.float64)), 0.0, 1.0)
    straight = np.divide(colour, alpha, out=np.zeros_like(colour), where=alpha > 0)
    return np.concatenate([to_srgb8(straight), np.round(alpha * 255.0).astype(np.uint8)], axis=-1)


def write_png(path: str | os.PathLike, rgb: np.ndarray, compression: int = 6) -> None:
    """Write a linear image as an sRGB 8-bit PNG preview: one channel (``Y``)
    gray, two (``Y``, ``A``) gray with alpha, three RGB, four RGB with alpha.
    Mitsuba's films store colour multiplied by alpha; PNG stores it divided
    (straight alpha), so colour is divided by alpha here and alpha is kept
    linear. ``compression``: zlib level, 1 (fastest) to 9."""
    image = _channels(rgb)
    count = image.shape[-1]
    if count not in _PNG_COLOUR_TYPES:
        raise ValueError(f"write_png: an image of {count} channels is not gray, gray-alpha, RGB or RGBA")
    if image.ndim != 3:
        raise ValueError(f"write_png: need an (H, W) or (H, W, C) image, got shape {image.shape}")
    pixels = np.empty(image.shape, dtype=np.uint8)
    band = max(1, _PNG_BAND_PIXELS // max(1, image.shape[1]))  # rows converted at a time
    for top in range(0, image.shape[0], band):
        pixels[top:top + band] = _png_pixels(image[top:top + band])
    data = encode_png(pixels, compression)
    with open(path, "wb") as f:
        f.write(data)


def write_images(stem: str, rgb: np.ndarray, metadata: dict[str, object] | None = None,
                 png: bool = True, half: bool = False,
                 layers: dict[str, np.ndarray] | None = None,
                 channels: Sequence[str] | None = None, png_compression: int = 6) -> list[str]:
    """Write ``STEM.exr`` (with ``metadata``; every channel of ``rgb``, named
    as in :func:`write_exr`) and, when ``png``, the sRGB preview ``STEM.png``
    of the image's own channels (:func:`image_channel_count`: AOVs are left
    out), each under a temporary name renamed when both are complete (the EXR
    last), so that an interrupted write leaves no partial file; returns the
    paths written. ``half`` and ``layers`` as in :func:`write_exr`;
    ``png_compression`` as in :func:`write_png`."""

    names = channel_names(rgb, channels)
    paths = [stem + ".exr", stem + ".png"] if png else [stem + ".exr"]
    with atomic_path(paths[0]) as tmp_exr, (atomic_path(paths[1]) if png else nullcontext()) as tmp_png:
        if tmp_png:
            write_png(tmp_png, _channels(rgb)[..., :image_channel_count(names)], png_compression)
        write_exr(tmp_exr, rgb, metadata, half, layers, names)
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
