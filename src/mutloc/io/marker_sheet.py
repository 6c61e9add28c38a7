"""Printable markers: a rig's tags and banded cylinders at their physical size, as a PDF.

Every page is A4 (210 x 297 mm) at scale 1:1.  A tag is its card as the
renderer draws it (:func:`mutloc.sim.world.tag_image`: the code, the border
and a white quiet zone of :data:`~mutloc.sim.world.TAG_MARGIN_CELLS` cell),
black cells as vector rectangles, so the square whose corners are the tag's
corners measures the rig's ``size``.  A banded cylinder is the sheet that
wraps it: ``2 pi radius`` wide, ``height`` tall, ``len(code)`` equal bands,
``code[0]`` at the top, bit 1 black; a grey glue flap on its right (a strip
wider than the page runs down it, top band at the left; one longer than the
page is tall is cut into pieces, each with its flap).  Each item has
its name under it and each page a 10 cm bar to check that the printer kept the
scale.  Balls, lights and plain points are not printable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._extras import require
from ..core.rig import Marker, MarkerKind, Rig
from ..errors import InputError

__all__ = ["PAGE_MM", "SCALE_BAR_MM", "SheetSummary", "write_marker_sheet"]

PAGE_MM = (210.0, 297.0)  # A4 portrait
SCALE_BAR_MM = 100.0
_MARGIN = 12.0  # mm around the page
_TOP = 18.0  # below the header
_BOTTOM = 24.0  # above the scale bar
_GAP = 6.0  # between items
_CAPTION = 6.5  # mm of caption (two lines) under an item
_CAPTION_PT = 5.5
_CHAR_MM = 1.0  # width of a caption character at _CAPTION_PT, rounded up
_FLAP = 10.0  # glue flap of a cylinder strip
_CUT_GREY = "0.6"
_MM_PER_M = 1000.0


@dataclass
class SheetSummary:
    """What :func:`write_marker_sheet` printed."""

    path: Path
    pages: int
    tags: list[str] = field(default_factory=list)
    cylinders: list[str] = field(default_factory=list)
    not_printable: list[str] = field(default_factory=list)

    def line(self) -> str:
        """One line for the command's output."""
        parts = [f"wrote {self.path}: {len(self.tags)} tag(s), {len(self.cylinders)} cylinder(s) on "
                 f"{self.pages} A4 page(s); print at 100 % (actual size) and check the 10 cm bar"]
        if self.not_printable:
            parts.append(f"not printable: {', '.join(self.not_printable)}")
        return "; ".join(parts)


@dataclass
class _Item:
    """One rectangle to place: ``draw(ax, x, y)`` draws it with its top-left corner at (x, y) mm."""

    width: float
    height: float
    caption: str
    draw: Any

    @property
    def footprint(self) -> float:
        """Width on the page, the caption's included."""
        return max(self.width, _CHAR_MM * max(len(line) for line in self.caption.splitlines()))


def _label(robot: str, marker: Marker) -> str:
    return f"{robot} / {marker.name}"


