"""Reading and writing the points of a profile (numpy only).

Three sources give the raw points ``(points (n, 2), sharp (n,), labels)``
that :func:`lathe_shape.profiles.polyline.make_profile` and
:func:`lathe_shape.profiles.bspline.make_bspline_profile` validate:

* an inline string ``"r z, r z, ..."`` (the lathe's ``profile`` parameter),
  a third number per point (0 or 1) flagging a sharp vertex;
* a CSV file with columns ``r,z`` and an optional third column ``sharp``
  (1 = crease at this vertex); ``#`` starts a comment and an optional header
  line names the columns;
* a ``.json``/``.toml`` arc spec (:mod:`lathe_shape.profiles.arcs`: lines and
  equally divided arcs, paper section 2.3).

Files are UTF-8 text (a byte order mark is accepted; other bytes are
refused naming the line and column). Numbers are plain decimal or scientific
numbers (``10``, ``-0.5``, ``1e-3``): Python's ``1_0`` or non-ASCII digits are
refused; ``inf`` and ``nan`` are read and then refused by the validation as
non-finite. ``labels[k]`` names point ``k`` (file and line, or parameter and
position) in error messages. :func:`format_profile_csv` / :func:`write_profile_csv`
are the one CSV writer (the inverse of :func:`read_profile_csv`).

A CSV file may declare how its points are read in comment lines of the form
``# kind: NAME`` (a profile kind: ``bspline``, ``bezier``, ``sor`` ...) and
``# open: true`` (a single open sheet); :func:`read_profile_options` reads
them, and the writer's ``options`` writes them.
"""

from __future__ import annotations

import os
import re
from array import array
from collections.abc import Iterable, Iterator, Sequence
from typing import BinaryIO

import numpy as np

from .arcs import load_profile_spec
from .errors import ProfileError
from .limits import MAX_PROFILE_POINTS, check_point_count
from .text import PointLabels, decode_utf8

__all__ = [
    "SPEC_SUFFIXES",
    "read_points",
    "parse_profile_string",
    "read_profile_csv",
    "format_profile_csv",
    "write_profile_csv",
    "read_profile_options",
]

#: Largest profile CSV file read whole (the fast path of read_profile_csv).
FAST_READ_BYTES = 64 << 20

#: File name endings read as arc specs; anything else is read as CSV.
SPEC_SUFFIXES = (".json", ".toml")

#: Raw points as every reader returns them: (points (n, 2), sharp (n,), labels).
RawPoints = tuple[np.ndarray, np.ndarray, Sequence[str]]


def read_points(path: str | os.PathLike) -> RawPoints:
    """The raw points of a profile file: an arc spec (``.json``, ``.toml``)
    or a CSV file (any other name). Raises :class:`ProfileError` naming the
    file (and the line or spec key) on bad input."""
    if os.fspath(path).lower().endswith(SPEC_SUFFIXES):
        return load_profile_spec(path)
    return read_profile_csv(path)


def parse_profile_string(text: str, source: str = "parameter 'profile'") -> RawPoints:
    """Parse ``"r z, r z, ..."`` (or ``"r z sharp, ..."``) into points.

    Returns ``(points (n, 2), sharp (n,), labels)``; ``labels[k]`` names point
    ``k`` in error messages.
    """
    items = [item.strip() for item in text.replace(";", ",").split(",")]
    rows = _Rows(source, "point")
    for k, item in enumerate(item for item in items if item):
        rows.add(item.split(), k + 1, f"expected 'r z' or 'r z sharp', got {item!r}")
    return rows.raw_points()


