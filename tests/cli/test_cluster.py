"""Issue 29: turntables and sweeps on a Dask cluster (``--workers``,
``--scheduler``, ``lathe-sweep``, :mod:`lathe_shape.distributed`).

Every cluster here is a ``LocalCluster`` of 2 worker processes (the way
``--workers 2`` runs). A distributed turn writes the pixels of a plain run
bit for bit (one Dr.Jit thread each: the scenes' gaussian filters splat
across pixels in thread order); a worker killed mid-turn loses nothing; a
frame failing twice stops the job with its error; Ctrl-C ends the command
and its workers; without ``distributed`` the options name the extra."""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import SCENES, VARIANT

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

from lathe_shape.cli import sweep, turntable  # noqa: E402
from lathe_shape.distributed import FAULTS_ENV, ClusterError, render_many  # noqa: E402
from lathe_shape.tools.images import read_exr  # noqa: E402

pytestmark = pytest.mark.slow

WINE = str(SCENES / "wine_glass.xml")
#: 8 frames at 64x64, one Dr.Jit thread (bit-reproducible with the gaussian filter).
TURN = ["--variant", VARIANT, WINE, "--count", "8", "--spp", "4", "--resolution", "64", "--threads", "1",
        "-D", "mesh_segments=32", "-D", "max_depth=6"]


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The frames of the single-process command."""
    out = tmp_path_factory.mktemp("plain")
    assert turntable.main([*TURN, "-o", str(out)]) == 0
    return out


def assert_same_frames(out, reference, count: int = 8) -> None:
    """The frames in ``out`` are those of ``reference``, bit for bit (the
    EXR pixels and the PNG files), and ``out`` holds nothing else."""
    names = sorted(os.listdir(out))
    assert names == sorted(f"frame_{k:04d}.{ext}" for k in range(count) for ext in ("exr", "png")), names
    for k in range(count):
        mine, header = read_exr(out / f"frame_{k:04d}.exr")
        theirs, _ = read_exr(reference / f"frame_{k:04d}.exr")
        assert np.array_equal(mine, theirs), f"frame {k} differs"
        assert (out / f"frame_{k:04d}.png").read_bytes() == (reference / f"frame_{k:04d}.png").read_bytes()
        assert header["frame"] == k and header["variant"] == VARIANT


def start(out, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "lathe_shape.cli.turntable", *TURN, "-o", str(out), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})


def wait_for_frames(proc: subprocess.Popen, count: int) -> None:
    """Read the progress lines (stderr) until ``count`` frames are done."""
    while (line := proc.stderr.readline()) and f"] {count}/" not in line:
        pass
    assert line, "the turntable ended early"


def workers_of(proc: subprocess.Popen) -> list:
    """The worker processes of the command's local cluster."""
    return [p for p in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(p.cmdline())]


def test_same_pixels_as_a_plain_run_and_resume(plain, tmp_path, capsys):
    """A 2-worker turn writes the plain run's frames bit for bit, whether the
    workers write them or send them back (--collect); a rerun resumes."""
    for mode in ([], ["--collect"]):
        out = tmp_path / f"turn{len(mode)}"
        assert turntable.main([*TURN, "-o", str(out), "--workers", "2", *mode]) == 0, capsys.readouterr().err
        assert "on a local Dask cluster of 2 worker process(es), 1 Dr.Jit thread(s) each" in \
            capsys.readouterr().out
        assert_same_frames(out, plain)
    os.remove(out / "frame_0005.exr")
    assert turntable.main([*TURN, "-o", str(out), "--workers", "2"]) == 0
    assert "7 finished frame(s) skipped" in capsys.readouterr().out
    assert_same_frames(out, plain)
    assert turntable.main([*TURN, "-o", str(out), "--workers", "2"]) == 0  # (no cluster started)
    assert "nothing to render" in capsys.readouterr().out


def test_killed_worker_loses_nothing(plain, tmp_path):
    """SIGKILL to a worker mid-turn: its frame is rendered by another
    worker and the turn completes, with the plain run's pixels."""
    out = tmp_path / "turn"
    proc = start(out, "--workers", "2", env={FAULTS_ENV: "delay=0.5"})
    try:
        wait_for_frames(proc, 1)
        workers = workers_of(proc)
        assert len(workers) == 2
        time.sleep(0.1)  # (both workers are busy: 7 frames wait)
        workers[0].kill()
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, stderr
    assert "rendered 7 frame(s)" in stderr or "8/8 frames" in stderr, stderr
    assert_same_frames(out, plain)


