"""The denoise errors of scripts/bench_turntable.py on a small wine glass."""

from __future__ import annotations

import pytest
from conftest import SCENES

from lathe_shape.tools.denoise import box_filter_xml
from lathe_shape.tools.scenes import load_scene
from lathe_shape.tools.turntable import Turntable
from lathe_shape.tools.turntable_bench import denoise_errors, lathe_mask

pytest.importorskip("pyoidn")


def test_denoise_errors_on_the_glass():
    defines = {"integrator": "lathe_path", "max_depth": "6", "mesh_segments": "16"}
    scene = load_scene(SCENES / "wine_glass.xml", defines, (48, 48), box_filter_xml)
    turntable = Turntable(scene, guides=True)
    errors = denoise_errors(turntable, 30.0, spp=8, high_spp=64, reference_spp=256, clean_spp=512)
    assert errors["glass_pixels"] == lathe_mask(turntable).sum() > 100  # the glass is in view
    for against in ("", "_vs_512spp"):
        noisy = errors[f"noisy_8spp{against}"]
        # Denoising and more samples both bring the glass closer to the reference.
        assert errors[f"denoised_8spp{against}"] < 0.6 * noisy
        assert errors[f"denoised_32spp{against}"] < errors[f"denoised_8spp{against}"]
        assert errors[f"noisy_64spp{against}"] < 0.5 * noisy
        # Converged guides denoise better than the frame's own noisy ones.
        assert errors[f"denoised_8spp_reference_guides{against}"] < errors[f"denoised_8spp{against}"]
        # Two independent 256 spp renders differ less than a 64 spp one from either.
        assert errors[f"second_reference_256spp{against}"] < errors[f"noisy_64spp{against}"]
    assert abs(errors["denoised_8spp_brightness"]) < 0.25
