"""Turntable modes (orbit, world, spin), denoised frames with their noisy
layer, the ``lathe_path`` guide AOVs and the background frame writer."""

from __future__ import annotations

import sys

import mitsuba as mi
import numpy as np
import OpenEXR
import pytest
from conftest import SCENES, VARIANT

from lathe_shape.cli.turntable import main
from lathe_shape.tools import denoise as dn
from lathe_shape.tools import turntable as tt
from lathe_shape.tools.images import read_exr, relative_error
from lathe_shape.tools.poses import spin_matrix, world_matrix
from lathe_shape.tools.scenes import load_scene
from lathe_shape.tools.world import WorldTurner
from lathe_shape.tools.writer import FrameWriter

WINE = str(SCENES / "wine_glass.xml")
EXACT = {"integrator": "lathe_path", "max_depth": "6"}


def wine(size: int = 32, **defines: str) -> mi.Scene:
    return load_scene(WINE, {**EXACT, **defines}, (size, size))


def wine_without_caustics(size: int = 32) -> mi.Scene:
    """The wine glass with ``caustics`` off: its light-traced particles are
    drawn in the light's frame, which a world turn rotates, so they are not
    the orbit's particles seen from elsewhere (the path-traced samples are)."""
    def edit(text: str, path: str) -> str:
        opening = '<integrator type="$integrator">'
        assert opening in text
        return text.replace(opening, opening + '\n        <boolean name="caustics" value="false"/>')
    return load_scene(WINE, EXACT, (size, size), edit=edit)


def mean_diff(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a - b).mean() / np.abs(b).mean())


def coarse(image: np.ndarray, block: int = 8) -> np.ndarray:
    """Means of block x block pixels: less noise, same large features."""
    h, w = image.shape[0] // block, image.shape[1] // block
    return image[: h * block, : w * block].reshape(h, block, w, block, -1).mean(axis=(1, 3))


def test_orbit_and_world():
    orbit, world = tt.Turntable(wine_without_caustics()), tt.Turntable(wine_without_caustics(), "world")
    assert orbit.mode == "orbit" and world.mode == "world" and not world.warnings
    noise = mean_diff(coarse(orbit.render(0.0, spp=32, seed=1)), coarse(orbit.render(0.0, spp=32, seed=2)))
    o90, w90 = orbit.render(90.0, spp=32, seed=1), world.render(90.0, spp=32, seed=1)
    # The floor's checks and the soft box move the other way round...
    assert mean_diff(coarse(o90), coarse(w90)) > 5.0 * noise
    # ... as the world turns by -a: an untextured lathe then shows what the
    # orbit shows at -a (same seed: equal up to float rounding).
    assert mean_diff(coarse(orbit.render(-90.0, spp=32, seed=1)), coarse(w90)) < 0.1 * noise
    # Poses are absolute: back at 0 the scene is as loaded.
    np.testing.assert_allclose(world.render(0.0, spp=8, seed=1), orbit.render(0.0, spp=8, seed=1),
                               rtol=1e-4, atol=1e-5)


def test_world_turner_moves_emitters_and_shapes():
    scene = mi.load_dict({
        "type": "scene",
        "light": {"type": "point", "position": [2.0, 0.0, 3.0]},
        "box": {"type": "cube", "to_world": mi.ScalarTransform4f().translate([3.0, 0.0, 0.0])},
        "ball": {"type": "sphere", "center": [0.0, 2.0, 0.0], "radius": 0.5},
        "glass": {"type": "lathe", "profile": "0 0, 1 0, 1 1, 0 1"},
    })
    glass = next(s for s in scene.shapes() if s.id() == "glass")
    turner = WorldTurner(scene, glass)
    assert not turner.fixed
    box_before = scene.shapes()[[s.id() for s in scene.shapes()].index("box")].bbox()
    turner.turn(world_matrix(glass.to_world_matrix, 90.0))  # the world turns by -90 degrees
    params = mi.traverse(scene)
    np.testing.assert_allclose(np.ravel(params["light.position"]), [0.0, -2.0, 3.0], atol=1e-6)
    box = next(s for s in scene.shapes() if s.id() == "box").bbox()
    np.testing.assert_allclose([box.min, box.max], [[-1, -4, -1], [1, -2, 1]], atol=1e-5)
    assert tuple(box_before.min) != tuple(box.min)
    np.testing.assert_allclose(glass.to_world_matrix, np.eye(4))  # the lathe stays


