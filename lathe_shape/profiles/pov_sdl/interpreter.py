"""The token stream of a scene with POV-Ray's directives applied: what the
expression and object parsers read (:meth:`Interpreter.next`).

As in POV-Ray, directives act while tokens are read: ``#declare`` and
``#local`` (numbers, vectors, strings, arrays, objects, textures,
transforms; ``NAME[i]`` elements), ``#undef``, ``#if``/``#ifdef``/
``#ifndef``/``#elseif``/``#else``, ``#switch``/``#case``/``#range``/
``#break``, ``#while``, ``#for``, ``#macro`` (a call splices the body in,
with its parameters in a new local scope), ``#include`` (the scene's own
folder, then POV-Ray's include folders), ``#version``, ``#debug``/
``#warning`` (read, ignored), ``#error`` (an error), ``#default`` (skipped)
and file output (``#fopen``/``#write``/``#fclose``: ignored, nothing is
written). ``#read`` is refused.

Bounds: files only from the scene's folder (and below) and the include
folders; at most :data:`MAX_INCLUDE_DEPTH` nested includes,
:data:`MAX_MACRO_DEPTH` nested macro calls, :data:`MAX_STEPS` tokens read
and :data:`MAX_ITERATIONS` loop iterations in all; any excess is a
:class:`PovError` naming file and line.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

from .tokens import MAX_FILE_CHARS, PovError, Token, tokenize
from .values import Macro, PovArray

__all__ = ["Interpreter", "INCLUDE_PATH", "MAX_STEPS", "MAX_ITERATIONS", "MAX_INCLUDE_DEPTH",
           "MAX_MACRO_DEPTH"]

#: POV-Ray's standard include folders (Debian's povray package), searched
#: after the scene's folder.
INCLUDE_PATH = ("/usr/share/povray-3.7/include", "/usr/share/povray/include")

MAX_STEPS = 20_000_000
MAX_ITERATIONS = 2_000_000
MAX_INCLUDE_DEPTH = 16
MAX_MACRO_DEPTH = 64

_OPENERS = {"#if", "#ifdef", "#ifndef", "#switch", "#while", "#for", "#macro"}


@dataclass
class _Frame:
    tokens: list
    pos: int
    end: int
    kind: str  # file, include, macro, dormant
    scope: dict | None = None
    where: str = ""


@dataclass
class _Cond:
    kind: str  # if, switch, while, for
    frame: _Frame
    pos: int = 0  # while: the #while token; for: the body start
    var: str = ""
    stop: float = 0.0
    step: float = 1.0


@dataclass
class Interpreter:
    """Directive-applying token reader over a scene file and its includes."""

    path: str
    include_path: tuple[str, ...] = INCLUDE_PATH
    defines: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        from .expressions import builtin_constants

        self.root = os.path.dirname(os.path.realpath(self.path))
        self.globals: dict = {}
        self.scopes: list[dict] = [self.globals]
        self.globals.update(builtin_constants())
        self.globals.update(self.defines)
        self.frames: list[_Frame] = []
        self.conds: list[_Cond] = []
        self.pushback: list[Token] = []
        self.steps = self.iterations = 0
        self.files: list[str] = []
        self._cache: dict[str, list[Token]] = {}
        self._lines: dict[str, int] = {}
        self.last = Token("end", "", self.path, 1)
        self.declaring: list[str] = []  # names being #declared (objects take them)
        self.rand_streams: list[int] = []
        self.evaluated: set[int] = set()  # id() of lathe/sor keyword tokens read
        self.registry: list = []  # every lathe/sor ObjectNode read, in order
        #: len(registry) when the directive being run (not one nested in
        #: another) began: the objects of that statement follow.
        self.statement_registry = 0
        self.statement_directive = ""  # ... and its name (#declare, #include, ...)
        self._directive_depth = 0  # directives being run, nested
        tokens = self.read_file(self.path, None)
        self.frames.append(_Frame(tokens, 0, len(tokens), "file", where=self.path))

    # -- files ---------------------------------------------------------------

    def read_file(self, path: str, token: Token | None) -> list[Token]:
        if path in self._cache:
            return self._cache[path]
        try:
            with open(path, encoding="utf-8", errors="replace") as f:
                text = f.read(MAX_FILE_CHARS + 1)
        except OSError as e:
            where = f"{token.where}: " if token else ""
            raise PovError(f"{where}{path}: cannot read POV-Ray file ({e.strerror})") from None
        if len(text) > MAX_FILE_CHARS:
            raise PovError(f"{path}: file too large (over {MAX_FILE_CHARS:,} characters)")
        self._cache[path] = tokenize(text, path)
        self._lines[path] = text.count("\n") + 1
        self.files.append(path)
        return self._cache[path]

    def resolve_include(self, name: str, token: Token) -> str:
        """The file ``#include "name"`` reads, or a PovError: relative names
        only, found in the including file's folder, the scene's folder or an
        include folder, and never outside them."""
        if os.path.isabs(name) or ".." in name.replace("\\", "/").split("/"):
            raise self.error(f"#include \"{name}\": only files in the scene's folder or POV-Ray's "
                             f"include folders are read", token)
        here = os.path.dirname(os.path.realpath(token.path))
        folders = list(dict.fromkeys([here, self.root, *self.include_path]))
        for folder in folders:
            candidate = os.path.realpath(os.path.join(folder, name))
            allowed = [self.root, *[os.path.realpath(p) for p in self.include_path]]
            if not any(candidate == a or candidate.startswith(a + os.sep) for a in allowed):
                continue
            if os.path.isfile(candidate):
                return candidate
        raise self.error(f"#include \"{name}\": file not found in {', '.join(folders)}", token)

    # -- errors --------------------------------------------------------------

    def error(self, message: str, token: Token | None = None) -> PovError:
        token = token or self.last
        return PovError(f"{token.where}: {message}")

    # -- scopes --------------------------------------------------------------

    def lookup(self, name: str):
        for scope in reversed(self.scopes):
            if name in scope:
                return scope[name]
        return None

    def defined(self, name: str) -> bool:
        return any(name in scope for scope in self.scopes)

    def assign(self, name: str, value, local: bool) -> None:
        if local:
            self.scopes[-1][name] = value
            return
        for scope in reversed(self.scopes):
            if name in scope:
                scope[name] = value
                return
        self.globals[name] = value

    # -- reading -------------------------------------------------------------

    def next(self) -> Token:
        """The next token after directives and macro calls."""
        while True:
            if self.pushback:
                self.last = self.pushback.pop()
                return self.last
            token = self._raw()
            if token.kind == "end":
                self.last = token
                return token
            if token.kind == "directive":
                self.last = token
                self._directive(token)
                continue
            if token.kind == "word":
                value = self.lookup(token.text)
                if isinstance(value, Macro):
                    self.last = token
                    self._call(value, token)
                    continue
            self.last = token
            return token

    def peek(self) -> Token:
        token = self.next()
        self.pushback.append(token)
        return token

    def peek_soft(self) -> Token:
        """:meth:`peek`, but a directive next in the text is not run: a
        ``barrier`` token stands for it (an expression ends there)."""
        if not self.pushback and self.frames:
            frame = self.frames[-1]
            if frame.pos < frame.end:
                token = frame.tokens[frame.pos]
                if token.kind == "directive" or (token.kind == "word" and
                                                 isinstance(self.lookup(token.text), Macro)):
                    return Token("barrier", "", self.last.path, self.last.line)
        return self.peek()

    def push(self, token: Token) -> None:
        self.pushback.append(token)

    def take(self, text: str, what: str) -> Token:
        token = self.next()
        if token.text != text or token.kind in ("string", "end"):
            got = "the end of the file" if token.kind == "end" else repr(token.text)
            raise self.error(f"expected '{text}' {what}, got {got}", token)
        return token

    def _raw(self) -> Token:
        while self.frames:
            frame = self.frames[-1]
            if frame.pos < frame.end:
                token = frame.tokens[frame.pos]
                frame.pos += 1
                self.steps += 1
                if self.steps > MAX_STEPS:
                    raise self.error(f"more than {MAX_STEPS:,} tokens read: the scene is too long "
                                     f"or loops", token)
                return token
            self._pop_frame()
        return Token("end", "", self.path, self._lines.get(self.path, self.last.line))

    def _pop_frame(self) -> None:
        frame = self.frames.pop()
        while self.conds and self.conds[-1].frame is frame:
            cond = self.conds.pop()
            if cond.kind in ("while", "for", "if", "switch") and frame.kind != "dormant":
                self.notes.append(f"{frame.where}: #{cond.kind} not closed by #end")
        if frame.scope is not None and self.scopes and self.scopes[-1] is frame.scope:
            self.scopes.pop()

    def depth(self) -> tuple[int, int, int]:
        """The reader's state (frames, conditions, scopes), for :meth:`unwind`."""
        return len(self.frames), len(self.conds), len(self.scopes)

    def unwind(self, state: tuple[int, int, int]) -> None:
        """Back to a state of :meth:`depth` after an error: frames, open
        conditions and scopes opened since are dropped."""
        frames, conds, scopes = state
        self.pushback.clear()
        del self.frames[frames:]
        del self.conds[conds:]
        del self.scopes[scopes:]

    def run_dormant(self, tokens: list, start: int, end: int) -> None:
        """Read ``tokens[start:end]`` next (a block outside the rendered
        scene, read with the symbols as they are at the end)."""
        self.pushback.clear()
        self.frames.append(_Frame(tokens, start, end, "dormant", where=tokens[start].path))

    # -- skipping ------------------------------------------------------------

    def _skip(self, stops: tuple[str, ...], token: Token) -> Token:
        """Skip raw tokens of the current frame to the first directive of
        ``stops`` at this nesting level (``#end`` always stops); returns it."""
        frame = self.frames[-1]
        depth = 0
        while frame.pos < frame.end:
            t = frame.tokens[frame.pos]
            frame.pos += 1
            if t.kind != "directive":
                continue
            if t.text in _OPENERS:
                depth += 1
            elif t.text == "#end":
                if depth == 0:
                    return t
                depth -= 1
            elif depth == 0 and t.text in stops:
                return t
        raise self.error(f"{token.text} is not closed by #end", token)

    # -- directives ----------------------------------------------------------

    def _directive(self, token: Token) -> None:
        if self._directive_depth == 0:
            self.statement_registry = len(self.registry)
            self.statement_directive = token.text
        self._directive_depth += 1
        try:
            self._run_directive(token)
        finally:
            self._directive_depth -= 1

    def _run_directive(self, token: Token) -> None:
        from . import expressions as ex

        d = token.text
        if d in ("#declare", "#local"):
            self._declare(token, local=d == "#local")
        elif d == "#undef":
            name = self.next()
            for scope in reversed(self.scopes):
                if name.text in scope:
                    del scope[name.text]
                    break
        elif d in ("#if", "#ifdef", "#ifndef"):
            if d == "#if":
                taken = ex.truth(ex.parse_condition(self), token)
            else:
                self.take("(", f"after {d}")
                name = self.next()
                present = self.defined(name.text)
                value = self.lookup(name.text)
                while self.peek().text == "[":
                    self.next()
                    index = int(ex.as_float(ex.parse_expression(self, relational=True), token, "index"))
                    self.take("]", "to close the index")
                    if isinstance(value, PovArray) and 0 <= index < len(value.items):
                        value = value.items[index]
                        present = value is not None
                    else:
                        present, value = False, None
                self.take(")", f"to close {d}")
                taken = present == (d == "#ifdef")
            self._branch(taken, token)
        elif d == "#elseif" or d == "#else":
            cond = self._top_cond(token)
            if cond.kind == "switch":  # fall through into the next clause
                return
            self._skip((), token)
            self.conds.pop()
        elif d == "#switch":
            value = ex.parse_condition(self)
            self._switch(value, token)
        elif d in ("#case", "#range"):
            self._top_cond(token)
            ex.parse_condition(self) if d == "#case" else self._range_args()
        elif d == "#break":
            while self.conds and self.conds[-1].frame is self.frames[-1] and \
                    self.conds[-1].kind == "if":
                self._skip((), token)
                self.conds.pop()
            cond = self._top_cond(token)
            self._skip((), token)
            self.conds.pop()
            del cond
        elif d == "#end":
            self._end(token)
        elif d == "#while":
            taken = ex.truth(ex.parse_condition(self), token)
            if taken:
                self._count_iteration(token)
                self.conds.append(_Cond("while", self.frames[-1], self._directive_pos(token)))
            else:
                self._skip((), token)
        elif d == "#for":
            self._for(token)
        elif d == "#macro":
            self._define_macro(token)
        elif d == "#include":
            name = ex.parse_expression(self)
            if not isinstance(name, str):
                raise self.error("#include needs a file name string", token)
            if sum(f.kind == "include" for f in self.frames) >= MAX_INCLUDE_DEPTH:
                raise self.error(f"more than {MAX_INCLUDE_DEPTH} nested #include", token)
            path = self.resolve_include(name, token)
            tokens = self.read_file(path, token)
            self._push_frame(_Frame(tokens, 0, len(tokens), "include", where=path))
        elif d == "#version":
            ex.parse_expression(self)
            if self.peek_soft().text == ";":
                self.next()
        elif d in ("#debug", "#warning"):
            ex.parse_expression(self)
        elif d == "#error":
            message = ex.parse_expression(self)
            raise self.error(f"#error {message}", token)
        elif d == "#default":
            from .objects import skip_braces
            skip_braces(self, "#default")
        elif d == "#fopen":
            self.next()
            ex.parse_expression(self)
            self.next()
        elif d == "#fclose":
            self.next()
        elif d == "#write":
            self.take("(", "after #write")
            depth = 1
            while depth:
                t = self.next()
                if t.kind == "end":
                    raise self.error("#write is not closed", token)
                depth += {"(": 1, ")": -1}.get(t.text, 0) if t.kind == "symbol" else 0
        elif d == "#read":
            raise self.error("#read: reading data files is not supported", token)
        else:
            raise self.error(f"unknown directive {d}", token)

    def _push_frame(self, frame: _Frame) -> None:
        """Read ``frame`` next, before any token already looked ahead at."""
        if self.pushback:
            tokens = list(reversed(self.pushback))
            self.pushback.clear()
            self.frames.append(_Frame(tokens, 0, len(tokens), "pushback", where=tokens[0].path))
        self.frames.append(frame)

    def _directive_pos(self, token: Token) -> int:
        frame = self.frames[-1]
        k = frame.pos - 1
        while k >= 0 and frame.tokens[k] is not token:
            k -= 1
        return max(k, 0)

    def _count_iteration(self, token: Token) -> None:
        self.iterations += 1
        if self.iterations > MAX_ITERATIONS:
            raise self.error(f"more than {MAX_ITERATIONS:,} loop iterations in all", token)

    def _top_cond(self, token: Token) -> _Cond:
        if not self.conds or self.conds[-1].frame is not self.frames[-1]:
            raise self.error(f"{token.text} without a matching #if, #switch or loop", token)
        return self.conds[-1]

    def _branch(self, taken: bool, token: Token) -> None:
        from . import expressions as ex

        while not taken:
            stop = self._skip(("#else", "#elseif"), token)
            if stop.text == "#end":
                return
            if stop.text == "#else":
                break
            taken = ex.truth(ex.parse_condition(self), stop)
        self.conds.append(_Cond("if", self.frames[-1]))

    def _range_args(self) -> tuple[float, float]:
        from . import expressions as ex

        self.take("(", "after #range")
        lo = ex.parse_expression(self, relational=True)
        self.take(",", "in #range")
        hi = ex.parse_expression(self, relational=True)
        self.take(")", "to close #range")
        return lo, hi

    def _switch(self, value, token: Token) -> None:
        from . import expressions as ex

        value = ex.as_float(value, token, "#switch")
        while True:
            stop = self._skip(("#case", "#range", "#else"), token)
            if stop.text == "#end":
                return
            if stop.text == "#else":
                break
            if stop.text == "#case":
                c = ex.as_float(ex.parse_condition(self), stop, "#case")
                if abs(c - value) < 1e-10:
                    break
            else:
                lo, hi = self._range_args()
                if ex.as_float(lo, stop, "#range") <= value <= ex.as_float(hi, stop, "#range"):
                    break
        self.conds.append(_Cond("switch", self.frames[-1]))

    def _end(self, token: Token) -> None:
        from . import expressions as ex

        cond = self._top_cond(token)
        if cond.kind == "while":
            self.conds.pop()
            self.frames[-1].pos = cond.pos
        elif cond.kind == "for":
            value = ex.as_float(self.lookup(cond.var), token, "#for") + cond.step
            self.assign(cond.var, value, local=False)
            if (value <= cond.stop + 1e-12) if cond.step > 0 else (value >= cond.stop - 1e-12):
                self._count_iteration(token)
                self.frames[-1].pos = cond.pos
            else:
                self.conds.pop()
        else:
            self.conds.pop()

    def _for(self, token: Token) -> None:
        from . import expressions as ex

        self.take("(", "after #for")
        name = self.next().text
        self.take(",", "in #for")
        start = ex.as_float(ex.parse_expression(self, relational=True), token, "#for")
        self.take(",", "in #for")
        stop = ex.as_float(ex.parse_expression(self, relational=True), token, "#for")
        step = 1.0
        if self.peek().text == ",":
            self.next()
            step = ex.as_float(ex.parse_expression(self, relational=True), token, "#for")
        self.take(")", "to close #for")
        if step == 0:
            raise self.error("#for with a zero step", token)
        self.assign(name, start, local=False)
        if (start <= stop) if step > 0 else (start >= stop):
            self.conds.append(_Cond("for", self.frames[-1], self.frames[-1].pos, name, stop, step))
        else:
            self._skip((), token)

    def _define_macro(self, token: Token) -> None:
        frame = self.frames[-1]
        if frame.pos + 1 >= frame.end or frame.tokens[frame.pos].kind != "word":
            raise self.error("#macro: expected a name and a parameter list", token)
        name = frame.tokens[frame.pos].text
        frame.pos += 1
        params: list[str] = []
        if frame.tokens[frame.pos].text != "(":
            raise self.error(f"#macro {name}: expected '(' after the name", token)
        frame.pos += 1
        while frame.pos < frame.end and frame.tokens[frame.pos].text != ")":
            t = frame.tokens[frame.pos]
            if t.kind == "word":
                params.append(t.text)
            frame.pos += 1
        if frame.pos >= frame.end:
            raise self.error(f"#macro {name}: parameter list not closed", token)
        frame.pos += 1
        start = frame.pos
        end_token = self._skip((), token)
        del end_token
        self.assign(name, Macro(name, params, frame.tokens, start, frame.pos - 1, token.where),
                    local=False)

    def _call(self, macro: Macro, token: Token) -> None:
        from . import expressions as ex

        if sum(f.kind == "macro" for f in self.frames) >= MAX_MACRO_DEPTH:
            raise self.error(f"more than {MAX_MACRO_DEPTH} nested macro calls", token)
        args: list = []
        if macro.params or self.peek().text == "(":
            self.take("(", f"after the macro name {macro.name}")
            if self.peek().text != ")":
                while True:
                    args.append(ex.parse_value(self))
                    if self.peek().text != ",":
                        break
                    self.next()
            self.take(")", f"to close the arguments of {macro.name}")
        if len(args) != len(macro.params):
            raise self.error(f"macro {macro.name} (of {macro.where}) takes {len(macro.params)} "
                             f"arguments, got {len(args)}", token)
        scope = dict(zip(macro.params, args, strict=True))
        self.scopes.append(scope)
        self._push_frame(_Frame(macro.tokens, macro.start, macro.end, "macro", scope,
                                where=macro.where))

    def _declare(self, token: Token, local: bool) -> None:
        from . import expressions as ex

        name_token = self.next()
        if name_token.kind != "word":
            raise self.error(f"{token.text}: expected a name, got {name_token.text!r}", name_token)
        name = name_token.text
        indices: list[int] = []
        while self.peek().text == "[":
            self.next()
            indices.append(int(ex.as_float(ex.parse_expression(self, relational=True), token, "index")))
            self.take("]", "to close the index")
        self.take("=", f"after {token.text} {name}")
        self.declaring.append(name)
        try:
            value = ex.parse_value(self)
        finally:
            self.declaring.pop()
        if self.peek_soft().text == ";":
            self.next()
        if indices:
            array = self.lookup(name)
            if not isinstance(array, PovArray):
                raise self.error(f"{name} is not an array", name_token)
            ex.set_element(self, array, indices, value, name_token)
        else:
            self.assign(name, value, local)
