"""Issue 26, item 1: never silent. A lathe with a medium under an exact
integrator is an error; a stock integrator on lathes is announced by the
CLI."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest
from conftest import VARIANT

from lathe_shape.cli import render
from lathe_shape.cli.common import root_message

SCENE = """<scene version="3.0.0">
    <integrator type="{integrator}"/>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, -6, 1" target="0, 0, 1" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
        <sampler type="independent"><integer name="sample_count" value="2"/></sampler>
    </sensor>
    <emitter type="constant"/>
    <shape type="lathe" id="jar">
        <string name="profile" value="0 0, 1 0, 1 2, 0 2"/>
        <integer name="mesh_segments" value="48"/>
        <bsdf type="dielectric"/>
        {medium}
    </shape>
</scene>"""

FOG = '<medium type="homogeneous" name="{side}" id="fog"/>'


@pytest.mark.parametrize("integrator", ["lathe_path", "lathe_whitted", "lathe_prb"])
@pytest.mark.parametrize("side", ["interior", "exterior"])
def test_lathe_with_medium_is_an_error(integrator, side):
    if integrator == "lathe_prb" and mi.is_polarized:
        pytest.skip("lathe_prb only")
    scene = mi.load_string(SCENE.format(integrator=integrator, medium=FOG.format(side=side)))
    with pytest.raises(Exception) as caught:
        mi.render(scene, spp=1)
    message = root_message(caught.value)  # mi.render wraps the integrator's error
    for part in ("lathe 'jar'", f"{side} medium", "'fog'", integrator, "use lathe_volpath"):
        assert part in message.replace("Use", "use"), message


def test_lathe_without_medium_renders():
    scene = mi.load_string(SCENE.format(integrator="lathe_path", medium=""))
    assert mi.render(scene, spp=1).shape[:2] == (8, 8)


def run_render(tmp_path, capsys, integrator):
    path = tmp_path / f"{integrator}.xml"
    path.write_text(SCENE.format(integrator=integrator, medium=""))
    assert render.main(["--variant", VARIANT, str(path), "-o", str(tmp_path / "out"), "--no-png"]) == 0
    return capsys.readouterr().out


def test_cli_names_mesh_rendering_under_a_stock_integrator(tmp_path, capsys):
    out = run_render(tmp_path, capsys, "path")
    notes = [line for line in out.splitlines() if "note:" in line]
    assert len(notes) == 1, out
    assert "1 lathe rendered as its 48-step reference mesh" in notes[0]
    assert "lathe_path renders them exactly" in notes[0]


def test_cli_is_quiet_under_lathe_path(tmp_path, capsys):
    out = run_render(tmp_path, capsys, "lathe_path")
    assert "note:" not in out and "reference mesh" not in out


def test_cli_names_lathe_volpath_for_lathes_with_media(tmp_path, capsys):
    """Under a stock integrator that renders media (volpath), the note
    points to lathe_volpath, which renders lathes with media exactly
    (lathe_path would refuse them)."""
    path = tmp_path / "fog.xml"
    path.write_text(SCENE.format(integrator="volpath", medium=FOG.format(side="interior")))
    assert render.main(["--variant", VARIANT, str(path), "-o", str(tmp_path / "out"), "--no-png"]) == 0
    notes = [line for line in capsys.readouterr().out.splitlines() if "note:" in line]
    expected = 'lathe_volpath renders them exactly (e.g. <integrator type="lathe_volpath">)'
    assert len(notes) == 1 and expected in notes[0], notes


INK = '<medium type="homogeneous" name="interior" id="ink"><float name="{name}" value="{value}"/></medium>'


@pytest.mark.parametrize("medium, shown", [(INK.format(name="scale", value="-2"), "-2"),
                                           (INK.format(name="sigma_t", value="-0.5"), "-0.5")])
def test_negative_extinction_is_an_error(medium, shown):
    """A negative extinction (which Mitsuba accepts for a float sigma_t or a
    negative scale) is refused by lathe_volpath naming the medium; before,
    it rendered NaN pixels and exited 0."""
    if mi.is_polarized:
        pytest.skip("lathe_volpath refuses polarized variants")
    scene = mi.load_string(SCENE.format(integrator="lathe_volpath", medium=medium))
    with pytest.raises(Exception) as caught:
        mi.render(scene, spp=1)
    message = root_message(caught.value)
    assert message.startswith("HomogeneousMedium 'ink': its extinction 'sigma_t' times 'scale' is (")
    assert f"{shown}, {shown}, {shown}" in message and "lathe_volpath would render NaN pixels" in message
    fine = mi.load_string(SCENE.format(integrator="lathe_volpath", medium=FOG.format(side="interior")))
    assert np.isfinite(np.array(mi.render(fine, spp=1))).all()


@pytest.mark.parametrize("value, shown", [("1.5", "1.5"), ("-0.5", "-0.5")])
def test_albedo_outside_zero_one_is_an_error(value, shown):
    """An albedo of 1.5 (Mitsuba accepts it) made the filled glass 4x
    brighter than at 1 under a sky of 1: energy from nowhere. Refused by
    lathe_volpath, naming the medium."""
    if mi.is_polarized:
        pytest.skip("lathe_volpath refuses polarized variants")
    ink = INK.format(name="albedo", value=value)
    scene = mi.load_string(SCENE.format(integrator="lathe_volpath", medium=ink))
    with pytest.raises(Exception) as caught:
        mi.render(scene, spp=1)
    message = root_message(caught.value)
    assert message.startswith(f"HomogeneousMedium 'ink': its 'albedo' is ({shown}, {shown}"), message
    assert "); it must be in [0, 1] (above 1 the medium scatters more light" in message
    one = INK.format(name="albedo", value="1")
    one = mi.load_string(SCENE.format(integrator="lathe_volpath", medium=one))
    assert np.isfinite(np.array(mi.render(one, spp=1))).all()
