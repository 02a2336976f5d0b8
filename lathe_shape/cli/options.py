"""The commands' option convention: ``-o/--output``, ``--spp``,
``--resolution``, ``--seed``, ``--variant`` and ``-D`` (see
:mod:`.common`), their parsing and their range checks."""

from __future__ import annotations

import argparse

from .errors import CliError

__all__ = [
    "DEFAULT_VARIANT",
    "UINT32_MAX",
    "add_output_option",
    "add_render_options",
    "check_at_least",
    "check_between",
    "check_render_options",
    "command_parser",
    "parse_defines",
    "parse_resolution",
]


#: The variant every command uses unless ``--variant`` says otherwise.
DEFAULT_VARIANT = "llvm_ad_rgb"


#: Largest sample count and seed (Mitsuba passes both as 32-bit unsigned).
UINT32_MAX = 2**32 - 1


def command_parser(prog: str, description: str,
                   scene_help: str = "Mitsuba XML scene file") -> argparse.ArgumentParser:
    """The parser of a command that takes one scene file as its first argument."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("scene", help=scene_help)
    return parser


def add_output_option(parser: argparse.ArgumentParser, default: str | None = "out", what: str = "",
                      default_help: str | None = None) -> None:
    """``-o/--output DIR``: the folder for everything the command writes.

    ``default_help`` describes a default the command computes itself (e.g.
    from the scene's name): the option is then optional, ``None`` when not
    given, whatever ``default`` says."""
    if default_help is not None:
        default, where = None, f"default: {default_help}"
    else:
        where = f"default: {default}" if default else "required"
    parser.add_argument(
        "-o", "--output", metavar="DIR", default=default,
        required=default is None and default_help is None,
        help=f"output folder, created if missing{': ' + what if what else ''} ({where})",
    )


def add_render_options(parser: argparse.ArgumentParser, seed_help: str = "sampler seed (default: 0)",
                       spp_default: int | None = None, resolution_default: str | None = None,
                       defines: bool = True, seed_default: int = 0, spp_help: str | None = None,
                       resolution_help: str | None = None) -> None:
    """``--spp``, ``--resolution``, ``--seed``, ``--variant`` and (unless
    ``defines`` is False, for scenes built in Python) ``-D``. ``spp_help`` and
    ``resolution_help`` replace the default named in the help text (for
    commands that choose their own defaults)."""
    spp_help = spp_help or spp_default or "the scene's sampler"
    size_help = resolution_help or resolution_default or "the scene's film"
    parser.add_argument("--spp", type=int, default=spp_default,
                        help=f"samples per pixel (default: {spp_help})")
    parser.add_argument("--resolution", metavar="WxH", default=resolution_default,
                        help=f"film resolution, e.g. 640x480, or 512 for a square (default: {size_help})")
    parser.add_argument("--seed", type=int, default=seed_default, help=seed_help)
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help=f"Mitsuba variant (default: {DEFAULT_VARIANT})")
    if defines:
        parser.add_argument(
            "-D", dest="defines", action="append", metavar="KEY=VALUE",
            help="set an XML <default> parameter, e.g. -D integrator=lathe_path (repeatable)",
        )


def _number(value: float) -> str:
    """``value`` as the user would write it (``%g`` for floats; integers in
    full: ``%g`` of an integer beyond the float range raises OverflowError)."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def check_at_least(option: str, value: float | None, minimum: float) -> None:
    """Raise :class:`CliError` unless ``value`` (when given) is >= ``minimum``."""
    if value is not None and not value >= minimum:
        raise CliError(f"{option} must be at least {_number(minimum)}, got {_number(value)}")


def check_between(option: str, value: float | None, minimum: float, maximum: float) -> None:
    """Raise :class:`CliError` unless ``value`` (when given) is in
    [``minimum``, ``maximum``]."""
    check_at_least(option, value, minimum)
    if value is not None and not value <= maximum:
        raise CliError(f"{option} must be at most {_number(maximum)}, got {_number(value)}")


def parse_defines(items: list[str] | None) -> dict[str, str]:
    """``["key=value", ...]`` (the ``-D`` options) -> dict."""
    defines: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CliError(f"-D expects key=value, got {item!r}")
        defines[key.strip()] = value
    return defines


def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` or ``"N"`` (square) -> (width, height)."""
    parts = text.lower().split("x")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2:
        raise CliError(f"--resolution must look like 640x480 or 512, got {text!r}")
    if min(values) < 1:
        raise CliError(f"--resolution needs a width and a height of at least 1 pixel, got {text!r}")
    if max(values) > UINT32_MAX:
        raise CliError(f"--resolution {text!r} is too large: at most {UINT32_MAX} pixels a side")
    return values[0], values[1]


def check_render_options(args: argparse.Namespace) -> None:
    """Check the options of :func:`add_render_options` before anything is
    loaded: ``--spp`` and ``--seed`` in their 32-bit ranges, the syntax of
    ``--resolution`` and of each ``-D``. Raises :class:`CliError` naming the
    option."""
    check_between("--spp", args.spp, 1, UINT32_MAX)
    check_between("--seed", args.seed, 0, UINT32_MAX)
    if args.resolution is not None:
        parse_resolution(args.resolution)
    parse_defines(getattr(args, "defines", None))
