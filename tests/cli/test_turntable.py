"""``lathe-turntable``: frame planning, transforms, resume, sharding,
metadata, animations and clear errors."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import mitsuba as mi
import numpy as np
import OpenEXR
import pytest
from conftest import SCENES, VARIANT

from lathe_shape.cli.common import CliError
from lathe_shape.cli.turntable import main, parse_frames
from lathe_shape.tools import frames, poses
from lathe_shape.tools import turntable as tt
from lathe_shape.tools.images import read_exr
from lathe_shape.tools.scenes import load_scene

WINE = str(SCENES / "wine_glass.xml")
FAST = ["--spp", "2", "--resolution", "24x24", "-D", "mesh_segments=16", "-D", "max_depth=4"]

# A pentagonal prism (a lathe tessellated with 5 segments) placed off the
# world origin: spinning it about its own axis changes the image, unlike a
# finely tessellated lathe. `knob` is a second lathe for --object. A single
# directional light keeps the noise low.
PRISM_XML = """<scene version="3.0.0">
    <default name="spp" value="2"/>
    <default name="res" value="24"/>
    <default name="max_depth" value="4"/>
    <default name="mesh_segments" value="16"/>
    <default name="integrator" value="path"/>
    <integrator type="$integrator"><integer name="max_depth" value="$max_depth"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="35"/>
        <transform name="to_world"><lookat origin="0, -9, 4" target="2, 0, 1" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="$res"/><integer name="height" value="$res"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="directional">
        <vector name="direction" value="1, 2, -3"/>
        <rgb name="irradiance" value="3, 3, 3"/>
    </emitter>
    <shape type="lathe" id="prism">
        <string name="profile" value="0 0, 1.2 0, 1.2 2, 0 2"/>
        <boolean name="smooth" value="false"/>
        <integer name="mesh_segments" value="5"/>
        <transform name="to_world"><translate x="2.5" y="0.5"/></transform>
        <bsdf type="diffuse"/>
    </shape>
    <shape type="lathe" id="knob">
        <string name="profile" value="0 0, 0.5 0, 0.5 0.5, 0 0.5"/>
        <integer name="mesh_segments" value="$mesh_segments"/>
        <transform name="to_world"><translate x="-1"/></transform>
    </shape>
</scene>
"""


@pytest.fixture
def prism(tmp_path) -> str:
    path = tmp_path / "prism.xml"
    path.write_text(PRISM_XML)
    return str(path)


def run(capsys, *args: str) -> tuple[int, str, str]:
    """``lathe-turntable ARGS`` in-process, in the test suite's variant."""
    code = main(["--variant", VARIANT, *args])
    captured = capsys.readouterr()
    if code:
        print(captured.err)  # (shown with a failing test)
    return code, captured.out, captured.err


def frames_in(folder) -> list[str]:
    return sorted(p for p in os.listdir(folder) if p.startswith("frame_"))


def pixels(folder, index: int) -> np.ndarray:
    return read_exr(os.path.join(folder, f"frame_{index:04d}.exr"))[0]


# -- planning and transforms (no rendering) -----------------------------------


def test_parse_frames():
    assert parse_frames(None, 24) == range(24)
    assert parse_frames("0:12", 24) == range(0, 12)
    assert parse_frames("12:", 24) == range(12, 24)
    assert parse_frames(":5", 24) == range(0, 5)
    assert parse_frames("7", 24) == range(7, 8)
    assert parse_frames("20:30", 24) == range(20, 24)  # clipped like a slice
    for bad, message in [("a:b", "integers"), ("1:2:3", "no step"), ("5:5", "selects no frame"),
                         ("30:40", "selects no frame"), ("-1:3", "must not be negative"), (":", None)]:
        if message is None:
            assert parse_frames(bad, 4) == range(4)
            continue
        with pytest.raises(CliError, match=message):
            parse_frames(bad, 24)
    with pytest.raises(CliError, match="--count must be at least 1"):
        parse_frames(None, 0)


