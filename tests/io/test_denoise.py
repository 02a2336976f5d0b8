"""OIDN filtering (lathe_shape.tools.denoise): guide prefiltering with the
guide-only filters and guided denoising of a textured image; the
multijitter sampler of lathe-turntable --multijitter."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mitsuba as mi
import numpy as np
import OpenEXR
import pytest
from conftest import SCENES, VARIANT

from lathe_shape.cli.turntable import main
from lathe_shape.tools import denoise as dn

pytest.importorskip("pyoidn")

pytestmark = pytest.mark.denoise


def checker_scene(size: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(radiance, albedo, normal) of a flat checkered surface under a smooth
    light: the radiance is the albedo times the light."""
    y, x = np.mgrid[0:size, 0:size]
    check = np.where((x // 8 + y // 8) % 2 == 0, 0.15, 0.8)
    albedo = np.repeat(check[..., None], 3, axis=-1).astype(np.float32)
    light = (0.6 + 0.4 * x / (size - 1))[..., None]
    normal = np.broadcast_to(np.float32([0.0, 0.0, 1.0]), albedo.shape).copy()
    return (albedo * light).astype(np.float32), albedo, normal


def test_guide_filters_keep_clean_guides():
    _, albedo, normal = checker_scene()
    clean_albedo, clean_normal = dn.prefilter_guides(albedo, normal)
    assert clean_albedo.dtype == np.float32 and clean_normal.shape == normal.shape
    # OIDN's albedo-only and normal-only filters leave noise-free guides (and
    # the checks' sharp edges) nearly as they are.
    assert np.abs(clean_albedo - albedo).mean() < 0.02
    assert np.abs(clean_normal - normal).mean() < 0.02
    only_albedo, no_normal = dn.prefilter_guides(albedo, None)
    assert no_normal is None and np.array_equal(only_albedo, clean_albedo)


def test_guided_denoising_keeps_the_texture():
    truth, albedo, normal = checker_scene()
    rng = np.random.default_rng(3)
    # Heavy per-pixel noise with the right mean (few samples per pixel).
    noisy = (truth * rng.exponential(1.0, truth.shape)).astype(np.float32)
    denoise = dn.Denoiser("oidn")

    def error(image: np.ndarray) -> float:
        return float(np.abs(image - truth).mean() / truth.mean())

    guided, blind = error(denoise(noisy, albedo, normal)), error(denoise(noisy))
    assert guided < 0.3 * error(noisy)
    assert guided < 0.7 * blind  # the albedo guide tells texture from noise
    with pytest.raises(dn.DenoiseError, match="unknown denoiser 'nlm'"):
        dn.Denoiser("nlm")



def test_multijitter_replaces_independent_samplers():
    scene = ('<scene><sensor><sampler type="independent"><integer name="sample_count" value="$spp"/>'
             '</sampler><film type="hdrfilm"><rfilter type="gaussian"/></film></sensor>'
             '<sensor><sampler type="ldsampler"/><film/></sensor><sensor><film/></sensor>'
             '<sensor><sampler type="$sampler"/></sensor></scene>')
    root = ET.fromstring(dn.multijitter_xml(scene))
    sensors = root.findall("sensor")
    # Independent samplers (named or Mitsuba's default) become multijitter,
    # with their sample count; a sampler chosen otherwise stays.
    assert [s.find("sampler").get("type") for s in sensors] == ["multijitter", "ldsampler", "multijitter",
                                                                "$sampler"]
    assert sensors[0].find("sampler/integer").attrib == {"name": "sample_count", "value": "$spp"}
    assert sensors[0].find("film/rfilter").get("type") == "gaussian"  # (box_filter_xml's job)
    with pytest.raises(dn.DenoiseError, match="glass.xml: not a valid XML file"):
        dn.multijitter_xml("<scene>", "glass.xml")
    # multijitter rounds some counts up (to a near-square product): 10 -> 12.
    sampler = mi.load_dict({"type": "multijitter"})
    assert (dn.rendered_spp(sampler, 16), dn.rendered_spp(sampler, 10)) == (16, 12)


def test_turntable_multijitter_records_the_samples_taken(tmp_path, capsys):
    out = tmp_path / "turn"
    code = main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(out), "--count", "4",
                 "--frames", "0", "--resolution", "16", "--spp", "10", "-D", "integrator=lathe_path",
                 "-D", "max_depth=4", "--denoise", "--multijitter"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "the MultijitterSampler takes 12 samples per pixel for --spp 10" in printed.err
    assert "12 spp" in printed.out and "sampler MultijitterSampler, denoised (oidn)" in printed.out
    with OpenEXR.File(str(out / "frame_0000.exr")) as exr:
        assert exr.header()["spp"] == 12
