"""Review of frame output at render speed: Ctrl-C while frames are still
being written, PNG edge cases, memory held by the PNG encoder."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest
from conftest import SCENES, VARIANT

from lathe_shape.tools.writer import FrameWriter


def _ctrl_c_later(delay: float, then: threading.Event | None = None) -> threading.Thread:
    """A thread that sends SIGINT to the main thread after ``delay`` seconds
    (as a Ctrl-C in the terminal does), then sets ``then``."""
    main = threading.main_thread().ident

    def send() -> None:
        time.sleep(delay)
        signal.pthread_kill(main, signal.SIGINT)
        time.sleep(0.2)
        if then is not None:
            then.set()

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    return thread


@pytest.fixture
def python_ctrl_c():
    """SIGINT raises KeyboardInterrupt in the main thread during the test,
    its handler installed with SA_RESTART as a Mitsuba render leaves it (a
    blocking lock wait then does not wake on Ctrl-C)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.siginterrupt(signal.SIGINT, False)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_while_waiting_for_a_free_writer(python_ctrl_c):
    # The renderer waits for room in the queue (the disk is the slower one):
    # Ctrl-C interrupts the wait at once, and the queued job is still run.
    release, ran = threading.Event(), []
    writer = FrameWriter(workers=1, depth=1)
    writer.submit(lambda: (release.wait(10), ran.append(0)))
    writer.submit(lambda: ran.append(1))
    _ctrl_c_later(0.2)
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        writer.submit(lambda: ran.append(2))
    assert time.monotonic() - start < 2.0
    release.set()
    writer.close()
    assert ran in ([0, 1], [0, 1, 2])


def test_ctrl_c_while_closing_lets_the_running_job_finish(python_ctrl_c):
    # A Ctrl-C while close() waits: the job being written completes (no
    # half-written file), jobs not started are dropped, then the interrupt
    # goes on.
    started, release, ran = threading.Event(), threading.Event(), []

    def slow() -> None:
        started.set()
        release.wait(10)
        ran.append("slow")

    writer = FrameWriter(workers=1, depth=2)
    writer.submit(slow)
    writer.submit(lambda: ran.append("queued"))
    assert started.wait(10)
    _ctrl_c_later(0.2, then=release)
    with pytest.raises(KeyboardInterrupt):
        writer.close()
    assert ran == ["slow"]
    assert not any(thread.is_alive() for thread in writer._threads)


def test_second_ctrl_c_stops_waiting_for_a_hung_write(python_ctrl_c):
    release = threading.Event()
    writer = FrameWriter(workers=1)
    writer.submit(lambda: release.wait(10))
    _ctrl_c_later(0.2)
    _ctrl_c_later(0.6)
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        writer.close()
    assert time.monotonic() - start < 3.0
    release.set()


def test_turntable_ctrl_c_while_last_frames_are_written(tmp_path, capsys, monkeypatch, python_ctrl_c):
    # Every frame rendered, the command waits for the writers: a Ctrl-C then
    # must not leave a hidden temporary file or a PNG without its EXR.
    from lathe_shape.cli.turntable import main
    from lathe_shape.tools import images, writer

    # One writer, whatever the machine (with four, frame 2 would be written
    # alongside frames 0 and 1 before the Ctrl-C).
    monkeypatch.setattr(writer, "default_workers", lambda frame_bytes=0: 1)
    write_png, calls = images.write_png, []

    def slow_png(*args, **kwargs) -> None:
        write_png(*args, **kwargs)
        calls.append(1)
        if len(calls) == 2:  # (frame 2 rendered and queued: the command waits in close())
            _ctrl_c_later(0.3)
        time.sleep(0.6)

    monkeypatch.setattr(images, "write_png", slow_png)
    out = tmp_path / "turn"
    code = main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(out), "--count", "3",
                 "--spp", "1", "--resolution", "16x16", "-D", "mesh_segments=8", "-D", "max_depth=2"])
    assert code == 130, capsys.readouterr().err
    names = os.listdir(out)
    assert not [n for n in names if n.startswith(".")], names
    exrs = {n[:-4] for n in names if n.endswith(".exr")}
    assert exrs == {n[:-4] for n in names if n.endswith(".png")} == {"frame_0000", "frame_0001"}
    monkeypatch.setattr(images, "write_png", write_png)
    code = main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(out), "--count", "3",
                 "--spp", "1", "--resolution", "16x16", "-D", "mesh_segments=8", "-D", "max_depth=2"])
    assert code == 0 and "rendered 1 frame(s), skipped 2" in capsys.readouterr().out
    assert len(os.listdir(out)) == 6


# -- PNG edge cases -------------------------------------------------------------


def test_png_refuses_images_it_cannot_store(tmp_path):
    from lathe_shape.tools.images import encode_png, write_png

    # PNG has no empty image (libpng refuses an IHDR with a zero side).
    for shape in [(0, 4, 3), (4, 0, 3)]:
        with pytest.raises(ValueError, match="H and W at least 1"):
            encode_png(np.zeros(shape, dtype=np.uint8))
        with pytest.raises(ValueError, match="H and W at least 1"):
            write_png(tmp_path / "empty.png", np.zeros(shape, dtype=np.float32))
    with pytest.raises(ValueError, match=r"need an \(H, W\) or \(H, W, C\) image"):
        write_png(tmp_path / "4d.png", np.zeros((2, 2, 3, 1)))
    assert not list(tmp_path.iterdir())  # nothing written for a refused image