def test_plan_frames(tmp_path):
    plan = frames.plan_frames(8, range(2, 4), tmp_path, seed=10)
    assert [f.index for f in plan] == [2, 3] and [f.seed for f in plan] == [12, 13]
    assert [f.angle_deg for f in plan] == [90.0, 135.0]
    assert plan[0].exr == str(tmp_path / "frame_0002.exr") and plan[0].png.endswith("frame_0002.png")
    assert frames.plan_frames(12345, [7], tmp_path)[0].exr.endswith("frame_00007.exr")


def test_transforms():
    # A tilted, moved lathe frame (rigid).
    tilt = poses.rotation_about_axis(np.zeros(3), [1.0, 0.3, 0.0], 25.0)
    lathe = tilt.copy()
    lathe[:3, 3] = [1.0, -2.0, 0.5]
    origin, axis = poses.lathe_axis(lathe)
    np.testing.assert_allclose(origin, [1.0, -2.0, 0.5])
    np.testing.assert_allclose(axis, tilt[:3, 2])
    np.testing.assert_array_equal(poses.rotate_z(360.0), np.eye(4))
    np.testing.assert_array_equal(poses.rotation_about_axis(origin, axis, 0.0), np.eye(4))
    for angle in (float("nan"), float("inf")):  # (a numpy conversion error before)
        with pytest.raises(ValueError, match="a turntable angle must be a finite number of degrees"):
            poses.rotate_z(angle)
        with pytest.raises(ValueError, match="a turntable angle must be a finite number of degrees"):
            poses.spin_matrix(lathe, angle)

    spun = poses.spin_matrix(lathe, 70.0)
    np.testing.assert_allclose(spun[:3, 3], lathe[:3, 3])  # spins in place
    np.testing.assert_allclose(spun[:3, 2], lathe[:3, 2])  # about its own axis
    assert not np.allclose(spun, lathe)
    # Points on the axis stay put under the world-space rotation.
    rot = poses.rotation_about_axis(origin, axis, 33.0)
    on_axis = np.append(origin + 2.5 * axis, 1.0)
    np.testing.assert_allclose(rot @ on_axis, on_axis, atol=1e-12)

    # Orbiting the camera shows the lathe from the same side as spinning it.
    camera = np.eye(4)
    camera[:3, 3] = [0.0, -10.0, 3.0]
    orbit = poses.orbit_matrix(camera, lathe, 70.0)
    np.testing.assert_allclose(np.linalg.inv(orbit) @ lathe, np.linalg.inv(camera) @ spun, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(orbit[:3, 3] - origin), np.linalg.norm(camera[:3, 3] - origin))


def test_lathes_in_file_order(tmp_path):
    # Mitsuba's scene.shapes() keeps no order; the default lathe is the
    # file's first one, with or without id.
    lathe = '<shape type="lathe" {}><string name="profile" value="0 0, 1 0, 1 1, 0 1"/></shape>'
    for ids in (["z", "a", "", "m"], ["", "q", "b"], ["b", "a"]):
        body = "".join(lathe.format(f'id="{i}"' if i else "") for i in ids)
        path = tmp_path / "order.xml"
        path.write_text(f'<scene version="3.0.0"><shape type="rectangle" id="r"/>{body}</scene>')
        scene = mi.load_file(str(path))
        assert [s.id() for s in tt.lathes_in_file_order(scene, path)] == ids


# -- rendering ----------------------------------------------------------------


