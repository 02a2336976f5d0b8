"""The commands' image files hold every channel the film produced, under
Mitsuba's names (luminance, rgba and AOV films), and their PNG previews show
the image itself; turntable frames of one channel resume."""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import OpenEXR
import pytest
from conftest import VARIANT
from PIL import Image

from lathe_shape.cli import render, turntable
from lathe_shape.tools.frames import frame_state, plan_frames, write_frame
from lathe_shape.tools.images import read_exr, to_srgb8, write_images

MONO = "_mono" in VARIANT

#: A lathe in front of a black background (no emitter behind it: alpha is 0
#: there and 1 on the lathe), lit by a point light.
SCENE = """<scene version="3.0.0">
    <integrator type="{integrator}">{aovs}</integrator>
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,-6,1" target="0,0,1" up="0,0,1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="2"/></sampler>
        <film type="hdrfilm"><string name="pixel_format" value="{pixel_format}"/>
            <integer name="width" value="12"/><integer name="height" value="10"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="point"><point name="position" x="2" y="-4" z="4"/>
        <rgb name="intensity" value="40"/></emitter>
    <shape type="lathe" id="vase"><string name="profile" value="0 0, 1 0, 1.1 1, 0.6 2, 0 2"/>
        <bsdf type="diffuse"/></shape>
</scene>"""


def exr_channels(path) -> dict[str, np.ndarray]:
    """Every channel of an EXR file, by name."""
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return {name: np.array(channel.pixels) for name, channel in exr.channels().items()}


def mitsuba_channels(scene_path) -> list[str]:
    """The channel names Mitsuba gives the film of ``scene_path`` after
    ``mi.render`` (``film.bitmap()``, what Mitsuba's own writer stores)."""
    scene = mi.load_file(str(scene_path))
    mi.render(scene, spp=1)
    bitmap = scene.sensors()[0].film().bitmap()
    return [bitmap.struct_()[index].name for index in range(bitmap.channel_count())]


def render_scene(tmp_path, capsys, pixel_format: str, integrator: str = "path", aovs: str = "",
                 nested: str = "") -> str:
    """``lathe-render`` on :data:`SCENE` (``nested``: XML inside the
    integrator); returns the stem of the files written."""
    scene = tmp_path / "vase.xml"
    aov_xml = (f'<string name="aovs" value="{aovs}"/>' if aovs else "") + nested
    scene.write_text(SCENE.format(integrator=integrator, aovs=aov_xml, pixel_format=pixel_format))
    code = render.main(["--variant", VARIANT, str(scene), "-o", str(tmp_path), "--seed", "1"])
    assert code == 0, capsys.readouterr().err
    assert sorted(exr_channels(tmp_path / "vase.exr")) == sorted(mitsuba_channels(scene))
    return str(tmp_path / "vase")


def test_luminance_film_gives_y_and_gray_png(tmp_path, capsys):
    stem = render_scene(tmp_path, capsys, "luminance")
    channels = exr_channels(stem + ".exr")
    assert list(channels) == ["Y"] and channels["Y"].shape == (10, 12) and channels["Y"].max() > 0
    png = Image.open(stem + ".png")
    assert png.mode == "L"
    assert np.array_equal(np.asarray(png), to_srgb8(channels["Y"][..., None])[..., 0])
    assert read_exr(stem + ".exr")[0].shape == (10, 12, 1)


def test_rgba_film_keeps_alpha(tmp_path, capsys):
    stem = render_scene(tmp_path, capsys, "rgba")
    channels = exr_channels(stem + ".exr")
    if MONO:  # Mitsuba's mono variants render every film as luminance
        assert list(channels) == ["Y"]
        return
    assert sorted(channels) == ["A", "B", "G", "R"]
    alpha = channels["A"]
    assert alpha.min() == 0.0 and alpha.max() > 0.99  # background and lathe
    png = np.asarray(Image.open(stem + ".png"))
    assert png.shape == (10, 12, 4)
    assert np.array_equal(png[..., 3], np.round(np.clip(alpha, 0, 1) * 255).astype(np.uint8))


