"""The command-line layer's guarantees, in process: every exception becomes
one line, renders run interruptibly, absurd sizes are refused with the
numbers, and resolution overrides keep the scene file's lines."""

from __future__ import annotations

import argparse
import threading

import drjit as dr
import pytest
from conftest import SCENES, VARIANT

from lathe_shape.cli import common, compare, render
from lathe_shape.cli.common import CliError, check_render_budget, interruptible, run_command
from lathe_shape.tools.scenes import SceneError, load_scene, set_film_size


def run_body(capsys, error: BaseException) -> tuple[int, str]:
    """run_command on a body that raises ``error``: (status, stderr)."""
    def body(args: argparse.Namespace) -> int:
        raise error

    code = run_command("prog", argparse.ArgumentParser(prog="prog"), body, [])
    return code, capsys.readouterr().err


@pytest.mark.parametrize("error, message", [
    (CliError("bad option"), "prog: error: bad option\n"),
    (MemoryError(), "prog: error: MemoryError\n"),
    (OverflowError("int too large"), "prog: error: OverflowError: int too large\n"),
    (TypeError("incompatible arguments"), "prog: error: TypeError: incompatible arguments\n"),
    (UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte"),
     "prog: error: 'utf-8' codec can't decode byte 0xff in position 0: invalid start byte\n"),
    (KeyboardInterrupt(), "prog: interrupted\n"),
])
def test_every_exception_is_one_line(capsys, error, message):
    code, stderr = run_body(capsys, error)
    assert stderr == message and code == (130 if isinstance(error, KeyboardInterrupt) else 2)


def test_wrapped_interrupt(capsys):
    """Ctrl-C inside a Dr.Jit call arrives as the cause of a RuntimeError."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            raise RuntimeError("drjit: error while performing a custom operation") from inner
    except RuntimeError as wrapped:
        assert run_body(capsys, wrapped) == (130, "prog: interrupted\n")


def test_traceback_on_request(capsys, monkeypatch):
    monkeypatch.setenv("LATHE_TRACEBACK", "1")
    code, stderr = run_body(capsys, ZeroDivisionError("division by zero"))
    assert code == 2 and "Traceback" in stderr
    assert stderr.endswith("prog: error: ZeroDivisionError: division by zero\n")


def test_interruptible_runs_in_a_worker():
    dr.set_flag(dr.JitFlag.SymbolicLoops, False)  # Dr.Jit flags are per thread: the worker gets the caller's
    try:
        name, flag = interruptible(lambda: (threading.current_thread().name,
                                            dr.flag(dr.JitFlag.SymbolicLoops)))
    finally:
        dr.set_flag(dr.JitFlag.SymbolicLoops, True)
    assert name != threading.main_thread().name and flag is False
    with pytest.raises(ValueError, match="from the worker"):
        interruptible(lambda: (_ for _ in ()).throw(ValueError("from the worker")))
    assert common._all_work_done()


def test_render_budget():
    check_render_budget(512, 512, 16320, available=10**9)
    with pytest.raises(CliError, match=r"a 100000x100000 film needs about 480.0 GB of memory, more than "
                                       r"80% of the 16.0 GB available: use a smaller --resolution"):
        check_render_budget(100000, 100000, 1, available=16 * 10**9)
    with pytest.raises(CliError, match=r"1000000000 spp on a 512x512 film is 262144000000000 samples, more "
                                       r"than the 4278190080 one render can take: use at most --spp 16320"):
        check_render_budget(512, 512, 10**9, available=10**12)
    with pytest.raises(CliError, match="more pixels than the 4278190080 samples one render can take"):
        check_render_budget(70000, 70000, 1, available=10**15)
    assert common.available_memory() > 0


#: A 16x12 scene with a lathe.
SMALL = """<scene version="3.0.0">
    <sensor type="perspective">
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="lathe"><string name="profile" value="0 0, 1 0, 1 2, 0 2"/></shape>
</scene>"""


@pytest.mark.parametrize("options, message", [
    (["--resolution", "100000x100000"], "a 100000x100000 film needs about 480.0 GB of memory"),
    (["--spp", "1000000000"], "1000000000 spp on a 16x12 film is 192000000000 samples"),
    (["--spp", "4294967296"], "--spp must be at most 4294967295, got 4294967296"),
    (["--seed", "-1"], "--seed must be at least 0, got -1"),
    (["--resolution", "99999999999x2"], "--resolution '99999999999x2' is too large"),
])
def test_absurd_options(tmp_path, capsys, options, message):
    """Refused before anything is rendered or written, in both commands."""
    scene = tmp_path / "scene.xml"
    scene.write_text(SMALL)
    for main, prog in ((render.main, "lathe-render"), (compare.main, "lathe-compare")):
        code = main(["--variant", VARIANT, str(scene), "-o", str(tmp_path / "out"), *options])
        stderr = capsys.readouterr().err
        assert code == 2 and stderr.startswith(f"{prog}: error: ") and message in stderr, stderr
    assert not (tmp_path / "out").exists()


def test_compare_interrupted_writes_nothing(tmp_path, capsys, monkeypatch):
    """Ctrl-C during the second render: no image of the first is left."""
    calls = []

    def render_image(*args):
        calls.append(args)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return common.render_image(*args)

    monkeypatch.setattr(common, "render_image", render_image)
    code = compare.main(["--variant", VARIANT, str(SCENES / "wine_glass.xml"), "-o", str(tmp_path),
                         "--spp", "1", "--resolution", "12x10", "-D", "mesh_segments=16"])
    assert code == 130 and capsys.readouterr().err == "lathe-compare: interrupted\n"
    assert len(calls) == 2 and list(tmp_path.iterdir()) == []


FILM = """<scene version="3.0.0">
    <!-- two lines
         of comment -->
    <sensor type="perspective">
        <film type="hdrfilm" >
            <integer name="height" value="$res"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <sensor type="perspective"><film type="hdrfilm"/></sensor>
    <film type="hdrfilm"/>
