"""Tokens of POV-Ray scene description language (SDL) text, and the error
every part of the SDL front end raises (numpy free, no evaluation).

A token is ``(kind, text, path, line)``: ``number``, ``string`` (the text
keeps its quotes), ``word`` (an identifier or keyword), ``directive``
(``#declare``, ``#if``, ...), ``symbol`` (one character, or ``<=``, ``>=``,
``!=``). Line comments and block comments (which POV-Ray lets nest) are
dropped; a block comment left open is an error naming where it started.
"""

from __future__ import annotations

import re
from typing import NamedTuple

from ..errors import ProfileError

__all__ = ["PovError", "Token", "tokenize", "MAX_FILE_CHARS"]

#: Largest scene or include file read (characters).
MAX_FILE_CHARS = 20_000_000


class PovError(ProfileError):
    """A POV-Ray scene (or one object of it) that cannot be read; the
    message names file and line."""


class Token(NamedTuple):
    kind: str
    text: str
    path: str
    line: int

    @property
    def where(self) -> str:
        return f"{self.path}:{self.line}"


_PATTERN = re.compile(r"""(?P<line_comment>//[^\n]*)|(?P<comment_open>/\*)
    |(?P<string>"(?:[^"\\\n]|\\.)*")
    |(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)
    |(?P<directive>\#[ \t]*[A-Za-z_][A-Za-z0-9_]*)|(?P<word>[A-Za-z_][A-Za-z0-9_]*)
    |(?P<space>\s+)|(?P<symbol><=|>=|!=|.)""", re.VERBOSE | re.DOTALL)

_BLOCK = re.compile(r"/\*|\*/")


def tokenize(text: str, path: str) -> list[Token]:
    """The tokens of ``text`` (read from ``path``, for messages)."""
    tokens: list[Token] = []
    pos, line, n = 0, 1, len(text)
    while pos < n:
        m = _PATTERN.match(text, pos)
        kind = m.lastgroup
        if kind == "comment_open":  # nested block comments
            start_line, depth, k = line, 1, m.end()
            while depth:
                b = _BLOCK.search(text, k)
                if b is None:
                    raise PovError(f"{path}:{start_line}: block comment '/*' is not closed")
                depth += 1 if b.group() == "/*" else -1
                k = b.end()
            line += text.count("\n", pos, k)
            pos = k
            continue
        chunk = m.group()
        if kind == "directive":
            tokens.append(Token(kind, "#" + chunk[1:].strip(), path, line))
        elif kind not in ("line_comment", "space"):
            tokens.append(Token(kind, chunk, path, line))
        line += chunk.count("\n")
        pos = m.end()
    return tokens