@pytest.mark.skipif(MONO, reason="lathe_path's aovs stop a mono variant's render (std::bad_cast)")
def test_integrator_aovs_are_kept(tmp_path, capsys):
    stem = render_scene(tmp_path, capsys, "rgb", integrator="lathe_path", aovs="albedo,nn")
    channels = exr_channels(stem + ".exr")
    albedo = ["albedo.R", "albedo.G", "albedo.B"]
    assert sorted(channels) == sorted(["R", "G", "B", *albedo, "nn.X", "nn.Y", "nn.Z"])
    # Pixel means: unit normals and the diffuse BSDF's albedo 0.5 where the
    # lathe covers the whole pixel (its centre), less at its outline.
    length = np.linalg.norm(np.stack([channels[f"nn.{axis}"] for axis in "XYZ"], axis=-1), axis=-1)
    assert length.max() <= 1.001 and abs(length[5, 6] - 1.0) < 1e-2
    assert channels[albedo[0]].max() <= 0.501 and abs(channels[albedo[0]][5, 6] - 0.5) < 1e-3
    assert Image.open(stem + ".png").mode == "RGB"  # the AOVs are left out


def test_aov_integrator_channels(tmp_path, capsys):
    """Mitsuba's ``aov`` integrator around another one: ``mi.render``
    returns fewer channels than the film holds; the EXR has the film's."""
    stem = render_scene(tmp_path, capsys, "rgb", integrator="aov", aovs="dd.y:depth",
                        nested='<integrator type="path" name="image"/>')
    channels = exr_channels(stem + ".exr")
    assert "dd.y.T" in channels and channels["dd.y.T"].max() > 4.0  # the lathe is 5-6 units away
    assert Image.open(stem + ".png").mode == ("L" if MONO else "RGB")


def test_write_images_checks_names(tmp_path):
    with pytest.raises(ValueError, match="^an image of 5 channels needs channel names"):
        write_images(str(tmp_path / "x"), np.zeros((2, 2, 5)))
    with pytest.raises(ValueError, match="^2 channel names for an image of 3 channels$"):
        write_images(str(tmp_path / "x"), np.zeros((2, 2, 3)), channels=["R", "G"])
    assert list(tmp_path.iterdir()) == []


def test_one_channel_frames_are_written_and_resumed(tmp_path):
    """A frame of a luminance film (or a mono variant), denoised or not."""
    frame = plan_frames(4, [1], tmp_path)[0]
    luminance = np.linspace(0.0, 1.0, 6 * 8, dtype=np.float32).reshape(6, 8, 1)
    write_frame(frame, luminance, {"spp": 3}, noisy=luminance * 0.5)
    channels = exr_channels(frame.exr)
    assert sorted(channels) == ["Y", "noisy.Y"]
    assert np.allclose(channels["noisy.Y"], luminance[..., 0] * 0.5, atol=1e-3)
    assert Image.open(frame.png).mode == "L"
    assert frame_state(frame, {"spp": 3}, (8, 6)) == "done"
    assert frame_state(frame, {"spp": 3}, (8, 7)) == "stale"


@pytest.mark.denoise
def test_turntable_denoise_needs_rgb(tmp_path, capsys):
    pytest.importorskip("pyoidn")  # (without a denoiser, that error comes first)
    scene = tmp_path / "vase.xml"
    scene.write_text(SCENE.format(integrator="path", aovs="", pixel_format="luminance"))
    code = turntable.main(["--variant", VARIANT, str(scene), "-o", str(tmp_path / "out"), "--count", "2",
                           "--denoise"])
    why = f"variant {VARIANT} renders luminance only" if MONO else "its pixel_format is not rgb or rgba"
    assert code == 2 and capsys.readouterr().err == (
        f"lathe-turntable: error: {scene}: --denoise needs an RGB film, and the film has 1 channel(s) "
        f"({why})\n")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("names", [("R", "G", "B", "A"), ("Y",), ("Y", "A"),
                                   ("R", "G", "B", "A", "albedo.R", "albedo.G", "albedo.B")])
def test_read_exr_reads_what_write_exr_writes(tmp_path, names):
    """read_exr gives the RGB (or Y) of every channel layout write_exr
    writes: rgba and luminance(+alpha) films, AOVs after the image."""
    from lathe_shape.tools.images import read_exr, write_exr

    rng = np.random.default_rng(1)
    image = rng.random((4, 5, len(names)), dtype=np.float32)
    write_exr(tmp_path / "x.exr", image, channels=names)
    pixels, _ = read_exr(tmp_path / "x.exr")
    colour = 1 if names[0] == "Y" else 3
    assert pixels.shape == (4, 5, colour)
    assert np.array_equal(pixels, image[..., :colour])