</scene>
"""


def test_set_film_size_keeps_lines():
    """Only the sizes change; a missing one goes on the <film> tag's line."""
    edited = set_film_size(FILM, (7, 5))
    assert edited.splitlines() == [
        *FILM.splitlines()[:4],
        '        <film type="hdrfilm" ><integer name="width" value="7"/>',
        '            <integer name="height" value="5"/>',
        *FILM.splitlines()[6:9],
        '    <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="7"/>'
        '<integer name="height" value="5"/></film></sensor>',
        *FILM.splitlines()[10:],
    ]
    with pytest.raises(SceneError, match="f.xml: no <sensor> with a <film>"):
        set_film_size("<scene><sensor/></scene>", (1, 1), "f.xml")
    with pytest.raises(SceneError, match=r"f.xml: not a valid XML file \(mismatched tag: line 2, column 2\)"):
        set_film_size("<scene><sensor>\n</scene>", (1, 1), "f.xml")


def test_resolution_with_a_comment_quoting_a_command_line(tmp_path):
    # Mitsuba accepts '--' inside a comment (strict XML does not): the
    # resolution override must still apply, with the lines unchanged.
    text = FILM.replace("<scene", "<!-- lathe-render this.xml --resolution 64x48 -->\n<scene", 1)
    edited = set_film_size(text, (7, 5))
    assert edited.splitlines()[0] == text.splitlines()[0]
    assert edited.count('value="7"') == 2 and edited.count('value="5"') == 2
    path = tmp_path / "commented.xml"
    path.write_text('<!-- lathe-render commented.xml --resolution 64x48 -->\n<scene version="3.0.0">'
                    '<sensor type="perspective"><film type="hdrfilm"/></sensor>'
                    '<shape type="sphere"/></scene>', encoding="utf-8")
    scene = load_scene(path, resolution=(64, 48))
    assert tuple(scene.sensors()[0].film().size()) == (64, 48)


def test_resolution_never_ignored(tmp_path):
    # Text Mitsuba accepts but strict XML refuses (an unescaped '<' in an
    # attribute): a requested resolution is an error, never silently dropped.
    path = tmp_path / "lenient.xml"
    path.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm"/></sensor>'
                    '<shape type="sphere" id="a<b"/></scene>', encoding="utf-8")
    try:
        load_scene(path)
    except SceneError:
        pytest.skip("Mitsuba refuses this text too")
    expected = r"lenient.xml: not a valid XML file .*the resolution 64x48 cannot be set"
    with pytest.raises(SceneError, match=expected):
        load_scene(path, resolution=(64, 48))