TEXTURED = """<scene version="3.0.0">
    <emitter type="constant"/>
    <integrator type="lathe_path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="24"/><integer name="height" value="24"/></film>
        <transform name="to_world"><lookat origin="0, -6, 1" target="0, 0, 1" up="0, 0, 1"/></transform>
    </sensor>
    <shape type="lathe" id="vase">
        <string name="profile" value="0 0, 1 0, 1 2, 0 2"/>
        <bsdf type="diffuse">$texture</bsdf>
    </shape>
</scene>"""
CHECKS = """<texture type="checkerboard" name="reflectance">
    <transform name="to_uv"><scale x="8" y="2"/></transform></texture>"""


def test_spin(tmp_path, capsys):
    textured = mi.load_string(TEXTURED.replace("$texture", CHECKS))
    plain = tmp_path / "plain.xml"
    plain.write_text(TEXTURED.replace("$texture", ""))
    assert tt.is_textured(textured.shapes()[0]) and not tt.is_textured(mi.load_file(str(plain)).shapes()[0])
    spin = tt.Turntable(textured, "rotate")  # the old name still works
    assert spin.mode == "spin" and not spin.warnings
    a, b = spin.render(0.0, spp=4, seed=0), spin.render(22.5, spp=4, seed=0)  # half a check
    still = tt.Turntable(mi.load_file(str(plain)), "spin")
    assert still.warnings and "identical" in still.warnings[0]
    # Same seed: only the texture can make a difference.
    c, d = still.render(0.0, spp=4, seed=0), still.render(22.5, spp=4, seed=0)
    assert mean_diff(a, b) > 0.02 and mean_diff(a, b) > 100.0 * mean_diff(c, d)
    code = main(["--variant", VARIANT, str(plain), "-o", str(tmp_path / "out"), "--count", "2", "--spp", "1",
                 "--mode", "spin"])
    err = capsys.readouterr().err
    assert code == 0 and "warning: lathe 'vase' has no texture" in err and "identical" in err


def test_aovs():
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "lathe_path", "aovs": "albedo,nn"},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 16, "height": 16},
                   "to_world": mi.ScalarTransform4f().look_at([0, -4, 3], [0, 0, 0], [0, 0, 1])},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(20),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.2, 0.5, 0.7]}}},
        "sky": {"type": "constant"},
    })
    assert scene.integrator().aov_names() == ["albedo.R", "albedo.G", "albedo.B", "nn.X", "nn.Y", "nn.Z"]
    image = np.asarray(mi.render(scene, spp=4))
    assert image.shape == (16, 16, 9)
    floor = image[10:]  # the lower rows see the floor
    albedo, normal = floor[..., 3:6].reshape(-1, 3), floor[..., 6:9].reshape(-1, 3)
    np.testing.assert_allclose(albedo, np.broadcast_to([0.2, 0.5, 0.7], albedo.shape), atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=-1), 1.0, atol=1e-4)
    # Up, towards the camera above the floor.
    np.testing.assert_allclose(normal, np.broadcast_to([0, 0, 1], normal.shape), atol=1e-4)
    with pytest.raises(Exception, match="unknown guide 'depth'"):
        mi.load_dict({"type": "lathe_path", "aovs": "albedo,depth"})
    # The glass's own surface is white under aov_through_delta=false.
    glass = wine(16, mesh_segments="16")
    glass.integrator().aovs, glass.integrator().aov_through_delta = ("albedo",), False
    albedo = np.asarray(mi.render(glass, spp=1))[..., 3:6]
    assert albedo.max() == pytest.approx(1.0, abs=1e-3)


@pytest.mark.denoise
def test_denoise(tmp_path, capsys):
    pytest.importorskip("pyoidn")
    out = tmp_path / "turn"
    job = [WINE, "-o", str(out), "--count", "4", "--frames", "1", "--resolution", "48", "-D",
           "integrator=lathe_path", "-D", "max_depth=6", "--denoise", "--mode", "world"]
    code = main(["--variant", VARIANT, *job, "--spp", "4"])
    assert code == 0, capsys.readouterr().err
    path = out / "frame_0001.exr"
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        assert sorted(exr.channels()) == ["B", "G", "R", "noisy.B", "noisy.G", "noisy.R"]
        assert exr.header()["denoiser"] == "oidn" and exr.header()["mode"] == "world"
    denoised = read_exr(path)[0]
    noisy = noisy_layer(path)
    # The same pose and box filter at 256 spp.
    reference = read_reference(tmp_path, capsys, job)
    assert relative_error(denoised, reference) < 0.8 * relative_error(noisy, reference)
    # Resume: a finished denoised frame is skipped.
    assert main(["--variant", VARIANT, *job, "--spp", "4"]) == 0
    assert "skipped 1 already done" in capsys.readouterr().out


