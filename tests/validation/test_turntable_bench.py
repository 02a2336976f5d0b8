"""The denoise errors of scripts/bench_turntable.py on a small wine glass."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SCENES

from lathe_shape.tools.denoise import box_filter_xml, multijitter_xml
from lathe_shape.tools.scenes import load_scene
from lathe_shape.tools.turntable import Turntable
from lathe_shape.validation.turntable_bench import denoise_errors, lathe_mask

pytest.importorskip("pyoidn")

pytestmark = [pytest.mark.slow, pytest.mark.denoise]


DEFINES = {"integrator": "lathe_path", "max_depth": "6", "mesh_segments": "16"}


def small_glass(multijitter: bool = False) -> Turntable:
    """The wine glass at 48x48, box filter (and multijitter samples)."""
    def edit(text: str, path: str) -> str:
        text = box_filter_xml(text, path)
        return multijitter_xml(text, path) if multijitter else text

    return Turntable(load_scene(SCENES / "wine_glass.xml", DEFINES, (48, 48), edit), guides=True)


def test_denoise_errors_on_the_glass():
    turntable = small_glass()
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
        # The albedo guide is the one that decides: the reference's, with the
        # frame's own normals, denoises about as well as both converged
        # guides and better than the frame's own guides; the albedo of a
        # 64 spp render, with the frame's normals, also beats the frame's own.
        reference_albedo = errors[f"denoised_8spp_reference_albedo{against}"]
        assert reference_albedo < 1.1 * errors[f"denoised_8spp_reference_guides{against}"]
        assert reference_albedo < errors[f"denoised_8spp{against}"]
        assert errors[f"denoised_8spp_64spp_albedo{against}"] < errors[f"denoised_8spp{against}"]
        # Two independent 256 spp renders differ less than a 64 spp one from either.
        assert errors[f"second_reference_256spp{against}"] < errors[f"noisy_64spp{against}"]
    assert abs(errors["denoised_8spp_brightness"]) < 0.25



def test_multijitter_frames_have_less_noisy_guides():
    """The guides behind the glass of a frame sampled as by lathe-turntable
    --multijitter are closer to converged ones than with the scene's
    independent sampler."""
    plain, stratified = small_glass(), small_glass(multijitter=True)
    plain.pose(30.0)
    mask = lathe_mask(plain)
    converged = plain.render(30.0, spp=1024, seed=1)[..., 3:6]

    def guide_error(turntable: Turntable) -> float:
        return float(np.abs(turntable.render(30.0, spp=8, seed=0)[..., 3:6] - converged)[mask].mean())

    assert guide_error(stratified) < 0.85 * guide_error(plain)
    errors = denoise_errors(plain, 30.0, spp=8, high_spp=16, reference_spp=64, stratified=stratified)
    assert errors["noisy_8spp_multijitter"] < 0.9 * errors["noisy_8spp"]
    assert errors["denoised_8spp_multijitter"] < errors["noisy_8spp_multijitter"]
    assert abs(errors["denoised_8spp_multijitter_brightness"]) < 0.25
