"""The lathe_whitted integrator: noise-free specular chains, agreement with
lathe_path where both estimate the same transport, Fresnel energy, errors."""

from __future__ import annotations

import re

import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.validation.furnace import furnace_scene, glass_mask

GLASS = "0 0, 1.5 0, 1.6 2.5, 1.2 4.5, 0 4.6"


def camera(width: int, height: int, origin=(0, -14, 6), target=(0, 0, 2.4)) -> dict:
    to_world = mi.ScalarTransform4f().look_at(origin=list(origin), target=list(target), up=[0, 0, 1])
    return {"type": "perspective", "fov": 35, "to_world": to_world,
            "film": {"type": "hdrfilm", "width": width, "height": height}}


def point_lit_scene(bsdf: dict | None = None) -> mi.Scene:
    """A glass on a diffuse floor, lit by point lights only, filling the frame."""
    return mi.load_dict({
        "type": "scene",
        "sensor": camera(32, 32, origin=(0, -9, 4)),
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(20),
                  "bsdf": {"type": "diffuse", "reflectance": 0.6}},
        "key": {"type": "point", "position": [-4, -6, 9], "intensity": {"type": "rgb", "value": 120.0}},
        "fill": {"type": "point", "position": [5, -2, 6], "intensity": {"type": "rgb", "value": 40.0}},
        "glass": {"type": "lathe", "profile": GLASS, "bsdf": bsdf or {"type": "dielectric"}},
    })


def backdrop_scene(bsdf: dict) -> mi.Scene:
    """A glass in front of an emissive checkered backdrop (black BSDF): no
    diffuse light transport at all, only specular chains to an emitter."""
    texture = {"type": "checkerboard", "color0": {"type": "rgb", "value": [0.1, 0.2, 0.6]},
               "color1": {"type": "rgb", "value": [1.0, 0.8, 0.3]},
               "to_uv": mi.ScalarTransform4f().scale([6, 6, 1])}
    return mi.load_dict({
        "type": "scene",
        "sensor": camera(24, 24),
        "backdrop": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": 0.0},
                     "to_world": mi.ScalarTransform4f().translate([0, 6, 2.4]).rotate([1, 0, 0], 90).scale(8),
                     "emitter": {"type": "area", "radiance": texture}},
        "glass": {"type": "lathe", "profile": GLASS, "bsdf": bsdf},
    })


def render(scene: mi.Scene, integrator: dict, spp: int, seed: int) -> np.ndarray:
    return mi.render(scene, spp=spp, seed=seed, integrator=mi.load_dict(integrator)).numpy()


def test_point_lights_render_without_noise():
    # Two seeds differ only by the pixel jitter (antialiasing): far less than
    # two seeds of the path tracer at the same spp.
    scene = point_lit_scene()
    spp = 16
    whitted = {"type": "lathe_whitted", "max_depth": 8}
    path = {"type": "lathe_path", "max_depth": 8}
    a, b = render(scene, whitted, spp, 1), render(scene, whitted, spp, 2)
    p, q = render(scene, path, spp, 1), render(scene, path, spp, 2)
    assert np.isfinite(a).all() and a.mean() > 0.02
    jitter = np.abs(a - b).mean()
    noise = np.abs(p - q).mean()
    assert jitter < 0.2 * noise, (jitter, noise)


@pytest.mark.parametrize("bsdf", [{"type": "dielectric", "int_ior": 1.5}, {"type": "thindielectric"},
                                  {"type": "conductor", "material": "Au"}],
                         ids=["dielectric", "thindielectric", "conductor"])
@pytest.mark.slow
def test_agrees_with_path_tracer_on_specular_chains(bsdf):
    scene = backdrop_scene(bsdf)
    spp = 256
    whitted = render(scene, {"type": "lathe_whitted", "max_depth": 24, "cutoff": 1e-4}, spp, 1)
    path, path_again = (render(scene, {"type": "lathe_path", "max_depth": 24}, spp, seed) for seed in (2, 3))
    assert np.isfinite(whitted).all()
    assert abs(whitted.mean() - path.mean()) < 0.01 * path.mean()

    # 4x4-pixel blocks: lathe_whitted differs from the path tracer about as
    # much as the path tracer differs from itself with another seed (the
    # pixel jitter of both renders dominates; measured ratios 0.9-1.3, going
    # down with the spp: no bias).
    def blocks(image: np.ndarray) -> np.ndarray:
        return image.reshape(6, 4, 6, 4, 3).mean(axis=(1, 3))

    noise = np.abs(blocks(path_again) - blocks(path)).mean()
    assert np.abs(blocks(whitted) - blocks(path)).mean() < 1.5 * noise


def test_fresnel_energy_in_white_furnace():
    # No absorption, white environment: reflection and refraction together
    # keep all the energy, so the glass is 1.0 (deep TIR chains need a deep
    # tree and a low cutoff).
    scene = furnace_scene(resolution=32, smooth=False)
    image = render(scene, {"type": "lathe_whitted", "max_depth": 64, "cutoff": 1e-4}, 2, 1).mean(axis=2)
    glass = image[glass_mask(scene)]
    assert glass.size > 100
    assert abs(glass.mean() - 1.0) < 0.005, glass.mean()
    assert glass.max() < 1.001 and np.percentile(glass, 1) > 0.99


