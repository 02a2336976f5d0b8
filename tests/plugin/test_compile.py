"""lathe_path compiles its render kernel once: later renders of the same
scene, with other seeds, launch the very kernels of the first (which may
also launch one-off kernels of the scene's setup, such as a mesh's area
table, built the first time the caustic paths' weights ask for it)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
from conftest import SCENES

from lathe_shape.tools.scenes import load_scene


def _jit_hashes(scene: mi.Scene, integrator: mi.Integrator, seed: int) -> set[str]:
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        mi.render(scene, spp=2, seed=seed, integrator=integrator).numpy()
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}


def test_second_render_reuses_the_first_kernels():
    # A fresh integrator and scene: the first render builds the exact scene
    # geometry, which must not change the kernel of that first render.
    scene = load_scene(SCENES / "wine_glass.xml", {"res": "16", "spp": "2", "mesh_segments": "16",
                                                   "max_depth": "3"})
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": 3})
    first = _jit_hashes(scene, integrator, seed=0)
    second = _jit_hashes(scene, integrator, seed=1)
    assert first and second and second <= first
    assert second == _jit_hashes(scene, integrator, seed=2)


def test_orbit_frames_reuse_the_kernels_with_caustics():
    """A turntable's orbit moves the camera every frame: the light-traced
    caustics' camera and aiming values are opaque, so every frame after the
    second launches the second frame's kernels (the first differs where
    Mitsuba's sensor transform is still a literal before the turntable's
    first update)."""
    from lathe_shape.tools.turntable import Turntable

    scene = load_scene(SCENES / "wine_glass.xml", {"res": "16", "spp": "2", "mesh_segments": "16",
                                                   "max_depth": "3", "integrator": "lathe_path"})
    turntable = Turntable(scene)

    def hashes(angle: float) -> set[str]:
        with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
            dr.kernel_history()
            turntable.render(angle, spp=2, seed=1)
            return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}

    hashes(0.0)
    second, third, fourth = hashes(30.0), hashes(75.0), hashes(140.0)
    assert second and third == second and fourth == second
