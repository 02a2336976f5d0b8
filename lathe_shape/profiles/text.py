"""Profile files as text: UTF-8 decoding with a clear error, and the point
labels of error messages (numpy only).

* :func:`decode_utf8` -- bytes of a profile file as text: a leading UTF-8
  byte order mark is dropped, bytes that are not UTF-8 raise
  :class:`ProfileError` naming the file, the line and the column;
* :class:`PointLabels` -- ``labels[k]`` names point ``k`` (``"FILE, line
  12"``, ``"parameter 'profile', point 3"``), built when asked for, so that a
  profile of millions of points does not carry millions of strings.
"""

from __future__ import annotations

import codecs
from collections.abc import Sequence

import numpy as np

from .errors import ProfileError

__all__ = ["PointLabels", "decode_utf8"]


def decode_utf8(data: bytes, path: str, first_line: int = 1) -> str:
    """``data`` (the bytes of ``path`` from line ``first_line`` on) as text.

    A UTF-8 byte order mark at the start of the file is dropped. Raises
    :class:`ProfileError` ``"PATH, line L: not UTF-8 text (byte 0xff at
    column C)"`` (C counts bytes from 1) on the first byte that is not UTF-8.
    """
    if first_line == 1 and data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8):]
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = first_line + data.count(b"\n", 0, e.start)
        column = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise ProfileError(f"{path}, line {line}: not UTF-8 text (byte 0x{data[e.start]:02x} "
                           f"at column {column})") from None


class PointLabels(Sequence[str]):
    """``labels[k] == f"{prefix}, {word} {numbers[k]}"``: the name of point
    ``k`` in error messages (file and line, or parameter and position)."""

    def __init__(self, prefix: str, numbers: np.ndarray | Sequence[int], word: str = "point") -> None:
        self.prefix = prefix
        self.word = word
        self.numbers = np.asarray(numbers, dtype=np.int64)

    @classmethod
    def counting(cls, prefix: str, count: int) -> PointLabels:
        """``"PREFIX, point 1"`` .. ``"PREFIX, point COUNT"``."""
        return cls(prefix, np.arange(1, count + 1))

    def __len__(self) -> int:
        return len(self.numbers)

    def __getitem__(self, k):  # type: ignore[override]
        if isinstance(k, slice):
            return PointLabels(self.prefix, self.numbers[k], self.word)
        return f"{self.prefix}, {self.word} {int(self.numbers[k])}"

    def __repr__(self) -> str:
        return f"PointLabels({self.prefix!r}, {len(self)} {self.word}s)"
