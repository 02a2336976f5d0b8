"""Denoising rendered frames: Intel Open Image Denoise (``pyoidn``, the
optional extra ``lathe_shape[denoise]``, on the CPU) or, on CUDA variants
where it is known to be safe, Mitsuba's OptiX denoiser.

Both take the albedo and normal guides the ``lathe_path`` integrator renders
as AOVs (its ``aovs`` parameter). Without guides a denoiser keeps the sparse
caustic speckles of glass on a textured floor (they look like texture to
it); the albedo guide tells it what is texture.

OptiX is used only when its weights file ships with the driver
(``/usr/share/nvidia/nvoptix.bin``): without it, constructing and running
``mi.OptixDenoiser`` ends the process with no Python exception to catch.
Otherwise OIDN is used, and :func:`choose_backend` says why.

Frames to denoise are rendered with a ``box`` reconstruction filter
(:func:`box_filter_xml`): a wider filter (Mitsuba's default ``gaussian``)
splats each sample into neighbouring pixels, and the denoiser then takes the
correlated noise for detail and keeps it. Sampling them with
``multijitter`` in place of ``independent`` (:func:`multijitter_xml`) lowers
their error after denoising: behind glass the guides are noisy mostly where
a pixel's samples land on different surfaces (the edges of a refracted
texture) or take different lobes at the glass, and stratifying both within
each pixel makes the guides, and the image, less noisy.
"""

from __future__ import annotations

import importlib
import os
import threading
import xml.etree.ElementTree as ET

import numpy as np

from .scenes import blank_comments

__all__ = [
    "BACKENDS",
    "OPTIX_WEIGHTS",
    "DenoiseError",
    "GUIDE_QUALITY",
    "Denoiser",
    "STRATIFIED_SAMPLER",
    "box_filter_xml",
    "choose_backend",
    "multijitter_xml",
    "oidn_filter",
    "prefilter_guides",
    "rendered_spp",
]

#: The denoisers, by name.
BACKENDS = ("oidn", "optix")
#: Where the NVIDIA driver keeps the OptiX denoiser's weights.
OPTIX_WEIGHTS = "/usr/share/nvidia/nvoptix.bin"
#: The sampler of :func:`multijitter_xml`, in place of ``independent``.
STRATIFIED_SAMPLER = "multijitter"
#: OIDN's quality setting for prefiltering guides (``OIDN_QUALITY_BALANCED``).
GUIDE_QUALITY = 5


class DenoiseError(RuntimeError):
    """No denoiser can run; the message says what to install."""


def _has_oidn() -> bool:
    try:
        importlib.import_module("pyoidn")
    except ImportError:
        return False
    return True


def _parse(xml_text: str, source: str) -> ET.Element:
    try:
        return ET.fromstring(blank_comments(xml_text.encode("utf-8")).decode("utf-8"))
    except ET.ParseError as e:
        raise DenoiseError(f"{source}: not a valid XML file ({e})") from None


def box_filter_xml(xml_text: str, source: str = "scene") -> str:
    """The scene text with every film's reconstruction filter set to
    ``box`` (the filter a denoiser expects: independent pixel noise)."""
    root = _parse(xml_text, source)
    for film in root.iter("film"):
        for old in film.findall("rfilter"):
            film.remove(old)
        ET.SubElement(film, "rfilter", {"type": "box"})
    return ET.tostring(root, encoding="unicode")


def multijitter_xml(xml_text: str, source: str = "scene") -> str:
    """The scene text with every sensor's ``independent`` sampler
    (Mitsuba's default, also where a sensor names none) replaced by
    :data:`STRATIFIED_SAMPLER`, with the same sample count and seed; other
    samplers, and a type given by a ``$`` parameter, are kept. Stratified
    pixel positions and BSDF choices make the guides behind glass, and the
    image, less noisy (``lathe-turntable --multijitter``)."""
    root = _parse(xml_text, source)
    for sensor in root.iter("sensor"):
        samplers = sensor.findall("sampler")
        if not samplers:
            ET.SubElement(sensor, "sampler", {"type": STRATIFIED_SAMPLER})
        for sampler in samplers:
            if sampler.get("type") == "independent":
                sampler.set("type", STRATIFIED_SAMPLER)
    return ET.tostring(root, encoding="unicode")


def rendered_spp(sampler: object, spp: int) -> int:
    """The samples per pixel ``mi.render`` takes for ``spp`` with the
    ``mi.Sampler`` ``sampler``: ``multijitter`` rounds a count up to a
    product of two near-equal integers (10 to 12; 16 stays 16). Sets the
    sampler's count, as ``mi.render`` does."""
    sampler.set_sample_count(spp)
    return int(sampler.sample_count())


def choose_backend(variant: str, weights: str = OPTIX_WEIGHTS) -> tuple[str, str]:
    """(backend, note): OptiX on a CUDA ``variant`` whose driver has the
    weights file, else OIDN; ``note`` explains a fall-back ("" when none).
    Raises :class:`DenoiseError` when neither is available."""
    note = ""
    if variant.startswith("cuda"):
        if os.path.isfile(weights):
            return "optix", ""
        note = f"OptiX denoiser weights ({weights}) missing: denoising with Intel Open Image Denoise"
    if _has_oidn():
        return "oidn", note
    raise DenoiseError(
        "denoising needs Intel Open Image Denoise (module 'pyoidn' not found): "
        "pip install lathe_shape[denoise]"
    )


#: The OIDN device of :func:`oidn_filter`, made at its first call, and its
#: filters by slots and parameters (set up once: OIDN builds a filter's
#: network at its first commit; later commits only take the new images).
_OIDN_DEVICE = None
_OIDN_FILTERS: dict[tuple, object] = {}
_OIDN_LOCK = threading.Lock()


