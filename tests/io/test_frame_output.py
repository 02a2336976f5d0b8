"""Frame output at render speed: the PNG encoder, parallel frame writers and
the long-lived render worker of ``lathe-turntable``."""

from __future__ import annotations

import threading
import time
import zlib

import mitsuba as mi
import numpy as np
import pytest
from PIL import Image

from lathe_shape.cli.common import interruptible, one_render_thread
from lathe_shape.tools.images import encode_png, to_srgb8, write_png
from lathe_shape.tools.writer import HELD_BYTES, FrameWriter, default_workers


@pytest.mark.parametrize("channels", [1, 2, 3, 4])
@pytest.mark.parametrize("compression", [1, 9])
def test_png_round_trip(tmp_path, channels, compression):
    pixels = np.random.default_rng(channels).integers(0, 256, (7, 5, channels), dtype=np.uint8)
    path = tmp_path / "a.png"
    path.write_bytes(encode_png(pixels, compression))
    with Image.open(path) as image:
        assert image.mode == {1: "L", 2: "LA", 3: "RGB", 4: "RGBA"}[channels]
        read = np.asarray(image).reshape(7, 5, channels)
    assert np.array_equal(read, pixels)
    assert np.array_equal(np.asarray(mi.Bitmap(str(path))).reshape(7, 5, channels), pixels)


def test_png_is_marked_srgb_and_compressed_as_asked():
    smooth = np.tile(np.arange(256, dtype=np.uint8)[None, :, None], (64, 1, 3))
    fast, small = encode_png(smooth, 1), encode_png(smooth, 9)
    assert b"sRGB\x00" in fast
    assert len(small) < len(fast)
    start = fast.index(b"IDAT") + 4
    rows = np.frombuffer(zlib.decompressobj().decompress(fast[start:]), dtype=np.uint8).reshape(64, -1)
    assert np.all(rows[:, 0] == 0) and np.array_equal(rows[:, 1:].reshape(64, 256, 3), smooth)


def test_write_png_converts_to_srgb(tmp_path):
    linear = np.linspace(0.0, 1.2, 2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    write_png(tmp_path / "b.png", linear, compression=1)
    with Image.open(tmp_path / "b.png") as image:
        assert np.array_equal(np.asarray(image), to_srgb8(linear))


def test_encode_png_refuses_other_pixels():
    with pytest.raises(ValueError, match="uint8"):
        encode_png(np.zeros((2, 2, 3), dtype=np.float32))
    with pytest.raises(ValueError, match="1..4"):
        encode_png(np.zeros((2, 2, 5), dtype=np.uint8))


def test_frame_writers_run_in_parallel():
    # Three jobs that each wait for the other two finish only when three
    # workers run them at once.
    meeting = threading.Barrier(3, timeout=10)
    done = []
    with FrameWriter(workers=3) as writer:
        for k in range(3):
            writer.submit(lambda k=k: (meeting.wait(), done.append(k)))
    assert sorted(done) == [0, 1, 2]


def test_parallel_frame_writer_raises_a_failure_and_runs_nothing_after_it():
    ran = []
    failed = threading.Event()

    def fail() -> None:
        failed.set()
        raise ZeroDivisionError

    writer = FrameWriter(workers=2)
    writer.submit(fail)
    assert failed.wait(10)
    time.sleep(0.1)  # (the worker records the error as the job returns)
    with pytest.raises(ZeroDivisionError):
        writer.submit(lambda: ran.append(1))
    writer.close()
    assert ran == []
    with pytest.raises(ValueError, match="at least one worker"):
        FrameWriter(workers=0)


def test_default_workers_bound_the_memory_held():
    assert 1 <= default_workers() <= 4
    assert default_workers(HELD_BYTES) == 1  # huge frames: one at a time
    assert default_workers(HELD_BYTES // 4) <= 2


def test_one_render_thread_runs_every_call_on_one_thread():
    with one_render_thread():
        first = interruptible(threading.current_thread)
        second = interruptible(threading.current_thread)
    assert first is second and first is not threading.current_thread()
    first.join(10)  # the thread ends with the block
    assert not first.is_alive()
    assert interruptible(threading.current_thread) is not first  # a thread per call again


def test_threads_option_caps_the_frame_writers(tmp_path, capsys, monkeypatch):
    from conftest import SCENES, VARIANT

    from lathe_shape.cli.turntable import main
    from lathe_shape.tools import writer

    made = []

    class Recording(writer.FrameWriter):
        def __init__(self, depth=None, workers=1):
            made.append(workers)
            super().__init__(depth, workers)

    monkeypatch.setattr(writer, "FrameWriter", Recording)
    monkeypatch.setattr(writer, "default_workers", lambda frame_bytes=0: 4)
    job = [str(SCENES / "wine_glass.xml"), "--variant", VARIANT, "--count", "2", "--spp", "1",
           "--resolution", "8x8", "-D", "mesh_segments=8", "-D", "max_depth=2", "--force"]
    assert main([*job, "-o", str(tmp_path / "a")]) == 0
    assert main([*job, "-o", str(tmp_path / "b"), "--threads", "1"]) == 0
    capsys.readouterr()
    assert made == [4, 1]
