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

``labels[k]`` names point ``k`` (file and line, or parameter and position)
in error messages. :func:`format_profile_csv` / :func:`write_profile_csv`
are the one CSV writer (the inverse of :func:`read_profile_csv`).
"""

from __future__ import annotations

import os

import numpy as np

from .arcs import load_profile_spec
from .errors import ProfileError

__all__ = [
    "SPEC_SUFFIXES",
    "read_points",
    "parse_profile_string",
    "read_profile_csv",
    "format_profile_csv",
    "write_profile_csv",
]

#: File name endings read as arc specs; anything else is read as CSV.
SPEC_SUFFIXES = (".json", ".toml")

#: Raw points as every reader returns them: (points (n, 2), sharp (n,), labels).
RawPoints = tuple[np.ndarray, np.ndarray, list[str]]


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
    rows: list[tuple[list[float], bool, str]] = []
    for k, item in enumerate(item for item in items if item):
        label = f"{source}, point {k + 1}"
        point, flag = _parse_row(item.split(), label, f"expected 'r z' or 'r z sharp', got {item!r}")
        rows.append((point, flag, label))
    return _as_raw_points(rows)


def read_profile_csv(path: str | os.PathLike) -> RawPoints:
    """Read a profile CSV file: columns ``r,z[,sharp]``, ``#`` comments,
    optional header. Returns ``(points, sharp, labels)`` like
    :func:`parse_profile_string`; labels give file name and line number."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.readlines()
    except OSError as e:
        raise ProfileError(f"{path}: cannot read profile file ({e.strerror})") from None
    rows: list[tuple[list[float], bool, str]] = []
    for number, line in enumerate(lines, start=1):
        content = line.split("#", 1)[0].strip()
        if not content:
            continue
        fields = [f.strip() for f in content.replace(";", ",").split(",")]
        if len(fields) == 1:
            fields = content.split()
        if not rows and _is_header(fields):
            continue
        label = f"{path}, line {number}"
        point, flag = _parse_row(fields, label, f"expected 2 or 3 columns (r,z[,sharp]), got {len(fields)}")
        rows.append((point, flag, label))
    return _as_raw_points(rows)


def format_profile_csv(
    points: np.ndarray, sharp: np.ndarray | None = None, header: str = "", number_format: str = ".9g"
) -> str:
    """CSV text of a profile: ``header`` lines as ``#`` comments, then
    ``r,z,sharp`` rows (``r,z`` rows when ``sharp`` is None), numbers written
    with ``number_format`` (e.g. ``".6f"``)."""
    lines = [f"# {line}" for line in header.splitlines()]
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
) -> str:
    """Write :func:`format_profile_csv` to ``path``; returns the path."""
    path = os.fspath(path)
    with open(path, "w", encoding="utf-8") as f:
        f.write(format_profile_csv(points, sharp, header, number_format))
    return path


def _parse_row(fields: list[str], label: str, wrong_count: str) -> tuple[list[float], bool]:
    """One point: ``r z`` or ``r z sharp`` -> ([r, z], sharp)."""
    if len(fields) not in (2, 3):
        raise ProfileError(f"{label}: {wrong_count}")
    point = [_parse_float(f, label) for f in fields[:2]]
    return point, len(fields) == 3 and _parse_flag(fields[2], label)


def _is_header(fields: list[str]) -> bool:
    names = [f.lower() for f in fields]
    return names[:2] == ["r", "z"] and (len(names) == 2 or names[2:] == ["sharp"])


def _parse_float(text: str, label: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ProfileError(f"{label}: {text!r} is not a number") from None


def _parse_flag(text: str, label: str) -> bool:
    if text in ("0", "1"):
        return text == "1"
    raise ProfileError(f"{label}: sharp flag must be 0 or 1, got {text!r}")


def _as_raw_points(rows: list[tuple[list[float], bool, str]]) -> RawPoints:
    points = np.array([point for point, _, _ in rows], dtype=np.float64).reshape(-1, 2)
    sharp = np.array([flag for _, flag, _ in rows], dtype=bool)
    return points, sharp, [label for _, _, label in rows]