def test_frame_failing_twice_stops_the_job(tmp_path, monkeypatch, capsys):
    """A render that raises is tried once more, then stops the job with its
    error (status 2), without retrying it further or waiting for the rest."""
    log = tmp_path / "failures.txt"
    monkeypatch.setenv(FAULTS_ENV, f"fail=3,log={log}")
    start_time = time.monotonic()
    code = turntable.main([*TURN, "-o", str(tmp_path / "turn"), "--workers", "2"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.strip().splitlines()[-1] == \
        "lathe-turntable: error: frame 3 failed 2 times: injected failure of render 3"
    assert len(log.read_text().splitlines()) == 2
    assert time.monotonic() - start_time < 60
    assert not [n for n in os.listdir(tmp_path / "turn") if n.startswith(".")]


def test_ctrl_c_ends_the_command_and_its_workers(tmp_path):
    """SIGINT to the command: status 130 within seconds, its workers ended,
    the finished frames whole and no staging or lock file left."""
    out = tmp_path / "turn"
    proc = start(out, "--workers", "2", env={FAULTS_ENV: "delay=0.5"})
    try:
        wait_for_frames(proc, 1)
        family = psutil.Process(proc.pid).children(recursive=True)
        assert len(workers_of(proc)) == 2
        sent = time.monotonic()
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=30)
        latency = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert latency < 5, latency
    assert "Traceback" not in stderr and "Warning" not in stderr, stderr
    assert stderr.strip().splitlines()[-1].startswith("lathe-turntable: interrupted after"), stderr
    gone, alive = psutil.wait_procs(family, timeout=5)
    assert not alive, alive
    names = os.listdir(out)
    assert not [n for n in names if n.startswith(".")], names
    exrs = {n[:-4] for n in names if n.endswith(".exr")}
    assert exrs and exrs == {n[:-4] for n in names if n.endswith(".png")}, names


def test_missing_extra_and_option_errors(tmp_path, monkeypatch, capsys):
    """Without ``distributed`` the cluster options name the extra (before
    any scene is loaded); wrong combinations of the options are refused."""
    monkeypatch.setitem(sys.modules, "distributed", None)  # (import distributed fails)
    hint = "needs Dask's 'distributed' package, which is not installed: pip install 'lathe_shape[cluster]'"
    for prog, main, option in (("lathe-turntable", turntable.main, ["--workers", "2"]),
                               ("lathe-sweep", sweep.main, ["--scheduler", "tcp://127.0.0.1:8786"])):
        assert main(["--variant", VARIANT, WINE, "-o", str(tmp_path / "out"), *option]) == 2
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"{prog}: error: {option[0]} {hint}"
    assert not (tmp_path / "out").exists()
    monkeypatch.delitem(sys.modules, "distributed")
    for options, message in (
        (["--workers", "2", "--scheduler", "tcp://h:8786"], "--scheduler and --workers exclude each other"),
        (["--collect"], "--collect needs --scheduler or --workers"),
        (["--workers", "0"], "--workers must be at least 1, got 0"),
    ):
        assert turntable.main(["--variant", VARIANT, WINE, "-o", str(tmp_path / "out"), *options]) == 2
        last = capsys.readouterr().err.strip().splitlines()[-1]
        assert last.startswith(f"lathe-turntable: error: {message}"), last


def test_sweep_writes_exrs_and_index(tmp_path, capsys):
    """``lathe-sweep -D a=1,2 -D b=3,4 --workers 2``: one EXR per
    combination (the last key varying fastest) and the CSV index; each
    render is the one ``render_many`` makes in this process."""
    out = tmp_path / "sweep"
    options = ["--variant", VARIANT, WINE, "-o", str(out), "--spp", "2", "--resolution", "16",
               "--threads", "1"]
    code = sweep.main([*options, "-D", "mesh_segments=16,32", "-D", "max_depth=2,4", "--workers", "2"])
    assert code == 0, capsys.readouterr().err
    assert sorted(os.listdir(out)) == ["sweep.csv", *(f"sweep_{k:04d}.exr" for k in range(4))]
    with open(out / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["file"], r["mesh_segments"], r["max_depth"]) for r in rows] == [
        ("sweep_0000.exr", "16", "2"), ("sweep_0001.exr", "16", "4"),
        ("sweep_0002.exr", "32", "2"), ("sweep_0003.exr", "32", "4")]
    assert all(float(r["render_seconds"]) > 0 and r["worker"] for r in rows)
    pixels, header = read_exr(out / "sweep_0003.exr")
    assert header["D.mesh_segments"] == "32" and header["D.max_depth"] == "4"
    [local] = render_many(WINE, [{"mesh_segments": 32, "max_depth": 4}], None, spp=2, resolution="16",
                          variant=VARIANT, threads=1)
    assert local.variation == {"mesh_segments": "32", "max_depth": "4"}
    assert np.array_equal(pixels, local.image[..., :3])
    for kwargs, message in (({"variations": {"mesh_segments": 16}}, "'variations' must be a list"),
                            ({"spp": 2.5}, "'spp' must be a whole number >= 1 or None, got 2.5"),
                            ({"spp": -1}, "'spp' must be a whole number >= 1 or None, got -1"),
                            ({"resolution": 16.0}, "'resolution' must be 'WxH', 'N' or None, got 16.0")):
        arguments = {"variations": [{"mesh_segments": 16}], "spp": 2, "resolution": "16", **kwargs}
        with pytest.raises(ValueError, match=f"^render_many: {re.escape(message)}"):
            render_many(WINE, arguments.pop("variations"), None, variant=VARIANT, **arguments)
    missing = tmp_path / "no_such_profile.csv"
    with pytest.raises(ClusterError, match=f"^profile file '{missing}' not found$"):
        render_many(WINE, [{"mesh_segments": 32}, str(missing)], None, spp=2, resolution="16",
                    variant=VARIANT)

    # In this process (no cluster), a profile file per render.
    out = tmp_path / "profiles"
    code = sweep.main([*options[:4], str(out), *options[5:], "--profile", str(SCENES / "sundae_cup.csv"),
                       "--profile", str(SCENES / "wine_glass.csv")])
    assert code == 0, capsys.readouterr().err
    with open(out / "sweep.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [os.path.basename(r["profile"]) for r in rows] == ["sundae_cup.csv", "wine_glass.csv"]
    first, _ = read_exr(out / "sweep_0000.exr")
    second, _ = read_exr(out / "sweep_0001.exr")
    assert not np.array_equal(first, second)


def test_sweep_values_with_commas(tmp_path, capsys):
    """A ``-D`` value that holds commas (an RGB triple) goes in
    parentheses; a value listed twice (what ``0.5, 0.5, 0.5`` without them
    gives) is refused with the hint, before anything renders."""
    assert sweep.parse_grid(["s=(0.5, 0.5, 0.5),(1, 1, 1)", "n=1,2"]) == {
        "s": ["0.5, 0.5, 0.5", "1, 1, 1"], "n": ["1", "2"]}
    filled = str(SCENES / "wine_glass_filled.xml")
    out = tmp_path / "sweep"
    code = sweep.main(["--variant", VARIANT, filled, "-o", str(out), "--spp", "1", "--resolution", "8",
                       "-D", "wine_sigma_t=0.5, 0.5, 0.5"])
    assert code == 2 and not out.exists()
    assert capsys.readouterr().err == (
        "lathe-sweep: error: -D wine_sigma_t lists the value '0.5' 3 times; a value that holds commas "
        "(a colour) goes in parentheses: -D 'wine_sigma_t=(0.5, 0.5, 0.5)'\n")
    for item, message in (("a=(1,2", "-D a=(1,2: unbalanced parentheses"),
                          ("a=1,,2", "-D a=1,,2: a value is empty")):
        assert sweep.main(["--variant", VARIANT, filled, "-o", str(out), "-D", item]) == 2
        assert capsys.readouterr().err == f"lathe-sweep: error: {message}\n"
    code = sweep.main(["--variant", VARIANT, filled, "-o", str(out), "--spp", "4", "--resolution", "32",
                       "-D", "wine_sigma_t=(0.05, 0.05, 0.05),(0.9, 0.1, 0.1)"])
    assert code == 0, capsys.readouterr().err
    with open(out / "sweep.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert [row[:2] for row in rows[1:]] == [["sweep_0000.exr", "0.05, 0.05, 0.05"],
                                             ["sweep_0001.exr", "0.9, 0.1, 0.1"]]
    # Each triple reached the medium as a colour: a grey wine leaves the
    # (grey) scene grey, one that absorbs red most turns it cyan
    grey = read_exr(out / "sweep_0000.exr")[0][..., :3].mean(axis=(0, 1))
    red_absorbing = read_exr(out / "sweep_0001.exr")[0][..., :3].mean(axis=(0, 1))
    assert np.ptp(grey) < 1e-6 * grey.mean(), grey
    assert red_absorbing[0] < 0.99 * red_absorbing[1], red_absorbing


def test_sweep_checks_every_value_first_and_keeps_its_folder_consistent(tmp_path, capsys):
    """A value the scene cannot take was found only when its turn came
    (after the renders before it were written, and retried); a shorter
    sweep left the longer one's renders, unlisted; a failed one left the
    earlier index, describing files it had overwritten."""
    out = tmp_path / "sweep"
    options = ["--variant", VARIANT, WINE, "-o", str(out), "--spp", "1", "--resolution", "8"]
    assert sweep.main([*options, "-D", "max_depth=2,3,4"]) == 0
    capsys.readouterr()
    assert sweep.main([*options, "-D", "max_depth=2,abc"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lathe-sweep: error: -D max_depth=abc: ")
    assert 'could not parse integer value "abc"' in err
    assert sorted(os.listdir(out)) == ["sweep.csv", *(f"sweep_{k:04d}.exr" for k in range(3))]  # untouched
    assert sweep.main([*options, "-D", "max_depth=5"]) == 0
    assert "removed 2 render(s) of an earlier sweep (sweep_0001.exr ...)" in capsys.readouterr().out
    assert sorted(os.listdir(out)) == ["sweep.csv", "sweep_0000.exr"]
    with open(out / "sweep.csv", newline="") as f:
        assert [row["max_depth"] for row in csv.DictReader(f)] == ["5"]
