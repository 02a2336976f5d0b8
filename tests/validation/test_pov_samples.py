"""scenes/pov_samples: the four lathes of POV-Ray's curve kinds render the
same exactly (``lathe_path``) and as fine reference meshes (``path``),
within noise on the pixels that do not see the dielectric bottle; the
profiles there are what ``lathe-profile --from-pov`` writes.

The reference meshes have ``LATHE_REFERENCE_STEPS`` azimuthal steps
(default 512, which builds in an eighth of the time of 4096; 512, 1024 and
4096 steps gave the same differences to three digits when measured: 0.0175
mean and 0.0005 bias, relative)."""

from __future__ import annotations

import filecmp
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import SCENES

from lathe_shape.cli import profile as cli

SAMPLES = SCENES / "pov_samples"
RES = 64
STEPS = int(os.environ.get("LATHE_REFERENCE_STEPS", "512"))


def test_profiles_are_the_importers_output(tmp_path, capsys):
    assert cli.main(["--from-pov", str(SAMPLES / "pov_samples.pov"), "-o", str(tmp_path)]) == 0
    capsys.readouterr()
    for name in ("Cup", "Vase", "Goblet", "Bottle"):
        for ext in (".csv", ".xml"):
            ours = (SAMPLES / "profiles" / (name + ext)).read_text().splitlines()
            fresh = (tmp_path / (name + ext)).read_text().splitlines()
            # The first line names the source file's path as given.
            assert ours[1:] == fresh[1:], (name, ext)
    assert not filecmp.cmp(SAMPLES / "profiles" / "Cup.csv", SAMPLES / "profiles" / "Vase.csv")


@pytest.mark.slow
def test_exact_render_matches_fine_reference_mesh():
    scene = mi.load_file(str(SAMPLES / "pov_samples.xml"), res=RES, mesh_segments=STEPS,
                         max_depth=8)
    kinds = {s.id(): (s.surface.kind, s.profile.open_sheet) for s in scene.shapes()
             if hasattr(s, "surface")}
    assert kinds == {"Cup": ("bezier", True), "Vase": ("bezier", False),
                     "Goblet": ("catmull_rom", False), "Bottle": ("sor", False)}
    exact = mi.render(scene, spp=32, seed=3,
                      integrator=mi.load_dict({"type": "lathe_path", "max_depth": 8})).numpy()
    mesh = mi.render(scene, spp=32, seed=3, integrator=mi.load_dict({"type": "path", "max_depth": 8})).numpy()
    # Pixels whose primary ray meets the dielectric bottle are left out.
    sensor = scene.sensors()[0]
    idx = dr.arange(mi.UInt32, RES * RES)
    pos = (mi.Point2f(mi.Float(idx % RES), mi.Float(idx // RES)) + 0.5) / RES
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    si = scene.ray_intersect(mi.Ray3f(ray))
    bottle = next(s for s in scene.shapes() if s.id() == "Bottle")
    glass = (si.is_valid() & (si.shape == mi.ShapePtr(bottle))).numpy().reshape(RES, RES)
    keep = ~glass
    assert np.isfinite(exact).all() and glass.mean() > 0.01
    scale = exact[keep].mean()
    assert np.abs(mesh[keep] - exact[keep]).mean() / scale < 0.06
    assert abs(mesh[keep].mean() - exact[keep].mean()) / scale < 0.01
