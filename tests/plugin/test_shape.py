"""The ``lathe`` plugin: XML parameters, transforms, errors, scenes render."""

from __future__ import annotations

import re

import mitsuba as mi
import numpy as np
import pytest
from conftest import SCENE_FILES

from lathe_shape.plugin.shape import LatheShape
from lathe_shape.tools.scenes import load_string_in

GLASS = "0 0, 1 0, 1 2, 0.9 2, 0.9 0.1, 0 0.1"

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="8"/></integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,-6,3" target="0,0,1" up="0,0,1"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film>
    </sensor>
    <emitter type="constant"/>
    {shape}
</scene>"""


def lathe_xml(params: str = f'<string name="profile" value="{GLASS}"/>', extra: str = "") -> str:
    return f'<shape type="lathe" id="glass">{params}{extra}<bsdf type="dielectric"/></shape>'


def load(shape_xml: str) -> mi.Scene:
    return mi.load_string(SCENE.format(shape=shape_xml))


def test_loads_as_mesh_with_transform():
    scene = load(lathe_xml(extra='<integer name="mesh_segments" value="12"/>'
                           '<transform name="to_world"><scale value="2"/><translate z="1"/></transform>'))
    (shape,) = scene.shapes()
    assert isinstance(shape, LatheShape) and shape.id() == "glass"
    assert shape.vertex_count() > 0 and shape.face_count() == 5 * 2 * 12 - 2 * 12
    bbox = shape.bbox()
    np.testing.assert_allclose(np.array(bbox.min), [-2, -2, 1], atol=1e-6)
    np.testing.assert_allclose(np.array(bbox.max), [2, 2, 5], atol=1e-6)
    assert shape.bsdf() is not None and "Dielectric" in str(shape.bsdf())


def test_filename_resolves_relative_to_scene(tmp_path):
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "g.csv").write_text("r,z\n" + "\n".join(
        p.strip().replace(" ", ",") for p in GLASS.split(",")))
    xml = tmp_path / "scene.xml"
    xml.write_text(SCENE.format(shape=lathe_xml('<string name="filename" value="profiles/g.csv"/>')))
    scene = mi.load_file(str(xml))
    assert scene.shapes()[0].profile.source.endswith("profiles/g.csv")


@pytest.mark.parametrize(
    "shape_xml, message",
    [
        (lathe_xml(""), "lathe 'glass': give exactly one of the parameters 'filename' and 'profile'"),
        (lathe_xml(f'<string name="profile" value="{GLASS}"/><string name="filename" value="x.csv"/>'),
         "give exactly one of the parameters 'filename' and 'profile' (both were given)"),
        (lathe_xml(f'<string name="profle" value="{GLASS}"/>'),
         "lathe 'glass': give exactly one of the parameters 'filename' and 'profile' (unknown parameter "
         "'profle': did you mean 'profile'?)"),
        (lathe_xml('<string name="filename" value="missing.csv"/>'),
         "lathe 'glass': parameter 'filename': profile file 'missing.csv' not found"),
        (lathe_xml('<string name="profile" value="0 0, -1 1, 0 2"/>'),
         "lathe 'glass': parameter 'profile', point 2: negative radius r = -1 (r must be >= 0)"),
        (lathe_xml('<string name="profile" value="0 0, 1 0, 1 1, 0.5 1"/>'), "profile is not closed"),
        (lathe_xml(extra='<string name="kind" value="nurbs"/>'),
         "lathe 'glass': parameter 'kind': unknown profile kind 'nurbs'"),
        (lathe_xml(extra='<integer name="mesh_segments" value="2"/>'),
         "lathe 'glass': parameter 'mesh_segments' must be at least 3, got 2"),
        (lathe_xml(extra='<float name="crease_angle" value="200"/>'),
         "lathe 'glass': parameter 'crease_angle' must be within [0, 180] degrees, got 200"),
        (lathe_xml(extra='<string name="smooth" value="false"/>'),
         "lathe 'glass': parameter 'smooth' must be given as <boolean>, got 'false'"),
        (lathe_xml(extra='<float name="mesh_segments" value="16.5"/>'),
         "lathe 'glass': parameter 'mesh_segments' must be given as <integer>, got 16.5"),
        (lathe_xml(extra='<transform name="to_world"><scale x="0"/></transform>'),
         "lathe 'glass': parameter 'to_world': the transform is singular"),
    ],
)
def test_bad_parameters(shape_xml, message):
    with pytest.raises(RuntimeError, match=re.escape(message)):
        load(shape_xml)


@pytest.mark.parametrize("scene_file", SCENE_FILES, ids=lambda p: p.stem)
@pytest.mark.slow
def test_scene_renders_with_stock_path(scene_file):
    if "dispersive_dielectric" in scene_file.read_text() and not mi.is_spectral:
        pytest.skip("spectral variants only (tests/plugin/test_dispersion.py renders it)")
    small = {"spp": "4", "res": "48", "mesh_segments": "64", "max_depth": "8"}
    scene = mi.load_file(str(scene_file), **small)
    lathes = [s for s in scene.shapes() if isinstance(s, LatheShape)]
    assert lathes, "scene has no lathe"
    image = np.array(mi.render(scene, seed=1))
    assert np.isfinite(image).all() and image.mean() > 0.01

    # Without the lathe the image must differ clearly: the glass is visible.
    text = scene_file.read_text()
    without = re.sub(r'<shape type="lathe".*?</shape>', "", text, flags=re.S)
    assert without != text
    no_mesh = {k: v for k, v in small.items() if k != "mesh_segments"}
    scene_empty = load_string_in(scene_file.parent, without, **no_mesh)
    empty = np.array(mi.render(scene_empty, seed=1))
    changed = np.abs(image - empty).max(axis=2) > 0.05
    assert changed.mean() > 0.02


def test_set_to_world_moves_mesh_and_exact_surface():
    scene = load(lathe_xml(extra='<integer name="mesh_segments" value="64"/>'))
    (shape,) = scene.shapes()
    moved = np.eye(4)
    moved[:3, 3] = [3.0, 0.0, 0.5]
    shape.set_to_world(moved, scene)
    ray = mi.Ray3f(mi.Point3f(3.0, -10.0, 1.5), mi.Vector3f(0, 1, 0))
    assert abs(scene.ray_intersect(ray).t[0] - 9.0) < 1e-2   # the mesh moved (r = 1)
    assert abs(shape.ray_intersect_exact(ray).t[0] - 9.0) < 1e-4
    with pytest.raises(ValueError, match="mirrors the shape relative to the old one"):
        shape.set_to_world(np.diag([-1.0, 1.0, 1.0, 1.0]), scene)
    with pytest.raises(ValueError, match="the transform is singular"):
        shape.set_to_world(np.diag([0.0, 1.0, 1.0, 1.0]), scene)


SHARED_BSDF_XML = """<scene version="3.0.0">
    <bsdf type="diffuse" id="glass_material"/>
    <shape type="lathe" id="left">
        <string name="profile" value="0 0, 1 0, 1 2, 0 2"/><integer name="mesh_segments" value="8"/>
        <ref id="glass_material"/>
    </shape>
    <shape type="lathe" id="right">
        <string name="profile" value="0 0, 1 0, 1 2, 0 2"/><integer name="mesh_segments" value="8"/>
        <transform name="to_world"><translate x="3"/></transform>
        <ref id="glass_material"/>
    </shape>
    <shape type="lathe" id="third">
        <string name="profile" value="0 0, 1 0, 1 2, 0 2"/><integer name="mesh_segments" value="8"/>
        <transform name="to_world"><translate x="-3"/></transform>
        <bsdf type="diffuse"/>
    </shape>
