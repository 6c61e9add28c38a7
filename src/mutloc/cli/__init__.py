"""The ``mutloc`` command line.

Each subcommand is a module ``mutloc.cli.<name>`` (names starting with ``_``
and ``main`` excepted) that defines:

- ``add_parser(subparsers) -> argparse.ArgumentParser``: adds its parser with
  ``subparsers.add_parser("<command>", help=..., description=...)`` and returns it;
- ``run(args: argparse.Namespace) -> int``: does the work; returns the exit status;
- optionally ``ORDER: int``: position in ``mutloc --help`` (lower first, default 100).

:func:`mutloc.cli.main.main` finds these modules by itself, so adding a command
means adding one file.  Keep heavy imports inside ``run``.  ``run`` raises
:class:`mutloc.errors.MutlocError` for a user's mistake; ``main`` prints it as
one line ``mutloc: error: <message>`` and exits with status 2.  Shared
argument types are in :mod:`mutloc.cli._common`.
"""

from __future__ import annotations

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Run the command line; see :func:`mutloc.cli.main.main`."""
    from .main import main as _main

    return _main(argv)
