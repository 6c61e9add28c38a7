"""``mutloc markers``: the rig's tags and banded cylinders as a PDF to print at their physical size."""

from __future__ import annotations

import argparse

from ._common import RIG

ORDER = 48


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``markers``."""
    p = subparsers.add_parser(
        "markers", parents=[RIG],
        help="draw the rig's tags and banded cylinders at their physical size (PDF, A4 pages)",
        description=(
            "Writes a PDF of A4 pages with every tag of the rig (the square whose corners are the tag's corners "
            "measures its 'size') and the sheet that wraps each banded cylinder (2 pi radius by height, the top "
            "band first, with a glue flap), each with its name, and a 10 cm bar on every page. Print at 100 % "
            "(actual size, no 'fit to page') and measure the bar. Balls and lights are not printable; a rig "
            "with nothing printable is refused."
        ),
    )
    p.add_argument("--out", required=True, metavar="SHEET.pdf", help="the PDF to write")
    return p


def run(args: argparse.Namespace) -> int:
    """Load the rig, draw its printable markers, say what was written."""
    from pathlib import Path

    from ..io import load_rig
    from ..io.marker_sheet import write_marker_sheet

    summary = write_marker_sheet(load_rig(args.rig), args.out, title=Path(args.rig).name)
    print(summary.line())
    return 0