def test_frames_and_metadata(tmp_path, capsys):
    out = tmp_path / "turn"  # created by the tool
    code, stdout, stderr = run(capsys, WINE, "-o", str(out), "--count", "2", "--seed", "5", "--mode", "spin",
                               "--seeds", "frame", *FAST)
    assert code == 0, stderr
    assert frames_in(out) == ["frame_0000.exr", "frame_0000.png", "frame_0001.exr", "frame_0001.png"]
    assert "rendered 2 frame(s), skipped 0" in stdout and str(out) in stdout
    assert "2/2 frames" in stderr and "ETA" in stderr  # the progress bar
    rgb, header = read_exr(out / "frame_0001.exr")
    assert rgb.shape == (24, 24, 3) and np.isfinite(rgb).all() and rgb.mean() > 0
    expected = {"frame": 1, "count": 2, "angle_deg": 180.0, "spp": 2, "integrator": "PathIntegrator",
                "seed": 6, "mode": "spin", "object": "wine_glass"}
    assert {k: header[k] for k in expected} == expected
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    with OpenEXR.File(str(out / "frame_0001.exr")) as exr:
        assert exr.channels()["RGB"].pixels.dtype == np.float16
    assert not [p for p in os.listdir(out) if p.startswith(".")]  # no temporary files left


def test_resume_skips_finished_frames(tmp_path, capsys):
    out = tmp_path / "turn"
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", "--frames", "0:2", *FAST)
    assert code == 0 and "frames 0:2" in stdout and "rendered 2 frame(s)" in stdout
    assert frames_in(out) == [f"frame_{i:04d}.{e}" for i in (0, 1) for e in ("exr", "png")]
    mtimes = {p: os.stat(out / p).st_mtime_ns for p in frames_in(out)}
    time.sleep(0.02)
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", *FAST)
    assert code == 0 and "rendered 2 frame(s), skipped 2 already done" in stdout
    assert len(frames_in(out)) == 8
    assert {p: os.stat(out / p).st_mtime_ns for p in mtimes} == mtimes  # frames 0, 1 untouched

    # A truncated EXR (an interrupted copy, say) is rendered again; so is a
    # frame of another job (different spp) and everything with --force.
    data = (out / "frame_0002.exr").read_bytes()
    (out / "frame_0002.exr").write_bytes(data[: len(data) // 2])
    (out / "turntable.gif").write_bytes(b"GIF89a")  # (an earlier run's animation of these frames)
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", *FAST)
    assert code == 0 and "rendered 1 frame(s), skipped 3" in stdout
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", "--frames", "3", *FAST[2:],
                          "--spp", "3")
    assert code == 0 and "1 frame(s) of a different job" in stdout and "rendered 1 frame(s)" in stdout
    assert read_exr(out / "frame_0003.exr")[1]["spp"] == 3
    # (the animation showed the other job's frame: it was left behind, stale)
    assert "turntable.gif of that job removed" in stdout and not (out / "turntable.gif").exists()
    # So is a frame of another sampler (--multijitter, same spp).
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", "--frames", "3", *FAST[2:],
                          "--spp", "4")
    assert code == 0 and "rendered 1 frame(s)" in stdout
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", "--frames", "3", *FAST[2:],
                          "--spp", "4", "--multijitter")
    assert code == 0 and "1 frame(s) of a different job" in stdout
    assert read_exr(out / "frame_0003.exr")[1]["sampler"] == "MultijitterSampler"
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "4", "--frames", "0:2", "--force", *FAST)
    assert code == 0 and "rendered 2 frame(s), skipped 0" in stdout