def _tag_items(robot: str, marker: Marker) -> list[_Item]:
    from ..detect.tags import tag_cells, tag_spec
    from ..sim.world import tag_image

    family, tid, size = tag_spec(marker)
    img = tag_image(family, tid) > 127  # white cells
    cell = size * _MM_PER_M / tag_cells(family)
    side = img.shape[0] * cell

    def draw(ax: Any, x: float, y: float) -> None:
        from matplotlib.patches import PathPatch, Rectangle
        from matplotlib.path import Path as MplPath

        verts, codes = [], []
        for i, row in enumerate(~img):  # runs of black cells, row by row
            j = 0
            while j < len(row):
                if not row[j]:
                    j += 1
                    continue
                k = j
                while k < len(row) and row[k]:
                    k += 1
                x0, x1, y0, y1 = x + j * cell, x + k * cell, y + i * cell, y + (i + 1) * cell
                verts += [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
                codes += [MplPath.MOVETO, MplPath.LINETO, MplPath.LINETO, MplPath.LINETO, MplPath.CLOSEPOLY]
                j = k
        ax.add_patch(PathPatch(MplPath(verts, codes), facecolor="black", edgecolor="none", linewidth=0))
        ax.add_patch(Rectangle((x, y), side, side, fill=False, edgecolor=_CUT_GREY, linewidth=0.3))

    caption = f"{_label(robot, marker)}\n{family} #{tid}, size {size * _MM_PER_M:g} mm"
    return [_Item(side, side, caption, draw)]


def _cylinder_items(robot: str, marker: Marker, max_width: float, max_height: float) -> list[_Item]:
    from ..sim.world import cylinder_spec

    radius, height, code = cylinder_spec(marker)
    circ, h = 2.0 * math.pi * radius * _MM_PER_M, height * _MM_PER_M
    band = h / len(code)
    bits = " ".join(str(int(b)) for b in code)
    name = f"{_label(robot, marker)}: cylinder r {radius * _MM_PER_M:g} mm, h {h:g} mm"
    if circ + _FLAP > max_width and circ + _FLAP <= max_height and h <= max_width:
        # Turned a quarter: the strip runs down the page, the top band at the left.

        def draw_turned(ax: Any, x: float, y: float) -> None:
            from matplotlib.patches import Rectangle

            for i, b in enumerate(code):
                if b:
                    ax.add_patch(Rectangle((x + i * band, y), band, circ, facecolor="black", edgecolor="none",
                                           linewidth=0))
            ax.add_patch(Rectangle((x, y), h, circ, fill=False, edgecolor=_CUT_GREY, linewidth=0.3))
            ax.add_patch(Rectangle((x, y + circ), h, _FLAP, facecolor="0.85", edgecolor=_CUT_GREY, linewidth=0.3))
            ax.text(x + 0.5 * h, y + circ + 0.5 * _FLAP, "glue", ha="center", va="center", fontsize=6, color="0.4")

        return [_Item(h, circ + _FLAP, f"{name}\nbands from the left (the top) on: {bits}", draw_turned)]
    pieces = max(1, math.ceil(circ / (max_width - _FLAP)))
    w = circ / pieces
    items = []
    for k in range(pieces):

        def draw(ax: Any, x: float, y: float) -> None:
            from matplotlib.patches import Rectangle

            for i, b in enumerate(code):  # code[0] is the top band
                if b:
                    ax.add_patch(Rectangle((x, y + i * band), w, band, facecolor="black", edgecolor="none",
                                           linewidth=0))
            ax.add_patch(Rectangle((x, y), w, h, fill=False, edgecolor=_CUT_GREY, linewidth=0.3))
            ax.add_patch(Rectangle((x + w, y), _FLAP, h, facecolor="0.85", edgecolor=_CUT_GREY, linewidth=0.3))
            ax.text(x + w + 0.5 * _FLAP, y + 0.5 * h, "glue", rotation=90, ha="center", va="center", fontsize=6,
                    color="0.4")

        piece = f", piece {k + 1} of {pieces}" if pieces > 1 else ""
        items.append(_Item(w + _FLAP, h, f"{name}{piece}\nbands from the top on: {bits}", draw))
    return items


def _items(rig: Rig) -> tuple[list[_Item], list[str], list[str], list[str]]:
    width = PAGE_MM[0] - 2 * _MARGIN
    height = PAGE_MM[1] - _TOP - _BOTTOM - _CAPTION
    items: list[_Item] = []
    tags, cylinders, other = [], [], []
    for rname, robot in rig.robots.items():
        for marker in robot.markers.values():
            kind = marker.kind
            if kind == MarkerKind.TAG:
                new = _tag_items(rname, marker)
                tags.append(_label(rname, marker))
            elif kind == MarkerKind.CYLINDER:
                new = _cylinder_items(rname, marker, width, height)
                cylinders.append(_label(rname, marker))
            else:
                if kind not in (MarkerKind.TAG_CORNER, MarkerKind.CYLINDER_BAND):  # printed with their parent
                    other.append(f"{_label(rname, marker)} ({kind.value})")
                continue
            for it in new:
                if it.width > width or it.height > height:
                    raise InputError(f"marker {marker.name!r} of robot {rname!r}: {it.width:.0f} x "
                                     f"{it.height:.0f} mm does not fit on an A4 page ({width:.0f} x "
                                     f"{height:.0f} mm printable)")
            items += new
    return items, tags, cylinders, other


def _pack(items: list[_Item]) -> list[list[tuple[_Item, float, float]]]:
    """Shelves, left to right and top to bottom, in the rig's order: pages of (item, x, y)."""
    x_max, y_max = PAGE_MM[0] - _MARGIN, PAGE_MM[1] - _BOTTOM
    pages: list[list[tuple[_Item, float, float]]] = [[]]
    x, y, shelf = _MARGIN, _TOP, 0.0
    for it in items:
        if x + it.footprint > x_max + 1e-9 and x > _MARGIN:  # next shelf
            x, y, shelf = _MARGIN, y + shelf + _GAP, 0.0
        if y + it.height + _CAPTION > y_max + 1e-9:  # next page
            pages.append([])
            x, y, shelf = _MARGIN, _TOP, 0.0
        pages[-1].append((it, x, y))
        x += it.footprint + _GAP
        shelf = max(shelf, it.height + _CAPTION)
    return pages


def _scale_bar(ax: Any) -> None:
    from matplotlib.patches import Rectangle

    x, y = _MARGIN, PAGE_MM[1] - _MARGIN - 2.0
    ax.add_patch(Rectangle((x, y), SCALE_BAR_MM, 2.0, facecolor="black", edgecolor="none", linewidth=0))
    for cm in range(11):
        ax.plot([x + 10 * cm, x + 10 * cm], [y - (3.0 if cm % 5 == 0 else 1.5), y], color="black", linewidth=0.4)
    ax.text(x + SCALE_BAR_MM + 3, y + 1.0, "10 cm: measure it to check the printer kept the scale",
            va="center", fontsize=7)


def write_marker_sheet(rig: Rig, path: str | Path, *, title: str = "") -> SheetSummary:
    """Draw ``rig``'s tags and banded cylinders at their exact size on A4 pages of a PDF at ``path``.

    :class:`InputError` when the rig has nothing printable, a marker does not
    fit on a page, or ``path`` is not a ``.pdf``.
    """
    path = Path(path)
    if path.suffix.lower() != ".pdf":
        raise InputError(f"the marker sheet is a PDF: {path} does not end in .pdf")
    items, tags, cylinders, other = _items(rig)
    if not items:
        raise InputError("the rig has nothing printable (tags or banded cylinders)"
                         + (f": its markers are {', '.join(other)}" if other else ""))
    require("matplotlib", "the marker sheet")
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    pages = _pack(items)
    mm = 1.0 / 25.4
    with PdfPages(path) as pdf:
        for n, page in enumerate(pages, 1):
            fig = Figure(figsize=(PAGE_MM[0] * mm, PAGE_MM[1] * mm))
            ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
            ax.set_xlim(0.0, PAGE_MM[0])
            ax.set_ylim(PAGE_MM[1], 0.0)  # mm from the top-left corner of the page
            ax.set_axis_off()
            head = f"mutloc markers{': ' + title if title else ''} -- page {n} of {len(pages)} -- print at 100 %"
            ax.text(_MARGIN, _MARGIN, head, va="center", fontsize=8)
            for it, x, y in page:
                it.draw(ax, x, y)
                ax.text(x, y + it.height + 1.0, it.caption, va="top", fontsize=_CAPTION_PT, linespacing=1.2)
            _scale_bar(ax)
            pdf.savefig(fig)
    return SheetSummary(path, len(pages), tags, cylinders, other)
