"""Property-based fuzzing of the command-line argument layer, in process:
whatever text or number reaches ``--resolution``, ``-D``, ``--spp`` or
``--seed``, the checks either accept it or raise :class:`CliError` naming
the option -- never another exception.

``LATHE_FUZZ_EXAMPLES=N`` runs N examples per property (default 25)."""

from __future__ import annotations

import argparse
import os

from hypothesis import given, settings
from hypothesis import strategies as st

from lathe_shape.cli.common import (
    CliError,
    check_at_least,
    check_between,
    check_render_options,
    parse_defines,
    parse_resolution,
)
from lathe_shape.cli.render import build_parser

FUZZ = settings(max_examples=int(os.environ.get("LATHE_FUZZ_EXAMPLES", "25")), deadline=None)

#: Text that looks like a resolution now and then.
RESOLUTIONS = st.one_of(
    st.text(),
    st.from_regex(r"\A-?[0-9]{0,25}(x-?[0-9]{0,25}){0,2}\Z"),
    st.builds(lambda w, h: f"{w}x{h}", st.integers(), st.integers()),
)
#: Numbers of any size and kind.
NUMBERS = st.one_of(st.integers(), st.floats(allow_nan=True, allow_infinity=True), st.none())


@FUZZ
@given(RESOLUTIONS)
def test_parse_resolution(text):
    try:
        width, height = parse_resolution(text)
    except CliError as e:
        assert "--resolution" in str(e)
    else:
        assert isinstance(width, int) and isinstance(height, int) and 1 <= min(width, height)


@FUZZ
@given(st.lists(st.one_of(st.text(), st.from_regex(r"\A[a-z_ ]*=.*\Z"))))
def test_parse_defines(items):
    try:
        defines = parse_defines(items)
    except CliError as e:
        assert str(e).startswith("-D expects key=value")
    else:
        assert all(key == key.strip() and key for key in defines)


@FUZZ
@given(NUMBERS, NUMBERS, NUMBERS)
def test_number_checks(value, minimum, maximum):
    for check in (lambda: check_at_least("--spp", value, minimum or 0),
                  lambda: check_between("--seed", value, minimum or 0, maximum or 0)):
        try:
            check()
        except CliError as e:
            assert str(e).startswith(("--spp must be", "--seed must be"))


@FUZZ
@given(st.one_of(st.none(), st.integers()), st.integers(), st.one_of(st.none(), RESOLUTIONS),
       st.one_of(st.none(), st.lists(st.text(max_size=12), max_size=3)))
def test_render_options(spp, seed, resolution, defines):
    """The render command's checks of parsed options."""
    args = argparse.Namespace(spp=spp, seed=seed, resolution=resolution, defines=defines)
    try:
        check_render_options(args)
    except CliError as e:
        assert str(e).startswith(("--spp ", "--seed ", "--resolution ", "-D "))


@FUZZ
@given(st.lists(st.sampled_from(["--spp", "--seed", "--resolution", "-D"]), max_size=4),
       st.lists(st.text(alphabet=st.characters(blacklist_categories=["Cs"]), max_size=20), min_size=4,
                max_size=4))
def test_render_command_line(options, values):
    """Whole command lines: argparse refuses (SystemExit 2) or the checks
    accept or raise CliError."""
    argv = ["scene.xml"] + [x for pair in zip(options, values[:len(options)], strict=True) for x in pair]
    parser = build_parser()
    parser.error = lambda message: (_ for _ in ()).throw(SystemExit(2))  # (quiet)
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:
        assert e.code == 2
        return
    try:
        check_render_options(args)
    except CliError:
        pass


#: Whitespace as scene files have it inside tags, and comments between them.
SPACES = st.lists(st.sampled_from([" ", "\n", "\t", "\n    "]), min_size=1, max_size=3).map("".join)
GAPS = st.lists(st.sampled_from([" ", "\n", "\n    ", "<!-- a\n comment -->"]), max_size=3).map("".join)


@st.composite
def film_scenes(draw) -> str:
    """A scene whose sensor's film has a width and/or height (or neither),
    spread over lines in various ways."""
    def gap(inside_tag: bool = False) -> str:
        return draw(SPACES if inside_tag else GAPS)

    values = st.sampled_from(["$res", "9"])
    sizes = [f'<integer{gap(True)}name="{name}"{gap(True)}value="{draw(values)}"{gap(True)}/>'
             for name in ("width", "height") if draw(st.booleans())]
    children = gap().join(draw(st.permutations([*sizes, '<rfilter type="box"/>'])))
    film = (f'<film type="hdrfilm"{gap(True)}/>' if not sizes and draw(st.booleans())
            else f'<film type="hdrfilm"{gap(True)}>{gap()}{children}{gap()}</film>')
    sensor = f'<sensor type="perspective">{gap()}{film}{gap()}</sensor>'
    return f'{gap()}<scene version="3.0.0">{gap()}{sensor}{gap()}</scene>'


@FUZZ
@given(film_scenes(), st.integers(1, 10**6), st.integers(1, 10**6))
def test_set_film_size(text, width, height):
    """The film gets the size; the lines stay where they were."""
    import xml.etree.ElementTree as ET

    from lathe_shape.tools.scenes import set_film_size

    edited = set_film_size(text, (width, height))
    assert edited.count("\n") == text.count("\n")
    film = ET.fromstring(edited).find("sensor/film")
    values = {child.get("name"): child.get("value") for child in film if child.tag == "integer"}
    assert values == {"width": str(width), "height": str(height)}
    head = text[:text.index("<film")]
    assert edited.startswith(head) and edited.endswith(text[text.index("</sensor>"):])