def test_resume_renders_again_after_a_change_of_look(tmp_path, capsys):
    """A -D value, the variant or an edited scene or profile file made no
    other job: a user adjusting the look with -D and running again got the
    old frames, called finished."""
    import shutil

    shutil.copy(SCENES / "wine_glass.xml", tmp_path / "glass.xml")
    shutil.copy(SCENES / "wine_glass.csv", tmp_path / "wine_glass.csv")
    scene, out = str(tmp_path / "glass.xml"), str(tmp_path / "turn")
    job = [scene, "-o", out, "--count", "2", "--frames", "0", *FAST]
    assert run(capsys, *job)[0] == 0
    code, stdout, _ = run(capsys, *job)
    assert code == 0 and "rendered 0 frame(s), skipped 1" in stdout
    code, stdout, _ = run(capsys, *job, "-D", "mesh_segments=24")  # (the later -D wins)
    assert code == 0 and "1 frame(s) of a different job" in stdout and "rendered 1 frame(s)" in stdout
    assert read_exr(os.path.join(out, "frame_0000.exr"))[1]["defines"] == "max_depth=4; mesh_segments=24"
    profile = tmp_path / "wine_glass.csv"
    text = profile.read_text()
    assert "\n0.000000," in text
    profile.write_text(text.replace("\n0.000000,", "\n0.0,", 1))  # (the same points, other bytes)
    code, stdout, _ = run(capsys, *job, "-D", "mesh_segments=24")
    assert code == 0 and "1 frame(s) of a different job" in stdout


def check_shards(tmp_path, capsys, name: str, job: list[str]) -> tuple[str, str]:
    single, sharded = tmp_path / f"{name}_single", tmp_path / f"{name}_sharded"
    assert run(capsys, *job, "-o", str(single))[0] == 0
    assert run(capsys, *job, "-o", str(sharded), "--frames", "2:4")[0] == 0  # any order
    assert run(capsys, *job, "-o", str(sharded), "--frames", ":2")[0] == 0
    assert frames_in(single) == frames_in(sharded) == [
        f"frame_{i:04d}.{e}" for i in range(4) for e in ("exr", "png")
    ]
    return single, sharded


def test_shards_equal_single_run(tmp_path, capsys, prism):
    # Same frame index => same pose and seed => the identical image: the
    # prism scene's box filter keeps every pixel's sum in one thread.
    single, sharded = check_shards(tmp_path, capsys, "box", [prism, "--count", "4", "--seed", "3", *FAST])
    for i in range(4):
        np.testing.assert_array_equal(pixels(single, i), pixels(sharded, i))
        assert (single / f"frame_{i:04d}.png").read_bytes() == (sharded / f"frame_{i:04d}.png").read_bytes()
    # The wine glass's gaussian filter sums splats in thread order: equal to
    # float rounding, and bit-identical with one thread.
    job = [WINE, "--count", "4", "--seed", "3", *FAST]
    single, sharded = check_shards(tmp_path, capsys, "gauss", job)
    for i in range(4):
        np.testing.assert_allclose(pixels(single, i), pixels(sharded, i), rtol=2e-3, atol=1e-4)
    single, sharded = check_shards(tmp_path, capsys, "one", [*job, "--threads", "1"])
    for i in range(4):
        np.testing.assert_array_equal(pixels(single, i), pixels(sharded, i))


