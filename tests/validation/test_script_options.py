"""The scripts' command-line convention: inverse_design.py writes to
-o/--output and takes WxH; bench_turntable.py finds its scene from any
folder and refuses a bad one in one line; the leak tests' options."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys

import pytest
from conftest import ROOT, VARIANT

from lathe_shape.cli.common import DEFAULT_VARIANT
from lathe_shape.validation import leaks
from lathe_shape.validation.turntable_bench import bench_parser


def load_script(name: str):
    """A script of scripts/ as a module (its ``main`` not run)."""
    spec = importlib.util.spec_from_file_location(name.removesuffix(".py"), ROOT / "scripts" / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_inverse_design_hollow_passes_its_options_and_lists_the_descents(tmp_path, capsys, monkeypatch):
    # The script's hollow path with recover_hollow replaced by a stand-in
    # that records its arguments and reports one iteration per descent
    import numpy as np

    import lathe_shape.tools.inverse_glass as inverse_glass

    calls = []

    def fake_recover(target, n_outer, *args, starts, axis_slope, refine, report, **kwargs):
        calls.append((starts, axis_slope, kwargs["uphill"], refine))
        ends = [np.asarray(target) + 0.01 * k for k in range(len(starts))]
        descents = []
        for k, bottom in enumerate(starts):
            report(0, 1.0 + k, (0.01 * k, 0.02 * k))
            loss = 0.5 - 0.1 * k if k < 2 else 0.9
            descents.append(inverse_glass.Descent(bottom, loss, (0.01 * k, 0.02 * k), ends[k]))
        if refine is not None:
            report(0, 0.5, (0.005, 0.005))
        kept = 1 if len(starts) > 1 else 0
        image = np.zeros((8, 8, 3), dtype=np.float32)
        return inverse_glass.HollowResult(ends[kept], n_outer, losses=[1.0], errors=[descents[kept].errors],
                                          valid=[True], descents=descents, before=[image], after=[image],
                                          targets=[image], kept=kept)

    monkeypatch.setattr(inverse_glass, "recover_hollow", fake_recover)
    inverse = load_script("inverse_design.py")
    code = inverse.main(["--kind", "hollow", "--starts", "0.3", "0.6", "0.7", "--axis-slope", "-1",
                         "--uphill", "-1", "-o", str(tmp_path / "a"), "--variant", VARIANT])
    out = capsys.readouterr().out
    assert code == 0 and calls[-1] == ((0.3, 0.6, 0.7), None, None, inverse_glass.REFINE)
    headers = [line for line in out.splitlines() if line.startswith(("descent from a tumbler", "refinement"))]
    assert headers == [
        *(f"descent from a tumbler with its inside bottom at {f} of the height"
          for f in ("0.3", "0.6", "0.7")),
        "refinement of the kept descent at 64x64 pixels, 64 spp"]
    listed = [line for line in out.splitlines() if line.startswith("descent from inside bottom")]
    assert len(listed) == 3 and [line.endswith("(kept)") for line in listed] == [False, True, False]
    assert listed[1] == ("descent from inside bottom 0.6: validation loss 0.400000, outer wall 1.000%, "
                         "inner wall 2.000% of height  (kept)")
    code = inverse.main(["--kind", "hollow", "--starts", "0.45", "--refine-steps", "0", "-o",
                         str(tmp_path / "b"), "--variant", VARIANT])
    out = capsys.readouterr().out
    assert code == 0 and calls[-1] == ((0.45,), inverse_glass.AXIS_SLOPE, 0.1, None)
    assert "descent from inside bottom" not in out  # one descent: nothing chosen
    assert "refinement" not in out
    code = inverse.main(["--kind", "hollow", "--axis-slope", "0.5", "-o", str(tmp_path / "c"),
                         "--variant", VARIANT])
    capsys.readouterr()
    assert code == 0 and calls[-1] == (inverse_glass.START_BOTTOMS, 0.5, 0.1, (64, 64, 100))
    code = inverse.main(["--kind", "hollow", "--refine-steps", "7", "-o", str(tmp_path / "d"),
                         "--variant", VARIANT])
    capsys.readouterr()
    assert code == 0
    assert calls[-1] == (inverse_glass.START_BOTTOMS, inverse_glass.AXIS_SLOPE, 0.1, (64, 64, 7))


@pytest.mark.slow
def test_inverse_design_output_and_resolution(tmp_path, capsys):
    inverse = load_script("inverse_design.py")
    assert inverse.square_resolution("24x24") == 24 and inverse.square_resolution("24") == 24
    code = inverse.main(["--resolution", "16x12", "-o", str(tmp_path / "no"), "--variant", VARIANT])
    assert code == 2 and capsys.readouterr().err == (
        "inverse_design.py: error: --resolution must be square (the views are), got '16x12'\n")
    code = inverse.main(["--resolution", "4", "-o", str(tmp_path / "no"), "--variant", VARIANT])
    assert code == 2
    assert capsys.readouterr().err == "inverse_design.py: error: --resolution must be at least 8, got 4\n"
    for option, value, message in (("--silhouette-weight", "-1", "must be >= 0, got -1"),
                                   ("--uphill", "nan", "must be finite, got nan"),
                                   ("--axis-slope", "inf", "must be finite, got inf"),
                                   ("--refine-steps", "-2", "must be at least 0, got -2")):
        code = inverse.main(["--kind", "hollow", option, value, "-o", str(tmp_path / "no"),
                             "--variant", VARIANT])
        assert code == 2
        assert capsys.readouterr().err == f"inverse_design.py: error: {option} {message}\n"
    for bad in ("1.5", "0", "nan"):
        code = inverse.main(["--kind", "hollow", "--starts", "0.4", bad, "-o", str(tmp_path / "no"),
                             "--variant", VARIANT])
        assert code == 2
        assert capsys.readouterr().err == (
            f"inverse_design.py: error: --starts must be fractions of the height between 0 and 1 "
            f"(exclusive), got {float(bad):g}\n")
    assert not (tmp_path / "no").exists()
    out = tmp_path / "out"
    code = inverse.main(["--iterations", "1", "--resolution", "8", "--spp", "1", "-o", str(out),
                         "--variant", VARIANT])
    assert code == 0, capsys.readouterr().err
    written = sorted(os.listdir(out))
    assert written == sorted(["convergence.png", *(f"view_{k}_{name}.png" for k in range(2)
                                                   for name in ("target", "before", "after"))])


def test_bench_turntable_scene_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = bench_parser().parse_args([])
    assert os.path.samefile(args.scene, ROOT / "scenes" / "wine_glass.xml") and args.resolution == 128
    assert bench_parser().parse_args(["--resolution", "64x64"]).resolution == 64


@pytest.mark.parametrize("content, message", [
    (None, "scene file 'nope.xml' not found"),
    ("<scene version='3.0.0'><shape type='lathe'>",
     "nope.xml: not a valid XML file (no element found: line 1"),
    ("<scene version='3.0.0'><shape type='sphere'/></scene>",
     "nope.xml: the scene has no <shape type=\"lathe\"> to turn"),
])
def test_bench_turntable_bad_scene(tmp_path, monkeypatch, capsys, content, message):
    monkeypatch.chdir(tmp_path)
    if content is not None:
        (tmp_path / "nope.xml").write_text(content)
    with pytest.raises(SystemExit) as exit_info:
        bench_parser().parse_args(["--scene", "nope.xml"])
    last = capsys.readouterr().err.splitlines()[-1]
    assert exit_info.value.code == 2
    assert last.startswith(f"bench_turntable.py: error: argument --scene: {message}")


def test_leak_test_options(capsys):
    with pytest.raises(SystemExit):
        leaks.leak_test_arguments("polyline", ["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--rays RAYS rays in all (default: 1e6)", f"(default: {DEFAULT_VARIANT})",
                   "(default: 250000)", "(default: 512)", "--random-profiles"):
        assert option in text
    with pytest.raises(SystemExit) as exit_info:
        leaks.leak_test_arguments("bspline", ["--random-profiles"], random_profiles=False)
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --random-profiles" in capsys.readouterr().err


def test_leak_test_bspline_help():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "leak_test_bspline.py"), "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "--rays" in result.stdout and "--random-profiles" not in result.stdout


@pytest.mark.slow
def test_hollow_glass_gradient_script(capsys):
    """Bad options in one line; a small run prints the interior sums that
    glass_gradient gives for the same scene, vertex, step and seed (32x32,
    4 spp: AD -0.430 against FD -0.423 when written)."""
    import numpy as np

    script = load_script("hollow_glass_gradient.py")
    for argv, message in [
        (["--vertex", "999"], "--vertex must be in 0..", ),
        (["--steps", "0.01", "-0.01"], "--steps must be positive, got 0.01 -0.01"),
        (["--resolution", "32x16"], "--resolution must be square, got '32x16'"),
        (["--spp", "0"], "--spp must be at least 1, got 0"),
        (["--resolution", "16", "--spp", "1"], "--resolution must be at least 32, got 16"),
    ]:
        assert script.main([*argv, "--variant", VARIANT]) == 2
        err = capsys.readouterr().err
        assert err.startswith("hollow_glass_gradient.py: error: ") and message in err and err.count("\n") == 1
    assert script.main(["--resolution", "32", "--spp", "4", "--steps", "0.05", "--vertex", "30",
                        "--variant", VARIANT]) == 0
    out = capsys.readouterr().out
    ad_line = next(line for line in out.splitlines() if line.strip().startswith("AD "))
    fd_line = next(line for line in out.splitlines() if line.strip().startswith("FD h=0.05"))
    whole, whole_fd = float(ad_line.split()[1]), float(fd_line.split()[2])
    assert whole != 0.0 and abs(whole - whole_fd) < 0.1 * abs(whole_fd), out

    import mitsuba as mi

    from lathe_shape.tools.diff_scenes import glass_scene
    from lathe_shape.tools.gradients import glass_gradient

    scene = glass_scene(str(ROOT / "scenes" / "wine_glass.csv"), resolution=32)
    (glass,) = [shape for shape in scene.shapes() if shape.id() == "glass"]
    expected = glass_gradient(scene, glass, 60, 0.05, 4, 0)
    assert mi.variant() == VARIANT
    assert np.isclose(whole, expected.ad[expected.interior].sum(), rtol=1e-3, atol=1e-3), (out, whole)


@pytest.mark.slow
@pytest.mark.parametrize("script, total", [("leak_test.py", "total "), ("leak_test_bspline.py", "total ")])
def test_leak_scripts_walk_the_solid_scene_profiles(script, total):
    """Both watertightness scripts run over scenes/ (whose filled glass's
    open sheets, which have no inside, they leave out: read as solids they
    gave 21% "leaks", read as B-spline control points a crash), and the
    exact queries have no odd count on these few rays."""
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / script), "6000", "--variant", VARIANT],
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "liquid_top" not in result.stdout and "filled_glass " not in result.stdout
    totals = [line for line in result.stdout.splitlines() if line.startswith(total)]
    assert totals, result.stdout
    if script == "leak_test.py":
        exact = totals[0].split(" exact: hitting")[1].split()  # ['N', 'odd', '0', ...]
        assert exact[1] == "odd" and exact[2] == "0", totals
    else:
        assert "odd walk    0 odd count    0" in totals[-1], totals



def test_profile_kernels_accounts_for_the_wall_time(capsys):
    profile = load_script("profile_kernels.py")
    assert profile.main(["--resolution", "16x16", "--spp", "1", "--top", "2", "--variant", VARIANT]) == 0
    lines = capsys.readouterr().out.splitlines()
    cases = [line for line in lines if not line.startswith(" ")]
    assert [line.split(":")[0] for line in cases] == ["plain bottle", "caustics bottle"]
    assert len(lines) == 2 + 2 * 2  # each case and its two most expensive kernels
    launches = []
    for line in cases:
        wall = float(line.split(": ")[1].split(" ms wall")[0])
        launches.append(int(line.split("wall, ")[1].split(" kernels")[0]))
        in_kernels = float(line.split("operations), ")[1].split(" ms in kernels")[0])
        assert 0.0 < in_kernels <= wall  # the kernels run within the case's wall time
    assert 2 <= launches[0] < launches[1]  # the caustic paths have kernels of their own
    for bad, message in ((["--resolution", "16x8"], "--resolution must be square (WxW)"),
                         (["--scene", "nope"], "unknown --scene 'nope'")):
        with pytest.raises(SystemExit, match=re.escape(message)):
            profile.main([*bad, "--variant", VARIANT])