def _cached_filter(slots: tuple[str, ...], params: dict[str, object]) -> object:
    import pyoidn

    global _OIDN_DEVICE
    if _OIDN_DEVICE is None:
        _OIDN_DEVICE = pyoidn.Device()
        _OIDN_DEVICE.commit()
    key = (slots, tuple(sorted(params.items())))
    if key not in _OIDN_FILTERS:
        oidn = pyoidn.Filter(_OIDN_DEVICE, pyoidn.OIDN_FILTER_TYPE_RT)
        for name, value in params.items():
            oidn.set_value(name, value)
        _OIDN_FILTERS[key] = oidn
    return _OIDN_FILTERS[key]


def oidn_filter(images: dict[str, np.ndarray], **params: object) -> np.ndarray:
    """Run an OIDN ``RT`` filter on the (H, W, 3) ``images`` given by slot
    (``color``, ``albedo``, ``normal``) with the filter parameters
    ``params`` (``hdr``, ``cleanAux``, ...): the output, float32.

    Unlike ``pyoidn.denoise``, the slots are free: an ``albedo`` (or
    ``normal``) alone selects OIDN's own weights for denoising that guide,
    the prefiltering OIDN documents for noisy guides."""
    import pyoidn

    inputs = {name: np.ascontiguousarray(image, dtype=np.float32) for name, image in images.items()}
    output = np.zeros_like(next(iter(inputs.values())))
    # One filter at a time (frames are denoised on a writer thread while the
    # next one renders).
    with _OIDN_LOCK:
        oidn = _cached_filter(tuple(inputs), params)
        for name, image in inputs.items():
            oidn.set_image(name, image, pyoidn.OIDN_FORMAT_FLOAT3)
        oidn.set_image(pyoidn.OIDN_IMAGE_OUTPUT, output, pyoidn.OIDN_FORMAT_FLOAT3)
        oidn.commit()
        oidn.execute()
        error = _OIDN_DEVICE.get_error()
    if error is not None:
        raise DenoiseError(f"Intel Open Image Denoise failed: {error}")
    return output


def prefilter_guides(albedo: np.ndarray, normal: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Denoise the albedo and normal guides themselves, each with OIDN's
    weights for that guide alone (OIDN's recommended prefiltering of guides
    rendered with few samples; the filtered guides are then declared clean).

    Behind glass the guides are noisy too: with ``lathe_path``'s
    ``aov_through_delta`` guides each sample of a pixel chooses reflection or
    refraction at random, so the guides of its first diffuse hit mix
    different surfaces. Given noisy guides, the denoiser keeps part of the
    colour noise as if it were detail; prefiltered guides lower the error of
    denoised glass pixels, the guide-only filters more than OIDN's colour
    filter run on a guide (docs/turntables.md)."""
    # OIDN's "balanced" quality: as close as "high" on the glass, faster.
    albedo = oidn_filter({"albedo": np.clip(albedo, 0.0, 1.0)}, quality=GUIDE_QUALITY)
    if normal is not None:
        normal = oidn_filter({"normal": np.clip(normal, -1.0, 1.0)}, quality=GUIDE_QUALITY)
    return albedo, normal


class Denoiser:
    """Denoises (H, W, 3) linear HDR images with optional albedo and normal
    guides of the same size; ``backend`` is ``"oidn"`` or ``"optix"``.
    OptiX wants normals in the sensor's frame: ``to_sensor`` is the sensor's
    world-to-camera transform (``sensor.world_transform().inverse()``)."""

    def __init__(self, backend: str = "oidn", to_sensor: object | None = None) -> None:
        if backend not in BACKENDS:
            raise DenoiseError(f"unknown denoiser '{backend}' (expected one of: {', '.join(BACKENDS)})")
        self.backend = backend
        self._optix = None
        self._to_sensor = to_sensor

    def __call__(self, rgb: np.ndarray, albedo: np.ndarray | None = None,
                 normal: np.ndarray | None = None) -> np.ndarray:
        """The denoised image (float32, the shape of ``rgb``)."""
        rgb = np.ascontiguousarray(rgb, dtype=np.float32)
        if self.backend == "optix":
            return self._run_optix(rgb, albedo, normal)
        if albedo is None:
            # OIDN takes normals only together with an albedo.
            return oidn_filter({"color": np.maximum(rgb, 0.0)}, hdr=True)
        albedo, normal = prefilter_guides(albedo, normal)
        guides = {"albedo": albedo} if normal is None else {"albedo": albedo, "normal": normal}
        return oidn_filter({"color": np.maximum(rgb, 0.0), **guides}, hdr=True, cleanAux=True)

    def _run_optix(self, rgb: np.ndarray, albedo: np.ndarray | None,
                   normal: np.ndarray | None) -> np.ndarray:
        import mitsuba as mi

        size = mi.ScalarVector2u(rgb.shape[1], rgb.shape[0])
        if self._optix is None:
            self._optix = mi.OptixDenoiser(size, albedo=albedo is not None, normals=normal is not None)
        guides = {}
        if albedo is not None:
            guides["albedo"] = mi.TensorXf(np.ascontiguousarray(albedo, dtype=np.float32))
        if normal is not None:
            guides["normals"] = mi.TensorXf(np.ascontiguousarray(normal, dtype=np.float32))
            guides["to_sensor"] = self._to_sensor
        return np.asarray(self._optix(mi.TensorXf(rgb), **guides).numpy(), dtype=np.float32)