def test_png_carries_gamma_and_chromaticities_for_readers_without_srgb(tmp_path):
    # (as Mitsuba's PNG writer did before: the PNG specification asks for
    # gAMA and cHRM next to sRGB)
    from PIL import Image

    from lathe_shape.tools.images import write_png

    write_png(tmp_path / "a.png", np.full((2, 3, 3), 0.5, dtype=np.float32), compression=1)
    with Image.open(tmp_path / "a.png") as image:
        assert image.info["gamma"] == pytest.approx(1 / 2.2, abs=1e-5)
        assert image.info["chromaticity"] == pytest.approx((0.3127, 0.329, 0.64, 0.33, 0.3, 0.6, 0.15, 0.06))
        assert "srgb" in image.info


def test_write_png_memory_stays_near_the_8_bit_image(tmp_path):
    # The sRGB conversion runs in float64: over a whole frame its
    # temporaries took over 100 bytes per pixel, per writer thread (a 4K
    # frame: 1 GB each). Converted in bands, the 8-bit image and its
    # encodings dominate.
    import tracemalloc

    from lathe_shape.tools.images import to_srgb8, write_png

    height, width = 1024, 4096
    linear = np.linspace(0.0, 1.0, height * width * 3, dtype=np.float32).reshape(height, width, 3)
    tracemalloc.start()
    try:
        write_png(tmp_path / "big.png", linear, compression=1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 24 * height * width, f"{peak / (height * width):.1f} bytes per pixel"
    from PIL import Image

    with Image.open(tmp_path / "big.png") as image:
        assert np.array_equal(np.asarray(image)[::97], to_srgb8(linear[::97]))


def test_default_workers_count_the_cores_this_process_may_use(monkeypatch):
    # A batch job given 2 cores of a 64-core node: one writer, not four
    # threads competing with the renderer for those 2 cores.
    from lathe_shape.tools import writer

    monkeypatch.setattr(os, "cpu_count", lambda: 64)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert writer.default_workers() == 1
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)), raising=False)
    assert writer.default_workers() == 4


def test_ctrl_c_wakes_a_blocking_wait_after_a_render():
    # Mitsuba's render puts Python's SIGINT handler back with SA_RESTART: a
    # blocking wait of the main thread then slept through Ctrl-C (here for
    # 3 s, in a turntable until the next frame was written).
    import mitsuba as mi

    from lathe_shape.cli.common import interruptible

    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "direct"}, "sensor": {
            "type": "perspective", "film": {"type": "hdrfilm", "width": 2, "height": 2}}})
        interruptible(lambda: mi.render(scene, spp=1).numpy())
        held = threading.Lock()
        held.acquire()
        threading.Timer(3.0, held.release).start()
        _ctrl_c_later(0.2)
        start = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            held.acquire()
        assert time.monotonic() - start < 2.0
    finally:
        signal.signal(signal.SIGINT, previous)


def test_repeated_in_process_turntables_leave_no_thread(tmp_path, capsys, monkeypatch):
    # Every job's render thread and writer threads end with the job.
    from lathe_shape.cli.turntable import main
    from lathe_shape.tools import writer

    monkeypatch.setattr(writer, "default_workers", lambda frame_bytes=0: 3)
    before = threading.active_count()
    for k in range(12):
        assert main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(tmp_path / f"t{k % 2}"),
                     "--count", "3", "--force", "--spp", "1", "--resolution", "8x8", "-D", "mesh_segments=8",
                     "-D", "max_depth=2"]) == 0
    capsys.readouterr()
    deadline = time.monotonic() + 10
    while threading.active_count() > before and time.monotonic() < deadline:
        time.sleep(0.05)
    # (at most as many as before: threads of an earlier test may end meanwhile)
    assert threading.active_count() <= before, [t.name for t in threading.enumerate()]


@pytest.mark.parametrize("error", [OSError(28, "No space left on device", "/x/.frame_0000.1.tmp.png"),
                                   RuntimeError("Failed to write pixel data to image file")])
def test_turntable_write_error_names_the_frame_and_folder(tmp_path, capsys, monkeypatch, error):
    # One line naming the frame and the folder (not the hidden temporary
    # file); OpenEXR's RuntimeError is a write error too.
    from lathe_shape.cli import turntable
    from lathe_shape.tools import frames

    def fail(*args, **kwargs):
        raise error

    monkeypatch.setattr(frames, "write_images", fail)
    out = tmp_path / "turn"
    code = turntable.main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(out),
                           "--count", "2", "--spp", "1", "--resolution", "8x8", "-D", "mesh_segments=8",
                           "-D", "max_depth=2"])
    err = capsys.readouterr().err
    assert code == 2
    reason = "No space left on device" if isinstance(error, OSError) else str(error)
    assert err.splitlines()[-1] == f"lathe-turntable: error: cannot write frame 0 to {out}: {reason}"