def test_filtered_shadows_let_light_through_glass():
    scene = point_lit_scene()
    opaque = render(scene, {"type": "lathe_whitted", "max_depth": 8}, 4, 1)
    filtered = render(scene, {"type": "lathe_whitted", "max_depth": 8, "shadows": "filtered"}, 4, 1)
    brighter = filtered.mean(axis=2) - opaque.mean(axis=2)
    # Only the shadow of the glass changes, and it gets lighter.
    assert brighter.min() > -1e-4 and (brighter > 0.01).sum() > 10


@pytest.mark.parametrize(("params", "message"), [
    ({"shadows": "soft"}, "lathe_whitted: parameter 'shadows': unknown mode 'soft' "
                          "(expected one of: opaque, filtered)"),
    ({"max_depth": -1}, "lathe_whitted: parameter 'max_depth' must be >= 0, got -1"),
    ({"cutoff": 1.5}, "lathe_whitted: parameter 'cutoff' must be in [0, 1), got 1.5"),
    ({"cutoff": -0.1}, "lathe_whitted: parameter 'cutoff' must be in [0, 1), got -0.1"),
    ({"normal_check": "bend"}, "lathe_whitted: parameter 'normal_check': unknown policy 'bend'"),
    ({"shadows": 1}, "lathe_whitted: parameter 'shadows' must be given as <string>"),
])
def test_parameter_errors(params, message):
    with pytest.raises(RuntimeError, match=re.escape(message)):
        mi.load_dict({"type": "lathe_whitted", **params})


def test_max_depth_zero_and_one():
    scene = point_lit_scene()
    assert render(scene, {"type": "lathe_whitted", "max_depth": 0}, 1, 1).max() == 0.0
    # Point lights are invisible and nothing emits: depth 1 is black too.
    assert render(scene, {"type": "lathe_whitted", "max_depth": 1}, 1, 1).max() == 0.0
    assert render(scene, {"type": "lathe_whitted", "max_depth": 2}, 1, 1).max() > 0.0


def test_hide_emitters():
    """hide_emitters as in lathe_path: the sky black and transparent, the
    area panel in front of the wall skipped (the wall behind it shows)."""
    from test_integrator import _hidden_emitters_scene

    whitted = mi.render(_hidden_emitters_scene("lathe_whitted"), seed=1).numpy()
    path = mi.render(_hidden_emitters_scene("lathe_path"), seed=1).numpy()
    panel = (slice(10, 14), slice(10, 14))
    assert whitted[panel][..., :3].mean() > 0.05
    sky = path[..., 3] == 0
    assert sky.sum() > 20 and np.abs(whitted[sky]).max() == 0.0
    assert np.abs(whitted[..., 3] - path[..., 3]).mean() < 0.05


def render_kernel_size(scene: mi.Scene, integrator: dict) -> int:
    """Operations in the largest kernel of a 1 spp render."""
    import drjit as dr

    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # (clears it)
        mi.render(scene, spp=1, seed=1, integrator=mi.load_dict(integrator))
        return max(kernel.get("operation_count", 0) for kernel in dr.kernel_history())
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)


def test_cost_does_not_grow_with_max_depth():
    # The stack of pending branches holds at most MAX_PENDING entries: a
    # deep max_depth neither enlarges the kernel nor the work of each step
    # (a stack of max_depth - 1 entries took 25 s at depth 1000, 64x64 at
    # 4 spp, against 0.75 s at depth 100).
    scene = furnace_scene(resolution=8)
    shallow = render_kernel_size(scene, {"type": "lathe_whitted", "max_depth": 40})
    deep = render_kernel_size(scene, {"type": "lathe_whitted", "max_depth": 1000})
    assert shallow > 0 and deep == shallow, (shallow, deep)


def test_full_stack_keeps_the_energy(monkeypatch):
    # Where the stack is full a vertex follows one branch, picked with
    # probability in proportion to its weight: unbiased, so the furnace
    # stays 1 even with a stack of one entry (then noisy).
    from lathe_shape.plugin import lathe_whitted

    scene = furnace_scene(resolution=32, smooth=False)
    whitted = {"type": "lathe_whitted", "max_depth": 64, "cutoff": 1e-4}
    tree = render(scene, whitted, 16, 1).mean(axis=2)[glass_mask(scene)]
    monkeypatch.setattr(lathe_whitted, "MAX_PENDING", 1)
    picked = render(scene, whitted, 16, 1).mean(axis=2)[glass_mask(scene)]
    assert abs(picked.mean() - 1.0) < 0.005, picked.mean()
    assert abs(picked.mean() - tree.mean()) < 0.002, (picked.mean(), tree.mean())
    # The random picks did happen (measured std 0.071 against 0.011).
    assert picked.std() > 3.0 * tree.std(), (picked.std(), tree.std())
