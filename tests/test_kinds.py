"""The profile kinds' registry (lathe_shape.surfaces.KINDS): one record per
kind, read by the plugin, the scene geometry, the differentiable code and
the CLI, so that a new kind is one ``register_kind`` call."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.cli import profile as cli
from lathe_shape.kernels import bspline
from lathe_shape.kernels.top_level import LAYOUTS
from lathe_shape.plugin.attached_hits import differentiable_kinds, differentiable_lathes
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry
from lathe_shape.profiles import make_profile
from lathe_shape.surfaces import KINDS, Kind, PolylineSurface, get_kind, register_kind, unregister_kind

#: A goblet: both ends on the axis.
GOBLET = "0 0, 0.8 0, 0.8 0.1, 0.15 0.2, 0.15 1.0, 0.9 1.6, 1.0 2.2, 0.92 2.2, 0.82 1.65, 0 1.2"


def _points(text: str) -> np.ndarray:
    return np.array([[float(v) for v in pair.split()] for pair in text.split(",")])


@pytest.fixture
def zigzag():
    """A made-up kind "zigzag": a polyline alias that runs the polyline
    kernels, with its own profile factory (it records its calls), registered
    for one test only. Registering touches the registry only."""
    calls = []

    def factory(kind, points, sharp, labels, source, crease_angle, smooth, open_sheet):
        calls.append((kind, len(points)))
        profile = make_profile(points, sharp, labels, source=source, crease_angle=crease_angle,
                               open_sheet=open_sheet)
        return PolylineSurface(profile, smooth)

    polyline = KINDS["polyline"]
    before = dict(KINDS)
    record = register_kind(Kind("zigzag", factory, PolylineSurface, polyline.layout, "polyline",
                                differentiable=False, cli_name="zigzag"))
    assert {name: k for name, k in KINDS.items() if name != "zigzag"} == before
    try:
        yield record, calls
    finally:
        unregister_kind("zigzag")
    assert "zigzag" not in KINDS


def _scene(kinds: list[str]) -> mi.Scene:
    scene: dict = {
        "type": "scene",
        "integrator": {"type": "lathe_path", "max_depth": 6},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at([0, -8, 2], [0, 0, 1], [0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 4}},
        "light": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 0.9, 0.8]}},
    }
    for i, kind in enumerate(kinds):
        scene[f"lathe_{i}"] = {
            "type": "lathe", "kind": kind, "profile": GOBLET, "mesh_segments": 16,
            "bsdf": {"type": "dielectric"} if i == 0 else {"type": "diffuse"},
            "to_world": mi.ScalarTransform4f().translate([2.5 * i, 0, 0]),
        }
    return mi.load_dict(scene)


def test_records_of_the_builtin_kinds():
    """Every built-in kind has one record: its kernel layout is one of the
    kernels' layouts, the B-spline strides are the kernel's public ones, and
    the CLI offers every kind by its name."""
    assert list(KINDS) == ["polyline", "bspline", "bezier", "catmull_rom", "quadratic", "sor"]
    for name, kind in KINDS.items():
        assert kind.name == name
        assert kind.layout is LAYOUTS[kind.kernel]
        assert kind.cli_name == name
    assert KINDS["bspline"].seg_stride == bspline.STRIDE == 8
    assert KINDS["sor"].leaf_stride == bspline.LEAF_STRIDE == 12
    assert KINDS["polyline"].leaf_stride is None
    assert differentiable_kinds() == ("polyline", "bspline", "bezier", "catmull_rom", "quadratic")
    assert tuple(cli.profile_kinds()) == tuple(KINDS)
    with pytest.raises(ValueError, match="unknown profile kind 'zigzag'"):
        get_kind("zigzag", "test")


def test_registered_kind_loads_and_renders(zigzag):
    """A lathe of the new kind loads through its factory and renders exactly
    as the polyline lathe of the same points (the same kernel and data)."""
    record, calls = zigzag
    scene = _scene(["zigzag"])
    assert calls == [("zigzag", 10)]
    lathe = [s for s in scene.shapes() if hasattr(s, "surface")][0]
    assert lathe.surface.kind == "zigzag"
    assert "kind='zigzag'" in str(lathe)
    image = np.array(mi.render(scene, seed=3))
    reference = np.array(mi.render(_scene(["polyline"]), seed=3))
    assert np.isfinite(image).all() and image.mean() > 0.01
    assert np.array_equal(image, reference)
    # Not differentiable: left out of the differentiable lathes
    assert differentiable_lathes([lathe]) == []


def test_registered_kind_shares_its_layouts_set(zigzag):
    """Lathes of kinds with one kernel layout make one set: a zigzag and two
    polylines are intersected together."""
    scene = _scene(["zigzag", "polyline", "polyline"])
    geometry = ExactSceneGeometry(scene)
    assert not geometry.single
    assert [sorted({lathe.surface.kind for lathe in g.lathes}) for g in geometry.groups] == [
        ["polyline", "zigzag"]]


def test_registered_kind_in_the_cli(zigzag, tmp_path, capsys):
    """``lathe-profile`` offers the kind's CLI name and validates with its
    factory."""
    record, calls = zigzag
    assert "zigzag" in cli.build_parser().format_help()
    path = tmp_path / "goblet.csv"
    path.write_text("".join(f"{r:g},{z:g}\n" for r, z in _points(GOBLET)))
    assert cli.main([str(path), "--kind", "zigzag"]) == 0
    assert "valid zigzag profile, 10 points" in capsys.readouterr().out
    assert calls == [("zigzag", 10)]
    # A CSV that declares the kind
    path.write_text("# kind: zigzag\n" + path.read_text())
    assert cli.main([str(path)]) == 0
    assert "valid zigzag profile" in capsys.readouterr().out


def test_unregistered_kind_is_refused(tmp_path, capsys):
    """Without the registration the kind is unknown to the plugin and the CLI."""
    with pytest.raises(Exception, match="unknown profile kind 'zigzag'"):
        _scene(["zigzag"])
    assert "zigzag" not in cli.build_parser().format_help()
    path = tmp_path / "goblet.csv"
    path.write_text("# kind: zigzag\n" + "".join(f"{r:g},{z:g}\n" for r, z in _points(GOBLET)))
    assert cli.main([str(path)]) == 2
    assert f"{path}, line 1: unknown profile kind 'zigzag'" in capsys.readouterr().err
    assert cli.main([str(path), "--kind", "polyline"]) == 0  # --kind overrides the file's line
    assert "valid polyline profile" in capsys.readouterr().out
    # Through the shape: the file and its line, not a 'kind' parameter the user never set
    with pytest.raises(Exception, match=f"{path}, line 1: unknown profile kind 'zigzag'"):
        mi.load_dict({"type": "lathe", "filename": str(path)})
