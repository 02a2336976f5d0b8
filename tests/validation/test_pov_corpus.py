"""POV-Ray's own example scenes (Debian's povray-examples): every lathe and
sor object of the 11 scenes that have them imports with its placement in
the scene, and renders the silhouette POV-Ray renders; glasschess.pov's six
pieces come through its #include; the --scene output renders as is.

Silhouettes: each imported object (its profile and its world transform)
against POV-Ray's render of the object's block as POV-Ray reads it (the
original spline keyword and points, under the same world matrix),
orthographic, flat white on black, without anti-aliasing; the exact
kernel's hits of the imported shapes (a cut-off loop included) give ours.
IoU >= 0.95 over the pixels off POV-Ray's outline (the object fills the
frame), and at most 0.5% of the object's pixels differing off that outline
(measured: none, for all 26; a 3% error of scale, or a shift of 2% of the
frame, fails). POV-Ray's renders are cached
for the test session. Skipped where povray-examples (or, for the
silhouettes, povray) is not installed.
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import VARIANT

from lathe_shape.cli import profile as cli
from lathe_shape.profiles import read_points, read_profile_options
from lathe_shape.profiles.pov import read_pov_objects, to_world
from lathe_shape.validation.povray_compare import render_povray

EXAMPLES = Path("/usr/share/doc/povray/examples")
pytestmark = pytest.mark.skipif(not (EXAMPLES / "objects" / "lathe2.pov").is_file(),
                                reason="povray-examples (Debian package) is not installed")

#: The scenes of povray-examples whose text names lathe or sor, and their
#: objects (20), then glasschess.pov's pieces (6, in chesspiece1.inc).
CORPUS = {
    "advanced/abyss.pov": ["MineCollar"],
    "incdemo/i_internal.pov": [],
    "language/trace-wicker.pov": ["BottleLathe"],
    "objects/lathe1a.pov": ["lathe1a_lathe1"],
    "objects/lathe1b.pov": ["lathe1b_lathe1"],
    "objects/lathe1c.pov": ["lathe1c_lathe1"],
    "objects/lathe2.pov": ["shape1", "shape2", "shape3", "shape4"],
    "objects/sor1.pov": ["Glas1", "Glas2", "Glas3", "Glas4", "Glas5", "Glas6"],
    "portfolio/allobjects.pov": ["allobjects_lathe1", "allobjects_lathe2", "allobjects_sor1"],
    "radiosity/patio-radio_36.pov": ["Spindle_01"],
    "radiosity/patio-radio_37.pov": ["Spindle_01"],
}
GLASSCHESS = "advanced/glasschess/glasschess.pov"
PIECES = ["Koning", "Dame", "Loper", "Paard", "Toren", "Pion"]
RES = 80


def _scale_translate(s, t):
    m = np.diag([*s, 1.0])
    m[:3, 3] = t
    return m


#: World transforms (POV-Ray axes) read off the scene text by hand.
PLACEMENTS = {
    ("language/trace-wicker.pov", "BottleLathe"): _scale_translate([50] * 3, [0, 0, 0]),
    ("objects/lathe2.pov", "shape1"): _scale_translate([15] * 3, [-10, 0.002, 10]),
    ("objects/sor1.pov", "Glas1"): _scale_translate([10] * 3, [-15, 0.001, 15]),
    ("objects/sor1.pov", "Glas2"): _scale_translate([8] * 3, [0, 0.001, 15]),
    ("radiosity/patio-radio_36.pov", "Spindle_01"): _scale_translate([60] * 3, [-500, 550, -500]),
    ("objects/lathe1a.pov", "lathe1a_lathe1"): np.eye(4),
}


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """{scene: (exit status, stdout, stderr, output folder)} of
    ``lathe-profile --from-pov`` on every corpus scene."""
    import contextlib
    import io

    root = tmp_path_factory.mktemp("corpus")
    results = {}
    for scene in [*CORPUS, GLASSCHESS]:
        out = root / Path(scene).stem
        stdout, stderr = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            try:
                rc = cli.main(["--from-pov", str(EXAMPLES / scene), "-o", str(out)])
            except SystemExit as e:
                rc = e.code
        results[scene] = (rc, stdout.getvalue(), stderr.getvalue(), out)
    return results


def test_every_corpus_object_imports(imported):
    lines = {}
    for scene, names in CORPUS.items():
        rc, out, err, folder = imported[scene]
        if not names:  # i_internal.pov: "lathe" in comments only
            assert rc != 0 and "no lathe or sor object found" in err
            continue
        for name in names:
            line = next((x for x in out.splitlines() if f"'{name}'" in x), None)
            assert line is not None, (scene, name, out)
            lines[(scene, name)] = line
    ok = [k for k, line in lines.items() if "not imported" not in line]
    assert len(lines) == 20
    assert len(ok) == 20, [lines[k] for k in lines if k not in ok]
    # Each line names the file and line of the block.
    for line in lines.values():
        assert re.match(rf"{re.escape(str(EXAMPLES))}/.+\.(pov|inc):\d+: (lathe|sor) '", line), line
    # The old refusals, now read: the repeated control point (a loop POV-Ray
    # renders), 'translate -y*0.363', the enclosing difference named.
    assert "warning: the curve crosses itself" in imported["objects/lathe2.pov"][2]
    assert "difference at" in imported["objects/lathe1a.pov"][2]
    assert "1 other object not imported" in imported["objects/lathe1a.pov"][2]


def test_glasschess_pieces_come_through_the_include(imported):
    rc, out, err, folder = imported[GLASSCHESS]
    assert rc == 0, out + err
    for name in PIECES:
        assert re.search(rf"chesspiece1\.inc:\d+: lathe '{name}': catmull_rom", out), (name, out)
        assert (folder / f"{name}.csv").is_file() and (folder / f"{name}.xml").is_file()


@pytest.mark.parametrize(("scene", "name"), sorted(PLACEMENTS))
def test_placements(imported, scene, name):
    blocks, _ = read_pov_objects(EXAMPLES / scene)
    block = next(b for b in blocks if b.name == name)
    np.testing.assert_allclose(block.transform, PLACEMENTS[scene, name], atol=1e-9)
    # The snippet carries it (Mitsuba axes).
    xml = (imported[scene][3] / f"{name}.xml").read_text()
    matrix = re.search(r'<matrix value="([^"]+)"', xml).group(1)
    np.testing.assert_allclose(np.array(matrix.split(), float).reshape(4, 4),
                               to_world(PLACEMENTS[scene, name]), atol=1e-6)


def _objects():
    out = [(scene, name) for scene, names in CORPUS.items() for name in names]
    return out + [(GLASSCHESS, name) for name in PIECES]


def _view(block):
    """Orthographic camera (POV-Ray axes) framing the block's world box
    tightly: (location, direction, right, up, width, center)."""
    p = block.points
    r, lo, hi = float(np.abs(p[:, 0]).max()), float(p[:, 1].min()), float(p[:, 1].max())
    local = np.array([[sx * r, h, sz * r, 1.0] for sx in (-1, 1) for sz in (-1, 1) for h in (lo, hi)])
    world = (block.transform @ local.T).T[:, :3]
    d = np.array([0.3, -0.45, 1.0])
    d /= np.linalg.norm(d)
    right = np.cross([0.0, 1.0, 0.0], d)
    right /= np.linalg.norm(right)
    up = np.cross(d, right)
    a, b = world @ right, world @ up
    width = 1.05 * max(np.ptp(a), np.ptp(b))
    center = 0.5 * (a.min() + a.max()) * right + 0.5 * (b.min() + b.max()) * up + (world @ d).mean() * d
    location = center - 2 * (width + float(np.ptp(world @ d))) * d
    return location, d, right, up, width, center


_POV_KEYWORD = {"polyline": "linear_spline", "quadratic": "quadratic_spline",
                "catmull_rom": "cubic_spline", "bezier": "bezier_spline"}


def _povray_block(block) -> str:
    m = block.transform
    rows = np.vstack([m[:3, :3].T, m[:3, 3]]).ravel()
    points = ", ".join(f"<{a:.17g}, {b:.17g}>" for a, b in block.points)
    head = "sor {" if block.object == "sor" else f"lathe {{ {_POV_KEYWORD[block.kind]}"
    extra = " open" if block.object == "sor" and block.open_sheet else ""
    return (f"{head} {len(block.points)}, {points}{extra}\n matrix <{', '.join(f'{v:.17g}' for v in rows)}>"
            f"\n pigment {{ rgb 1 }} finish {{ ambient 1 diffuse 0 }} }}\n")


_POVRAY_CACHE: dict[str, np.ndarray] = {}


def _povray_mask(folder: Path, block) -> np.ndarray:
    text = _povray_block(block)
    if text in _POVRAY_CACHE:
        return _POVRAY_CACHE[text]
    location, _, _, _, width, center = _view(block)
    scene = folder / "mask.pov"
    scene.write_text(
        "#version 3.7;\nglobal_settings { assumed_gamma 1.0 }\n"
        f"camera {{ orthographic location <{', '.join(f'{v:.17g}' for v in location)}> "
        f"look_at <{', '.join(f'{v:.17g}' for v in center)}> right x*{width:.17g} up y*{width:.17g} }}\n"
        "background { color rgb 0 }\n" + text)
    image, _ = render_povray(scene, (RES, RES), 1, threads=2)
    _POVRAY_CACHE[text] = image[..., 0] > 0.5
    return _POVRAY_CACHE[text]


def _exact_mask(folder: Path, block, view=None) -> np.ndarray:
    location, d, right, up, width, _ = view or _view(block)
    j, i = np.mgrid[0:RES, 0:RES]
    u, v = (i.ravel() + 0.5) / RES - 0.5, 0.5 - (j.ravel() + 0.5) / RES
    org = location + width * (u[:, None] * right + v[:, None] * up)
    swap = [0, 2, 1]  # POV-Ray (x, y, z) is (x, z, y) here
    ray = mi.Ray3f(mi.Point3f(org[:, swap].T.astype(np.float32)),
                   mi.Vector3f(np.tile(d[swap], (len(org), 1)).T.astype(np.float32)))
    mask = np.zeros(RES * RES, bool)
    profiles = [folder / f"{block.name}.csv"] + sorted(folder.glob(f"{block.name}_loop*.csv"))
    for csv in profiles:
        options = read_profile_options(str(csv))
        points = read_points(str(csv))[0]
        shape = mi.load_dict({"type": "lathe", "kind": options.get("kind", "polyline"),
                              "open": bool(options.get("open", False)),
                              "profile": ", ".join(f"{r:.17g} {h:.17g}" for r, h in points),
                              "to_world": mi.ScalarTransform4f(to_world(block.transform)),
                              "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse"}}})
        si = shape.ray_intersect_exact(ray)
        dr.eval(si.t)
        mask |= si.is_valid().numpy()
    return mask.reshape(RES, RES)


@pytest.mark.skipif(shutil.which("povray") is None, reason="povray is not installed")
@pytest.mark.parametrize(("scene", "name"), _objects(), ids=lambda v: os.path.basename(str(v)))
@pytest.mark.povray
@pytest.mark.slow
def test_silhouettes_match_povray(imported, tmp_path, scene, name):
    blocks, _ = read_pov_objects(EXAMPLES / scene)
    block = next(b for b in blocks if b.name == name)
    folder = imported[scene][3]
    pov = _povray_mask(tmp_path, block)
    ours = _exact_mask(folder, block)
    assert ours.sum() > 50, (scene, name)
    edge = np.zeros_like(pov)  # POV-Ray's outline
    for axis in (0, 1):
        for shift in (1, -1):
            edge |= pov != np.roll(pov, shift, axis=axis)
    inter = (pov & ours & ~edge).sum()
    union = ((pov | ours) & ~edge).sum()
    iou = inter / max(union, 1)
    wrong = int(((pov != ours) & ~edge).sum())
    print(f"{scene} {name}: IoU {iou:.4f}, {wrong} pixels differ off the outline")
    assert iou >= 0.95, (scene, name, iou)
    assert wrong <= 0.005 * pov.sum(), (scene, name, wrong, np.argwhere((pov != ours) & ~edge)[:5])


@pytest.mark.slow
def test_scene_output_renders(tmp_path, capsys):
    from lathe_shape.cli import render

    scene = tmp_path / "lathe2_scene.xml"
    assert cli.main(["--from-pov", str(EXAMPLES / "objects/lathe2.pov"), "-o", str(tmp_path / "p"),
                     "--scene", str(scene)]) == 0
    text = scene.read_text()
    assert '<scene version="3.0.0">' in text and 'value="lathe_path"' in text
    assert f"lathe-render {scene} -D spp=64 -D res=512 -->" in text  # (was "{this file}")
    assert text.count('<shape type="lathe"') == 5  # shape1's loop is a shape of its own
    assert 'type="conductor"' in text  # finish { Shiny metallic }
    capsys.readouterr()
    assert render.main([str(scene), "-D", "res=8", "-D", "spp=1", "-o", str(tmp_path / "r"),
                        "--variant", VARIANT]) == 0
    image = mi.Bitmap(str(tmp_path / "r" / "lathe2_scene.exr"))
    assert np.isfinite(np.array(image)).all() and np.array(image)[..., :3].max() > 0
