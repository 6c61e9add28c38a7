"""Entry point of the ``mutloc`` command (``mutloc.cli.main:main``)."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
from types import ModuleType

from ..errors import MutlocError

__all__ = ["main", "build_parser", "command_modules", "check_extras", "NEEDS"]

PROG = "mutloc"
EXIT_USER_ERROR = 2


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("mutloc")
    except Exception:  # noqa: BLE001 -- not installed: still usable from a checkout
        return "unknown"


def command_modules() -> list[ModuleType]:
    """The subcommand modules of :mod:`mutloc.cli` (see its docstring), in help order."""
    from . import __name__ as pkg_name, __path__ as pkg_path

    mods = []
    for info in pkgutil.iter_modules(pkg_path):
        if info.name.startswith("_") or info.name == "main":
            continue
        mod = importlib.import_module(f"{pkg_name}.{info.name}")
        if callable(getattr(mod, "add_parser", None)) and callable(getattr(mod, "run", None)):
            mods.append(mod)
    mods.sort(key=lambda m: (getattr(m, "ORDER", 100), m.__name__))
    return mods


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Mutual localization: relative 6-DOF pose of two cameras from reciprocal "
        "fiducial observations.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(title="commands", dest="command", metavar="COMMAND", required=True)
    for mod in command_modules():
        p = mod.add_parser(sub)
        if p is None:
            raise RuntimeError(f"{mod.__name__}.add_parser must return the parser it added")
        p.set_defaults(_run=mod.run)
    return parser


#: What a command, or one of its options, needs beyond the core install:
#: (command, option's dest -- when given -- or None for the command itself, optional packages,
#: extra to name or None for each package's own; see mutloc._extras).
#: Checked before the command starts, so it fails at once, not after the work.
NEEDS: tuple[tuple[str, str | None, tuple[str, ...], str | None], ...] = (
    ("track", "topic", ("rosbags",), None),  # a stream from a ROS bag
    ("track", "camera_info", ("rosbags",), None),
    ("track", "bag", ("rosbags",), None),
    ("track", "mcap", ("mcap", "rosbags"), None),
    ("track", "rerun", ("rerun",), None),
    ("track", "annotate", ("av",), None),
    ("experiment", None, ("matplotlib", "pycolmap"), "experiments"),
    ("demo", None, ("matplotlib", "av"), None),
    ("demo", "live", ("cyclonedds",), "live"),
    ("node", None, ("cyclonedds",), "live"),
    ("node", "topic", ("rosbags",), None),  # a recorded bag replayed as the camera
    ("localizer", None, ("cyclonedds",), "live"),
)


def check_extras(args: argparse.Namespace) -> None:
    """:class:`~mutloc.errors.MissingExtraError` for the first package
    :data:`NEEDS` asks of the parsed command line that is not installed."""
    from .._extras import require

    for command, dest, modules, extra in NEEDS:
        if args.command != command or (dest is not None and not getattr(args, dest, None)):
            continue
        what = f"mutloc {command}" + ("" if dest is None else f" --{dest.replace('_', '-')}")
        for module in modules:
            require(module, what, extra)


def _error(message: object) -> int:
    text = " ".join(str(message).split()) or "unknown error"
    print(f"{PROG}: error: {text}", file=sys.stderr)
    return EXIT_USER_ERROR


def main(argv: list[str] | None = None) -> int:
    """Run ``mutloc`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status.

    A user's mistake (:class:`MutlocError`, or an OSError such as an unwritable
    output file) prints one line ``mutloc: error: <message>`` on stderr and
    returns 2; argparse usage errors exit with status 2 as usual.  Ctrl-C
    and SIGTERM stop every command the same way (see :mod:`mutloc.signals`):
    what is finished is written, and the status is 130.
    """
    from ..signals import sigterm_as_interrupt

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        check_extras(args)
        with sigterm_as_interrupt():
            status = args._run(args)
    except MutlocError as exc:
        return _error(exc if str(exc) else type(exc).__name__)
    except OSError as exc:
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        return _error(f"{where}{exc.strerror or exc}")
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    return int(status or 0)


if __name__ == "__main__":
    sys.exit(main())