def test_rotation_and_orbit(tmp_path, capsys, prism):
    # Rotate: the prism turns by 36 degrees between frames (its most
    # different pose: a pentagon repeats every 72 degrees).
    rot = tmp_path / "rotate"
    code, stdout, _ = run(capsys, prism, "-o", str(rot), "--count", "10", "--frames", "0:2", "--mode", "spin",
                          "--seeds", "frame", *FAST)
    assert code == 0 and "lathe 'prism' spins" in stdout  # the first lathe of the file

    # The same poses through the library, with one seed: they differ by the
    # rotation only, and a full turn ends where it started.
    scene = load_scene(prism, {"spp": "2"}, (24, 24))
    turntable = tt.Turntable(scene, "rotate", scene_path=prism)
    still = turntable.render(0.0, seed=1)
    turned = turntable.render(36.0, seed=1)
    assert np.abs(turned - still).mean() > 0.1 * still.mean()
    np.testing.assert_allclose(pixels(rot, 1), turned, rtol=2e-3, atol=1e-3)  # (half floats)
    np.testing.assert_array_equal(turntable.render(360.0, seed=1), still)
    np.testing.assert_allclose(pixels(rot, 0), turntable.render(0.0, seed=0), rtol=2e-3, atol=1e-3)

    # --object picks another lathe; the prism then stays still.
    knob = tmp_path / "knob"
    code, stdout, _ = run(capsys, prism, "-o", str(knob), "--count", "10", "--frames", "1",
                          "--object", "knob", "--mode", "spin", "--seeds", "frame", *FAST)
    assert code == 0 and "lathe 'knob' spins" in stdout
    assert read_exr(knob / "frame_0001.exr")[1]["object"] == "knob"
    k1 = pixels(knob, 1)
    assert np.abs(k1 - still).mean() < 0.3 * np.abs(k1 - turned).mean()

    # Orbit: the camera moves, frame 0 is the scene as loaded.
    orbit = tmp_path / "orbit"
    code, stdout, _ = run(capsys, WINE, "-o", str(orbit), "--count", "4", "--frames", ":2", "--orbit", *FAST)
    assert code == 0 and "camera orbits lathe 'wine_glass'" in stdout
    o0, o1 = pixels(orbit, 0), pixels(orbit, 1)
    assert read_exr(orbit / "frame_0001.exr")[1]["mode"] == "orbit"
    assert np.abs(o0 - o1).mean() > 0.05 * o0.mean()
    wine = load_scene(WINE, {"mesh_segments": "16", "max_depth": "4"}, (24, 24))
    loaded = np.asarray(mi.render(wine, spp=2, seed=0).numpy())[..., :3].astype(np.float16)
    np.testing.assert_array_equal(o0, loaded.astype(np.float32))


def test_interrupt_then_resume(tmp_path, capsys, monkeypatch):
    out = tmp_path / "turn"
    render = tt.Turntable.render
    calls = []

    def interrupted(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            # Ctrl-C inside mi.render reaches the caller wrapped by Dr.Jit.
            raise RuntimeError("drjit.custom(...): error while performing ...") from KeyboardInterrupt()
        return render(self, *args, **kwargs)

    monkeypatch.setattr(tt.Turntable, "render", interrupted)
    code, _, stderr = run(capsys, WINE, "-o", str(out), "--count", "3", *FAST)
    assert code == 130 and "interrupted after 1 rendered frame(s)" in stderr and "Traceback" not in stderr
    assert frames_in(out) == ["frame_0000.exr", "frame_0000.png"]  # nothing half-written
    monkeypatch.setattr(tt.Turntable, "render", render)
    code, stdout, _ = run(capsys, WINE, "-o", str(out), "--count", "3", *FAST)
    assert code == 0 and "rendered 2 frame(s), skipped 1" in stdout and len(frames_in(out)) == 6


def test_ctrl_c_subprocess(tmp_path):
    """A real SIGINT: exit 130, no traceback, no half-written frame."""
    out = tmp_path / "turn"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lathe_shape.cli.turntable", "--variant", VARIANT, WINE, "-o", str(out),
         "--count", "1000", *FAST],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    deadline = time.monotonic() + 60
    while not (out / "frame_0001.exr").exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "run the same command again to resume" in stderr and "Traceback" not in stderr
    names = os.listdir(out)
    assert not [n for n in names if n.startswith(".")]
    done = {n[:-4] for n in names if n.endswith(".exr")}
    assert done == {n[:-4] for n in names if n.endswith(".png")} and len(done) >= 2
    for name in done:
        read_exr(out / f"{name}.exr")


def test_gif_and_mp4(tmp_path, capsys):
    pytest.importorskip("imageio")
    pytest.importorskip("PIL")
    out = tmp_path / "turn"
    args = [WINE, "-o", str(out), "--count", "3", "--orbit", "--gif", "--fps", "10", *FAST]
    try:
        import imageio_ffmpeg  # noqa: F401

        args.append("--mp4")
    except ImportError:
        pass
    code, stdout, stderr = run(capsys, *args)
    assert code == 0, stderr
    assert "turntable.gif (3 frames, 10 fps)" in stdout
    import imageio.v3 as iio

    gif = iio.imread(out / "turntable.gif")
    assert gif.shape[:3] == (3, 24, 24)
    if "--mp4" in args:
        assert (out / "turntable.mp4").stat().st_size > 0