</scene>"""


def _lathe_ids(scene: mi.Scene) -> list[str]:
    return sorted(s.id() for s in scene.shapes() if isinstance(s, LatheShape))


def test_lathes_sharing_a_bsdf_are_not_merged():
    """Mitsuba's default scene optimisation merges meshes with equivalent
    BSDFs into one plain mesh; lathes must survive it (XML with a shared
    reference or equal nested BSDFs, and dicts sharing one BSDF object)."""
    assert _lathe_ids(mi.load_string(SHARED_BSDF_XML)) == ["left", "right", "third"]
    bsdf = mi.load_dict({"type": "diffuse"})

    def lathe(x: float) -> dict:
        return {"type": "lathe", "profile": "0 0, 1 0, 1 2, 0 2", "mesh_segments": 8,
                "to_world": mi.ScalarTransform4f().translate([x, 0, 0]), "material": bsdf}

    shared = mi.load_dict({"type": "scene", "a": lathe(0), "b": lathe(3), "c": lathe(-3)})
    assert _lathe_ids(shared) == ["a", "b", "c"]
    by_ref = mi.load_dict({"type": "scene", "m": {"type": "diffuse"},
                           "a": {**lathe(0), "material": {"type": "ref", "id": "m"}},
                           "b": {**lathe(3), "material": {"type": "ref", "id": "m"}}})
    assert _lathe_ids(by_ref) == ["a", "b"]


def test_face_band_attribute_names_the_profile_segment():
    scene = mi.load_string(SHARED_BSDF_XML)
    lathe = next(s for s in scene.shapes() if s.id() == "left")
    bands = lathe.attribute_buffer("face_lathe_band").numpy()
    assert len(bands) == lathe.face_count()
    # The profile "0 0, 1 0, 1 2, 0 2" has 3 surface segments, 8 steps each;
    # the disc segments touch a pole and have one triangle per step, the
    # cylinder two.
    assert np.array_equal(np.bincount(bands.astype(int)), [8, 16, 8])


def test_typed_profile_and_transform_parameters():
    """A mistyped ``profile``, ``filename`` or ``to_world`` gets the
    typed-parameter error, and a tiny uniform scale is not singular."""
    base = ('<scene version="3.0.0"><shape type="lathe" id="g">{}'
            '</shape></scene>')
    cases = [
        ('<integer name="profile" value="3"/>', "parameter 'profile' must be given as <string>"),
        ('<integer name="filename" value="3"/>', "parameter 'filename' must be given as <string>"),
        ('<string name="profile" value="0 0, 1 0, 1 1, 0 1"/><string name="to_world" value="1"/>',
         "parameter 'to_world' must be given as <transform>"),
    ]
    for body, message in cases:
        with pytest.raises(RuntimeError, match=re.escape(message)):
            mi.load_string(base.format(body))
    small = mi.load_string(base.format(
        '<string name="profile" value="0 0, 1 0, 1 1, 0 1"/>'
        '<transform name="to_world"><scale value="1e-4"/></transform>'))
    lathe = small.shapes()[0]
    assert np.allclose(lathe.to_world_matrix[:3, :3], 1e-4 * np.eye(3))


def test_misses_carry_finite_fields():
    scene = mi.load_string('<scene version="3.0.0"><shape type="lathe">'
                           '<string name="profile" value="0 0, 1 0, 1 1, 0 1"/></shape></scene>')
    lathe = scene.shapes()[0]
    o = mi.Point3f([np.nan, np.inf, 5.0], [0.0, 0.0, 5.0], [0.5, 0.5, 0.5])
    d = mi.Vector3f([1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    si = lathe.ray_intersect_exact(mi.Ray3f(o, d))
    assert not si.is_valid().numpy().any()
    for field in (si.p, si.n, si.sh_frame.n, si.sh_frame.s, si.wi, si.uv, si.dp_du):
        assert np.isfinite(np.asarray(field.numpy())).all()


def test_mesh_segments_beyond_memory_are_refused_with_the_estimate():
    xml = ('<scene version="3.0.0"><shape type="lathe" id="g"><string name="profile" '
           'value="0 0, 1 0, 1 2, 0 2"/><integer name="mesh_segments" value="1000000000"/>'
           '</shape></scene>')
    with pytest.raises(RuntimeError, match=r"lathe 'g': parameter 'mesh_segments' = 1000000000 asks for a "
                                           r"reference mesh of 6,000,000,006 vertices, about [\d.]+ GiB"):
        mi.load_string(xml)
    from lathe_shape.plugin.reference_mesh import check_mesh_budget

    check_mesh_budget(100, 999, "g", available=2 * 100 * 1000 * 320)
    with pytest.raises(ValueError, match="more than half the memory available"):
        check_mesh_budget(100, 1000, "g", available=2 * 100 * 1000 * 320)


def test_proxy_reference_mesh_renders_the_same_exactly():
    """``reference proxy`` keeps a 12-step stand-in for stock integrators;
    lathe_path renders the exact surface either way."""
    def scene(reference: str) -> mi.Scene:
        return mi.load_dict({
            "type": "scene",
            "sensor": {"type": "perspective", "fov": 40,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, -6, 3], target=[0, 0, 1],
                                                                  up=[0, 0, 1]),
                       "film": {"type": "hdrfilm", "width": 24, "height": 24}},
            "light": {"type": "point", "position": [2, -3, 5], "intensity": 30.0},
            "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(10)},
            "glass": {"type": "lathe", "profile": "0 0, 1 0, 1.2 1.5, 0.6 2.5, 0 2.5",
                      "mesh_segments": 256, "reference": reference},
        })

    full, proxy = scene("mesh"), scene("proxy")
    lathe_full = next(s for s in full.shapes() if isinstance(s, LatheShape))
    lathe_proxy = next(s for s in proxy.shapes() if isinstance(s, LatheShape))
    assert lathe_full.vertex_count() > 10 * lathe_proxy.vertex_count()
    assert lathe_proxy.reference == "proxy"
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": 4})
    image_full = mi.render(full, spp=4, seed=1, integrator=integrator).numpy()
    image_proxy = mi.render(proxy, spp=4, seed=1, integrator=integrator).numpy()
    assert image_full.mean() > 0 and np.allclose(image_full, image_proxy, atol=1e-5)
    with pytest.raises(RuntimeError, match="parameter 'reference': unknown mode 'none'"):
        mi.load_dict({"type": "lathe", "profile": "0 0, 1 0, 1 1, 0 1", "reference": "none"})


@pytest.mark.slow
def test_scenes_of_many_lathes_load(tmp_path):
    """The package loads scenes sequentially (see tools.scenes.PARALLEL_LOAD):
    1000 lathes load."""
    from lathe_shape.plugin.shape import scene_lathes
    from lathe_shape.tools.scenes import load_scene

    count = 1000
    lathes = "".join(
        f'<shape type="lathe"><string name="profile" value="0 0, 1 0, 1 1, 0 1"/>'
        f'<string name="reference" value="proxy"/>'
        f'<transform name="to_world"><translate x="{3 * i}"/></transform></shape>'
        for i in range(count))
    scene_file = tmp_path / "many.xml"
    scene_file.write_text(f'<scene version="3.0.0">{lathes}</scene>')
    assert len(scene_lathes(load_scene(scene_file))) == count



def test_mesh_buffer_edits_are_refused():
    """Editing the reference mesh through mi.traverse would move the mesh
    but not the exact lathe: refused, and the mesh is put back."""
    scene = mi.load_dict({"type": "scene", "a": {
        "type": "lathe", "profile": "0 0, 1 0, 1.2 1, 0.6 2, 0 2",
        "to_world": mi.ScalarTransform4f().translate([-1.5, 0, 0])}})
    params = mi.traverse(scene)
    before = np.array(params["a.vertex_positions"])
    params["a.vertex_positions"] = params["a.vertex_positions"] + 3.0
    with pytest.raises(ValueError, match=re.escape(
            "lathe 'a': parameter 'vertex_positions' is the lathe's reference mesh, made from its profile "
            "and transform, and cannot be edited: move the lathe with LatheShape.set_to_world(matrix, "
            "scene), or change its profile through its 'points' parameter")):
        params.update()
    lathe = scene.shapes()[0]
    assert np.array_equal(np.array(mi.traverse(lathe)["vertex_positions"]), before)
    # The lathe's own ways still work.
    lathe.set_to_world(mi.ScalarTransform4f().translate([1.5, 0, 0]), scene)
    moved = np.array(mi.traverse(lathe)["vertex_positions"]).reshape(-1, 3)
    assert abs(moved[:, 0].mean() - 1.5) < 0.05


OPEN_DIELECTRIC = ("lathe '{}': a SmoothDielectric BSDF on an open profile (a single sheet, no inside) whose "
                   "ends meet no other open lathe's: rays refract into a solid that is not there; use "
                   "'thindielectric' for a thin glass sheet, or close the profile")


def test_open_dielectric_sheets_closed_by_each_other_do_not_warn():
    """The filled wine glass's three open dielectric sheets (glass, wine
    under the glass, wine's top) meet at the fill line: no warning. A lone
    open dielectric bowl, and two sheets whose ends do not meet, warn once
    each, naming the lathe."""
    from conftest import SCENES

    from lathe_shape.plugin.shape import warn_open_dielectrics

    text = (SCENES / "wine_glass_filled.xml").read_text()
    assert warn_open_dielectrics(load_string_in(SCENES, text, res="16")) == []

    def sheets(*profiles: str) -> mi.Scene:
        glass = {"type": "dielectric"}
        return mi.load_dict({"type": "scene", **{
            f"sheet{index}": {"type": "lathe", "profile": profile, "open": True, "bsdf": glass}
            for index, profile in enumerate(profiles)}})

    bowl = sheets("0 0, 1 0.2, 1.2 1")
    assert warn_open_dielectrics(bowl) == [OPEN_DIELECTRIC.format("sheet0")]
    assert warn_open_dielectrics(bowl) == []  # once
    # A bowl and a lid meeting at its rim; then a lid 0.01 too high
    assert warn_open_dielectrics(sheets("0 0, 1 0.2, 1.2 1", "1.2 1, 0 1")) == []
    assert warn_open_dielectrics(sheets("0 0, 1 0.2, 1.2 1", "1.2 1.01, 0 1.01")) == [
        OPEN_DIELECTRIC.format("sheet0"), OPEN_DIELECTRIC.format("sheet1")]


def test_a_medium_on_an_open_sheet_warns():
    """An interior medium on an open sheet (a liquid without its surface)
    rendered without a word: rays that pass the free ends miss the medium.
    It warns now, naming the lathe, unless other open sheets close it."""
    from lathe_shape.plugin.shape import warn_open_dielectrics

    def scene(*profiles: str) -> mi.Scene:
        wine = {"type": "homogeneous", "sigma_t": 2.0, "albedo": 0.5}
        return mi.load_dict({"type": "scene", **{
            f"liquid{index}": {"type": "lathe", "profile": profile, "open": True, "bsdf": {"type": "null"},
                               "interior": wine}
            for index, profile in enumerate(profiles)}})

    message = ("lathe 'liquid0': an interior medium on an open profile (a single sheet, no inside) whose "
               "ends meet no other open lathe's: rays that pass its free ends miss the medium; close the "
               "profile, or close the sheet with other open lathes (a liquid's surface)")
    assert warn_open_dielectrics(scene("0 0, 1 0.2, 1.2 1")) == [message]
    assert warn_open_dielectrics(scene("0 0, 1 0.2, 1.2 1", "1.2 1, 0 1")) == []