def read_profile_csv(path: str | os.PathLike) -> RawPoints:
    """Read a profile CSV file: columns ``r,z[,sharp]``, ``#`` comments,
    optional header, UTF-8 text (a byte order mark is accepted). Returns
    ``(points, sharp, labels)`` like :func:`parse_profile_string`; labels give
    file name and line number. Files of up to :data:`FAST_READ_BYTES` are
    read whole and parsed with one pattern per line; where a line needs a
    message, and for larger files, the file is read line by line, and
    refused past :data:`~lathe_shape.profiles.limits.MAX_PROFILE_POINTS`
    points."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            small = os.fstat(f.fileno()).st_size <= FAST_READ_BYTES
            fast = _read_csv_rows(f.read(), path) if small else None
    except OSError as e:
        raise ProfileError(f"{path}: cannot read profile file ({e.strerror})") from None
    # Something to report: read line by line, which names it
    return fast if fast is not None else _read_csv_lines(path)


def _read_csv_lines(path: str) -> RawPoints:
    """:func:`read_profile_csv` line by line, with a message naming the
    line for anything that is not a point, a comment or the header."""
    rows = _Rows(path, "line")
    first: tuple[str, int] | None = None  # The first point's separator and line
    try:
        with open(path, "rb") as f:
            for number, raw in _numbered_lines(f):
                content = decode_utf8(raw, path, number).split("#", 1)[0].strip()
                if not content:
                    continue
                fields = _csv_fields(content)
                if not rows.numbers and _is_header(fields):
                    continue
                separator = _separator(content)
                if _decimal_comma(content):
                    raise ProfileError(f"{rows.label(number)}: a decimal comma ({content!r}); numbers are "
                                       "written with a point (1.5, not 1,5)")
                if first is None:
                    first = separator, number
                elif separator != first[0]:
                    raise ProfileError(
                        f"{rows.label(number)}: columns separated by {_SEPARATOR_NAMES[separator]}, where "
                        f"line {first[1]} separates them by {_SEPARATOR_NAMES[first[0]]}: use one separator")
                rows.add(fields, number, f"expected 2 or 3 columns (r,z[,sharp]), got {len(fields)}")
    except OSError as e:
        raise ProfileError(f"{path}: cannot read profile file ({e.strerror})") from None
    return rows.raw_points()


def _read_csv_rows(data: bytes, path: str) -> RawPoints | None:
    """The points of a well-formed profile CSV file (``data``: its bytes),
    read fast; ``None`` when any line needs a message (not UTF-8, a bad
    row, too many points), which the line-by-line reader then gives."""
    try:
        text = decode_utf8(data, path)
    except ProfileError:
        return None
    coordinates: list[float] = []
    sharp: list[bool] = []
    numbers: list[int] = []
    first_pattern = None  # The pattern (separator) of the first point
    for number, line in enumerate(_LINE_END.split(text), start=1):
        index, match = _row_match(line)
        if match is not None:
            first_pattern = index if first_pattern is None else first_pattern
            if index != first_pattern:
                return None  # (another separator than the first point's)
        else:
            content = line.split("#", 1)[0].strip()
            if not content or (not numbers and _is_header(_csv_fields(content))):
                continue
            return None
        r, z, flag = match.groups()
        coordinates += (float(r), float(z))
        sharp.append(flag == "1")
        numbers.append(number)
    if len(numbers) > MAX_PROFILE_POINTS:
        return None
    points = np.array(coordinates, dtype=np.float64).reshape(-1, 2)
    return points, np.array(sharp, dtype=bool), PointLabels(path, np.array(numbers, dtype=np.int64), "line")


#: ``# key: value`` declarations of a profile CSV (see the module docstring).
_OPTION = re.compile(r"#\s*(kind|open)\s*:\s*([^\s#]+)\s*(?:#.*)?$", re.IGNORECASE)


def read_profile_options(path: str | os.PathLike, kinds: Iterable[str] | None = None) -> dict:
    """The ``# kind: NAME`` and ``# open: true|false`` declarations of a
    profile CSV file (``{}`` for none, or for an arc spec): ``{"kind": str,
    "open": bool}``. Raises :class:`ProfileError` naming the file and line
    for an ``open`` value other than true/false, and for a kind not in
    ``kinds`` (when given)."""
    path = os.fspath(path)
    if path.lower().endswith(SPEC_SUFFIXES):
        return {}
    options: dict = {}
    declared: dict[str, int] = {}  # key: line of its declaration
    try:
        with open(path, "rb") as f:
            for number, raw in _numbered_lines(f):
                if b"#" not in raw:
                    continue  # (bytes that are not UTF-8: read_profile_csv names them)
                line = decode_utf8(raw, path, number).strip()
                match = _OPTION.match(line) if line.startswith("#") else None
                if match is None:
                    continue
                key, value = match.group(1).lower(), match.group(2)
                if key in declared:
                    raise ProfileError(f"{path}, line {number}: a second '# {key}:' declaration (the "
                                       f"first is on line {declared[key]}): give it once")
                declared[key] = number
                if key == "open":
                    if value.lower() not in ("true", "false"):
                        raise ProfileError(f"{path}, line {number}: 'open' must be true or false, "
                                           f"got {value!r}")
                    options[key] = value.lower() == "true"
                else:
                    if kinds is not None and value not in kinds:
                        raise ProfileError(f"{path}, line {number}: unknown profile kind {value!r} "
                                           f"(expected one of: {', '.join(kinds)})")
                    options[key] = value
    except OSError as e:
        raise ProfileError(f"{path}: cannot read profile file ({e.strerror})") from None
    return options


def _numbered_lines(f: BinaryIO) -> Iterator[tuple[int, bytes]]:
    """``(line number, bytes)`` of a binary file, without the line ends;
    ``\n``, ``\r\n`` and ``\r`` all end a line (as in text mode)."""
    number = 0
    for raw in f:
        raw = raw[:-1] if raw.endswith(b"\n") else raw
        raw = raw[:-1] if raw.endswith(b"\r") else raw
        for part in raw.split(b"\r"):
            number += 1
            yield number, part


def format_profile_csv(
    points: np.ndarray, sharp: np.ndarray | None = None, header: str = "", number_format: str = ".9g",
    options: dict | None = None,
) -> str:
    """CSV text of a profile: ``header`` lines as ``#`` comments, the
    ``options`` (``kind``, ``open``) as ``# key: value`` declarations, then
    ``r,z,sharp`` rows (``r,z`` rows when ``sharp`` is None), numbers written
    with ``number_format`` (e.g. ``".6f"``)."""
    lines = [f"# {line}" for line in header.splitlines()]
    for key, value in (options or {}).items():
        lines.append(f"# {key}: {str(value).lower() if isinstance(value, bool) else value}")
    if sharp is None:
        lines.append("r,z")
        lines += [f"{r:{number_format}},{z:{number_format}}" for r, z in points]
    else:
        lines.append("r,z,sharp")
        lines += [f"{r:{number_format}},{z:{number_format}},{int(s)}"
                  for (r, z), s in zip(points, sharp, strict=True)]
    return "\n".join(lines) + "\n"


def write_profile_csv(
    path: str | os.PathLike,
    points: np.ndarray,
    sharp: np.ndarray | None = None,
    header: str = "",
    number_format: str = ".9g",
    options: dict | None = None,
) -> str:
    """Write :func:`format_profile_csv` to ``path``; returns the path."""
    path = os.fspath(path)
    with open(path, "w", encoding="utf-8") as f:
        f.write(format_profile_csv(points, sharp, header, number_format, options))
    return path


class _Rows:
    """The points read so far (compact arrays, no per-point objects) and
    their numbers (line or position) for the labels."""

    def __init__(self, prefix: str, word: str) -> None:
        self.prefix, self.word = prefix, word
        self.coordinates = array("d")  # r0, z0, r1, z1, ...
        self.sharp = bytearray()
        self.numbers = array("q")

    def add(self, fields: list[str], number: int, wrong_count: str) -> None:
        """One point: ``r z`` or ``r z sharp``, number ``number``."""
        if len(self.numbers) >= MAX_PROFILE_POINTS:
            check_point_count(len(self.numbers) + 1, self.label(number), at_least=True)
        if len(fields) not in (2, 3):
            raise ProfileError(f"{self.label(number)}: {wrong_count}")
        r, z = fields[0], fields[1]
        if _NUMBER.fullmatch(r) is None or _NUMBER.fullmatch(z) is None:
            for text in (r, z):
                _parse_float(text, self.label(number))
        self.coordinates.append(float(r))
        self.coordinates.append(float(z))
        self.sharp.append(len(fields) == 3 and _parse_flag(fields[2], self.label(number)))
        self.numbers.append(number)

    def label(self, number: int) -> str:
        """Where point ``number`` is, for messages (built only for one)."""
        return f"{self.prefix}, {self.word} {number}"

    def raw_points(self) -> RawPoints:
        points = np.frombuffer(self.coordinates, dtype=np.float64).reshape(-1, 2).copy()
        sharp = np.frombuffer(bytes(self.sharp), dtype=np.uint8).astype(bool)
        return points, sharp, PointLabels(self.prefix, np.frombuffer(self.numbers, np.int64), self.word)


def _row_match(line: str) -> tuple[int, re.Match | None]:
    """The index in :data:`_ROWS` (its separator) of the pattern that
    ``line`` matches, and the match (``(-1, None)``: none)."""
    for index, pattern in enumerate(_ROWS):
        match = pattern.fullmatch(line)
        if match is not None:
            return index, match
    return -1, None


def _decimal_comma(content: str) -> bool:
    """Whether a CSV line's content writes a number with a decimal comma:
    commas beside semicolons (``1,5;0``), or a comma between digits among
    fields that white space separates (``1,5 0``)."""
    if ";" in content:
        return "," in content
    fields = content.split()
    inner = [f for f in fields if "," in f.strip(",")]  # (a field's trailing comma separates)
    return len(fields) > 1 and bool(inner) and all(_DECIMAL_COMMA.fullmatch(f) for f in inner)


#: A number written with a decimal comma.
_DECIMAL_COMMA = re.compile(r"[+-]?[0-9]+,[0-9]+(?:[eE][+-]?[0-9]+)?")


def _separator(content: str) -> str:
    """The column separator of a CSV line's content: a semicolon if there is
    one, else a comma if there is one, else white space (``" "``)."""
    return ";" if ";" in content else "," if "," in content else " "


_SEPARATOR_NAMES = {",": "commas", ";": "semicolons", " ": "white space"}


def _csv_fields(content: str) -> list[str]:
    """The fields of a CSV line's content (comment removed), split at its
    :func:`_separator`."""
    separator = _separator(content)
    return content.split() if separator == " " else [f.strip() for f in content.split(separator)]


def _is_header(fields: list[str]) -> bool:
    """A header row: 2 or 3 column names (``r,z,sharp``, ``x,y``,
    ``"radius","height"``: any words, quoted or not), no number among
    them."""
    names = [f.strip().strip('"').strip("'").strip() for f in fields]
    return 2 <= len(names) <= 3 and all(names) and not any(_NUMBER.fullmatch(n) for n in names)


#: A plain decimal or scientific number, or the words inf, infinity, nan
#: (read, then refused as non-finite by the validation). Python's float()
#: also takes "1_0", non-ASCII digits and spaces; those are refused here.
_NUMBER = re.compile(r"[+-]?(?:(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|inf|infinity|nan)",
                     re.IGNORECASE)


#: A CSV row of two or three columns separated by commas, semicolons or
#: white space, and an optional comment: the whole content of a line that
#: :func:`read_profile_csv` accepts without a word (every point of a file
#: with the same separator).
_ROWS = [re.compile(rf"\s*({_NUMBER.pattern})\s*{sep}\s*({_NUMBER.pattern})(?:\s*{sep}\s*([01]))?\s*(?:#.*)?",
                    re.IGNORECASE) for sep in (",", ";", r"\s")]
#: Line ends as :func:`_numbered_lines` counts them.
_LINE_END = re.compile("\r\n|\r|\n")


def _parse_float(text: str, label: str) -> float:
    if _NUMBER.fullmatch(text) is None:
        raise ProfileError(f"{label}: {text!r} is not a number (write plain decimal numbers, "
                           f"e.g. 10, -0.5 or 1e-3)")
    return float(text)


def _parse_flag(text: str, label: str) -> bool:
    if text in ("0", "1"):
        return text == "1"
    raise ProfileError(f"{label}: sharp flag must be 0 or 1, got {text!r}")