def read_reference(tmp_path, capsys, job: list[str]) -> np.ndarray:
    ref = tmp_path / "ref"
    job = [*job[:2], str(ref), *job[3:]]
    assert main(["--variant", VARIANT, *job, "--spp", "256"]) == 0
    capsys.readouterr()
    return noisy_layer(ref / "frame_0001.exr")


def noisy_layer(path) -> np.ndarray:
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return np.stack([exr.channels()[f"noisy.{c}"].pixels for c in "RGB"], axis=-1).astype(np.float32)


@pytest.mark.denoise
def test_denoiser_choice(tmp_path, monkeypatch, capsys):
    pytest.importorskip("pyoidn")
    weights = tmp_path / "nvoptix.bin"
    assert dn.choose_backend("llvm_ad_rgb", str(weights)) == ("oidn", "")
    backend, note = dn.choose_backend("cuda_ad_rgb", str(weights))
    assert backend == "oidn" and "nvoptix.bin" in note and "Open Image Denoise" in note
    weights.write_bytes(b"")
    assert dn.choose_backend("cuda_ad_rgb", str(weights)) == ("optix", "")
    film = '<scene><sensor><film><rfilter type="gaussian"/></film></sensor></scene>'
    assert 'type="box"' in dn.box_filter_xml(film) and "gaussian" not in dn.box_filter_xml(film)
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # as if not installed
    with pytest.raises(dn.DenoiseError, match=r"pip install lathe_shape\[denoise\]"):
        dn.choose_backend("llvm_ad_rgb")
    code = main(["--variant", VARIANT, WINE, "-o", str(tmp_path / "x"), "--denoise"])
    assert code == 2 and "needs Intel Open Image Denoise" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.denoise
def test_prefiltered_guides_are_closer_to_clean_ones():
    pytest.importorskip("pyoidn")
    # Smooth guides plus per-pixel noise, as behind glass at few samples.
    y, x = np.mgrid[0:64, 0:64] / 63.0
    albedo = np.stack([0.2 + 0.6 * x, 0.5 + 0.0 * y, 0.8 - 0.5 * y], axis=-1).astype(np.float32)
    normal = np.stack([x - 0.5, y - 0.5, np.ones_like(x)], axis=-1)
    normal = (normal / np.linalg.norm(normal, axis=-1, keepdims=True)).astype(np.float32)
    rng = np.random.default_rng(1)
    noisy_albedo = albedo + rng.normal(0.0, 0.1, albedo.shape).astype(np.float32)
    noisy_normal = normal + rng.normal(0.0, 0.1, normal.shape).astype(np.float32)
    clean_albedo, clean_normal = dn.prefilter_guides(noisy_albedo, noisy_normal)
    assert clean_albedo.shape == albedo.shape and clean_normal.dtype == np.float32
    assert np.abs(clean_albedo - albedo).mean() < 0.5 * np.abs(noisy_albedo - albedo).mean()
    assert np.abs(clean_normal - normal).mean() < 0.5 * np.abs(noisy_normal - normal).mean()