def test_errors(tmp_path, capsys, prism, monkeypatch):
    def error(*args: str) -> str:
        code, _, stderr = run(capsys, *args)
        assert code == 2 and stderr.startswith("lathe-turntable: error: ") and "Traceback" not in stderr
        return stderr

    out = str(tmp_path / "out")
    assert f"scene file '{tmp_path / 'nope.xml'}' not found" in error(str(tmp_path / "nope.xml"), "-o", out)
    assert "no lathe with id 'cup' (lathes in the scene: 'prism', 'knob')" in error(prism, "-o", out,
                                                                                  "--object", "cup")
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert "cannot write to output folder" in error(prism, "-o", str(blocker / "sub"), *FAST)
    assert "exists and is not a folder" in error(prism, "-o", str(blocker), *FAST)
    assert "--frames expects integers" in error(prism, "-o", out, "--frames", "a:b")
    assert "selects no frame" in error(prism, "-o", out, "--count", "4", "--frames", "4:8")
    assert "--count must be at least 1, got 0" in error(prism, "-o", out, "--count", "0")
    assert "--threads must be at least 1" in error(prism, "-o", out, "--threads", "0")
    assert "-D expects key=value" in error(prism, "-o", out, "-D", "spp")
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    assert "--mp4 needs the optional video dependencies (missing: imageio_ffmpeg): pip install " \
        "lathe_shape[video]" in error(prism, "-o", out, "--mp4")
    assert not os.path.exists(out)  # nothing created for a failed job

    no_lathe = tmp_path / "no_lathe.xml"
    no_lathe.write_text(PRISM_XML.split('<shape type="lathe" id="prism">')[0] + "</scene>")
    assert "no lathe shape to rotate" in error(str(no_lathe), "-o", out, "--mode", "spin")
    no_sensor = tmp_path / "no_sensor.xml"
    no_sensor.write_text(PRISM_XML.split("<sensor")[0] + PRISM_XML.split("</sensor>")[1])
    assert "the scene has no sensor" in error(str(no_sensor), "-o", out)


def test_help(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--variant", VARIANT, "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    for option in ("--count", "--frames", "--object", "--orbit", "--gif", "--mp4", "--fps", "-D"):
        assert option in text


def test_mp4_writer_pads_and_renames(tmp_path, capsys, monkeypatch):
    """The MP4 path without ffmpeg: a stand-in imageio_ffmpeg records the
    frames; odd sizes are padded to even ones and the file appears only
    when complete."""
    out = tmp_path / "turn"
    odd = [*FAST[:2], "--resolution", "25x15", *FAST[4:]]
    assert run(capsys, WINE, "-o", str(out), "--count", "2", *odd)[0] == 0
    sent = []

    def write_frames(path, size, **options):  # imageio_ffmpeg's generator protocol
        assert os.path.basename(path).startswith(".") and not (out / "turntable.mp4").exists()
        sent.append(size)
        with open(path, "wb") as f:
            while True:
                image = yield  # the first send(None) only starts the generator
                sent.append(image.shape)
                f.write(b"frame")

    fake = type(sys)("imageio_ffmpeg")
    fake.write_frames = write_frames
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", fake)
    code, stdout, stderr = run(capsys, WINE, "-o", str(out), "--count", "2", "--mp4", *odd)
    assert code == 0, stderr
    assert "rendered 0 frame(s), skipped 2" in stdout and "turntable.mp4 (2 frames, 12 fps)" in stdout
    assert sent == [(26, 16), (16, 26, 3), (16, 26, 3)]
    assert (out / "turntable.mp4").read_bytes() == b"frame" * 2
    assert not [p for p in os.listdir(out) if p.startswith(".")]
