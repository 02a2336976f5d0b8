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