def test_frame_writer():
    done = []
    with FrameWriter() as writer:
        for k in range(5):
            writer.submit(lambda k=k: done.append(k))
    assert done == list(range(5))
    writer = FrameWriter()
    writer.submit(lambda: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        for _ in range(10):
            writer.submit(lambda: done.append(-1))
        writer.close()
    assert -1 not in done  # nothing runs after a failure


def test_moving_the_lathe_keeps_the_rest_scene():
    scene = wine(16, mesh_segments="16")
    spin = tt.Turntable(scene, "spin")
    spin.render(0.0, spp=1)
    geometry = scene.integrator().geometry(scene)
    rest = geometry.rest
    spin.render(45.0, spp=1)
    assert scene.integrator().geometry(scene) is geometry and geometry.rest is rest
    # Other shapes moved: the same second scene, its structure rebuilt.
    geometry.mark_moved()
    moved = scene.integrator().geometry(scene)
    assert moved is not geometry and moved.rest is rest and moved.matches(scene)


def _lamp_scene(integrator: str, turn: float = 0.0) -> mi.Scene:
    """A clear glass and an emitting textured lathe (the lamp, 1.5 off the
    glass's axis) on a floor; ``turn``: the floor and the lamp turned about
    the glass's axis by that many degrees, as a fresh scene."""
    world = mi.ScalarTransform4f().rotate([0, 0, 1], turn)
    return mi.load_dict({
        "type": "scene", "integrator": {"type": integrator, "max_depth": 4},
        "sensor": {"type": "perspective", "film": {"type": "hdrfilm", "width": 24, "height": 24,
                                                   "rfilter": {"type": "box"}},
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -6, 3], target=[0, 0, 1],
                                                              up=[0, 0, 1])},
        "floor": {"type": "rectangle", "to_world": world @ mi.ScalarTransform4f().scale(5),
                  "bsdf": {"type": "diffuse"}},
        "glass": {"type": "lathe", "profile": "0 0, 0.5 0, 0.5 1, 0 1", "bsdf": {"type": "dielectric"}},
        "lamp": {"type": "lathe", "profile": "0 0, 0.4 0, 0.4 0.8, 0 0.8",
                 "to_world": world @ mi.ScalarTransform4f().translate([1.5, 0.5, 0]),
                 "bsdf": {"type": "diffuse", "reflectance": {
                     "type": "checkerboard", "to_uv": mi.ScalarTransform4f().scale([6, 4, 1])}},
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 3}}}})


@pytest.mark.parametrize("integrator", ["lathe_path", "path"])
def test_emitting_lathes_turn_with_the_frames(integrator):
    """Every integrator traces an emitting lathe as its mesh. The spin and
    world modes moved it without rebuilding the acceleration structure
    under lathe_path: the lamp lost half its light in a spun frame (mean
    0.19 against 0.36) and the floor most of it in a world frame (0.06
    against 0.16). Each frame now equals the scene loaded in its pose."""
    fresh = np.array(mi.render(_lamp_scene(integrator, -90.0), spp=4, seed=0))[..., :3]
    world = tt.Turntable(_lamp_scene(integrator), "world", object_id="glass").render(90.0, spp=4, seed=0)
    assert np.abs(world - fresh).max() < 2e-3 * fresh.max()
    scene = _lamp_scene(integrator)
    lamp = next(shape for shape in scene.shapes() if shape.id() == "lamp")
    turned = spin_matrix(lamp.to_world_matrix, 90.0)  # (about its own axis)
    fresh = np.array(mi.render(scene, spp=4, seed=0))  # (compiled before the move)
    lamp.set_to_world(turned, scene)
    moved = np.array(mi.render(scene, spp=4, seed=0))[..., :3]
    spin = tt.Turntable(_lamp_scene(integrator), "spin", object_id="lamp").render(90.0, spp=4, seed=0)
    assert np.abs(spin - moved).max() < 2e-3 * moved.max() and np.abs(moved - fresh[..., :3]).mean() > 0.01


def test_set_to_world_needs_the_scene():
    scene = _lamp_scene("lathe_path")
    glass, lamp = (next(s for s in scene.shapes() if s.id() == name) for name in ("glass", "lamp"))
    with pytest.raises(ValueError, match=r"lathe 'glass': set_to_world: pass the scene that holds the lathe"):
        glass.set_to_world(np.eye(4))
    with pytest.raises(ValueError, match=r"lathe 'lamp': set_to_world: the lathe emits light"):
        lamp.set_to_world(np.eye(4), exact_only=True)
    glass.set_to_world(np.eye(4), exact_only=True)  # (lathe_path's fast path: no mesh rebuild)


@pytest.mark.denoise
@pytest.mark.skipif(not VARIANT.startswith("llvm") or "llvm_ad_spectral" not in mi.variants(),
                    reason="needs the llvm_ad_spectral variant")
def test_denoise_with_lathe_path_in_a_spectral_variant(tmp_path):
    """lathe_path's own guides are RGB: in a spectral variant --denoise
    failed inside the render ("mitsuba.Spectrum does not have a 'x'
    component"); it takes Mitsuba's aov guides there, as stock path does."""
    import subprocess

    result = subprocess.run(
        [sys.executable, "-m", "lathe_shape.cli.turntable", str(SCENES / "crystal_fire.xml"), "-o",
         str(tmp_path / "turn"), "--count", "2", "--frames", "0", "--spp", "1", "--resolution", "16",
         "--variant", "llvm_ad_spectral", "--denoise", "-D", "integrator=lathe_path"],
        capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "rendered 1 frame(s)" in result.stdout and (tmp_path / "turn" / "frame_0000.exr").is_file()
