"""``mutloc markers``: the printed sheet measured in the PDF itself.

The PDF's page content is parsed here (its streams inflated with zlib, its
path operators read), independently of matplotlib: every black fill's
extent in points gives the printed size in millimetres, and the cells of a
printed tag are compared with OpenCV's own image of that marker.
"""

from __future__ import annotations

import re
import zlib

import cv2
import numpy as np
import pytest
import yaml

from mutloc.cli.main import main

PT_PER_MM = 72.0 / 25.4
A4_PT = (210.0 * PT_PER_MM, 297.0 * PT_PER_MM)
CAM = {"K": [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]], "size": [640, 480]}


def _pages(pdf: bytes) -> list[tuple[list[float], bytes]]:
    """(MediaBox, inflated content stream) of every page, in order."""
    objects = {int(n): body for n, body in re.findall(rb"(\d+) 0 obj(.*?)endobj", pdf, re.S)}
    pages = []
    for body in objects.values():
        if re.search(rb"/Type\s*/Page\b", body):
            box = [float(v) for v in re.search(rb"/MediaBox\s*\[([^\]]*)\]", body).group(1).split()]
            content = objects[int(re.search(rb"/Contents\s+(\d+)\s+0\s+R", body).group(1))]
            raw = re.search(rb"stream\r?\n(.*)\r?\nendstream", content, re.S).group(1)
            pages.append((box, zlib.decompress(raw)))
    return pages


def _black_fills(content: bytes) -> list[list[np.ndarray]]:
    """The paths filled in black: each a list of subpaths (k, 2) in points (PDF y up)."""
    fills, subpaths, pts, stack, grey = [], [], [], [], 1.0
    text = re.sub(rb"BT.*?ET", b"", content, flags=re.S)  # no text operators
    for tok in text.split():
        if re.fullmatch(rb"[-+]?[\d.]+", tok):
            stack.append(float(tok))
            continue
        op = tok.decode("latin1")
        if op == "g":
            grey = stack[-1]
        elif op == "rg":
            grey = 1.0 if stack[-3:] != [0.0, 0.0, 0.0] else 0.0
        elif op in ("m", "l"):
            if op == "m" and pts:
                subpaths.append(np.array(pts))
                pts = []
            pts.append(stack[-2:])
        elif op == "re":
            x, y, w, h = stack[-4:]
            if pts:
                subpaths.append(np.array(pts))
            subpaths.append(np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]]))
            pts = []
        elif op in ("f", "f*", "B", "B*", "S", "n"):
            if pts:
                subpaths.append(np.array(pts))
            if op.startswith(("f", "B")) and grey == 0.0 and subpaths:
                fills.append(subpaths)
            subpaths, pts = [], []
        stack = []
    return fills


def _extent_mm(subpaths: list[np.ndarray]) -> tuple[float, float, float, float]:
    """(left, top, width, height) in mm from the top-left corner of an A4 page."""
    p = np.vstack(subpaths)
    lo, hi = p.min(axis=0), p.max(axis=0)
    return lo[0] / PT_PER_MM, (A4_PT[1] - hi[1]) / PT_PER_MM, (hi[0] - lo[0]) / PT_PER_MM, (hi[1] - lo[1]) / PT_PER_MM


def _cells(subpaths: list[np.ndarray], n: int) -> np.ndarray:
    """Which of the n x n cells of the path's extent are black (cell centre inside a subpath's box)."""
    p = np.vstack(subpaths)
    lo, hi = p.min(axis=0), p.max(axis=0)
    c = (hi - lo) / n
    out = np.zeros((n, n), bool)
    for i in range(n):  # row 0 at the top (PDF y up)
        for j in range(n):
            x, y = lo[0] + (j + 0.5) * c[0], hi[1] - (i + 0.5) * c[1]
            out[i, j] = any(s[:, 0].min() < x < s[:, 0].max() and s[:, 1].min() < y < s[:, 1].max() for s in subpaths)
    return out


def _rig(tmp_path, markers_p: dict, markers_q: dict) -> str:
    d = {"robots": {"p": {"camera": CAM, "markers": markers_p}, "q": {"camera": CAM, "markers": markers_q}}}
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(d))
    return str(path)


def test_printed_tags_and_bands_have_their_physical_size(tmp_path, capsys):
    code = [1, 0, 1, 1, 0]
    rig = _rig(tmp_path,
               {"T": {"position": [0.1, 0.0, 0.0], "tag": {"family": "tag36h11", "id": 7, "size": 0.06}},
                "B": {"position": [-0.1, 0.0, 0.0], "color": [255, 0, 0]}},
               {"A": {"position": [0.1, 0.0, 0.0], "tag": {"family": "4x4_50", "id": 3, "size": 0.045}},
                "C": {"position": [0.0, 0.1, 0.0], "cylinder": {"radius": 0.02, "height": 0.08, "code": code}}})
    out = tmp_path / "sheet.pdf"
    assert main(["markers", "--rig", rig, "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert "2 tag(s), 1 cylinder(s)" in said and "p / B (ball)" in said
    pages = _pages(out.read_bytes())
    assert len(pages) == 1
    box, content = pages[0]
    assert box[2:] == pytest.approx(A4_PT, abs=0.5)
    fills = sorted((_extent_mm(f), f) for f in _black_fills(content))
    # two tags, three dark bands, the scale bar
    assert len(fills) == 6, [e for e, _ in fills]
    sizes = [(round(w, 1), round(h, 1)) for (_, _, w, h), _ in fills]
    # the scale bar: 10 cm
    bar = [e for e, _ in fills if e[3] < 3.0]
    assert len(bar) == 1 and bar[0][2] == pytest.approx(100.0, abs=0.5)
    # each tag: the black square measures the rig's size, cells as OpenCV draws the marker
    for size_mm, dictionary, tid, n in ((60.0, cv2.aruco.DICT_APRILTAG_36h11, 7, 8),
                                        (45.0, cv2.aruco.DICT_4X4_50, 3, 6)):
        found = [f for (x, y, w, h), f in fills if abs(w - size_mm) < 0.5 and abs(h - size_mm) < 0.5]
        assert len(found) == 1, (size_mm, sizes)
        want = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(dictionary), tid, n, borderBits=1)
        np.testing.assert_array_equal(_cells(found[0], n), want < 128)
    # the cylinder: dark bands 0, 2, 3 (top first), 2 pi r wide, h / 5 tall each, stacked
    bands = sorted(e for e, _ in fills if abs(e[2] - 2 * np.pi * 20.0) < 0.5)
    assert len(bands) == 3, sizes
    top = bands[0][1]
    for (x, y, w, h), k in zip(bands, (0, 2, 3)):
        assert h == pytest.approx(16.0, abs=0.5)
        assert y - top == pytest.approx(16.0 * k, abs=0.5)
        assert x == pytest.approx(bands[0][0], abs=1e-6)


def test_wide_cylinder_is_turned_or_cut_to_fit(tmp_path, capsys):
    """A strip longer than the page is wide runs down the page; one longer than that is cut into pieces."""
    rig = _rig(tmp_path, {"C": {"position": [0, 0, 0], "cylinder": {"radius": 0.035, "height": 0.05, "code": [1, 0]}}},
               {"D": {"position": [0, 0, 0], "cylinder": {"radius": 0.06, "height": 0.05, "code": [0, 1]}}})
    out = tmp_path / "sheet.pdf"
    assert main(["markers", "--rig", rig, "--out", str(out)]) == 0
    capsys.readouterr()
    fills = [_extent_mm(f) for _, content in _pages(out.read_bytes()) for f in _black_fills(content)]
    turned = [e for e in fills if abs(e[3] - 2 * np.pi * 35.0) < 0.5]
    assert len(turned) == 1 and turned[0][2] == pytest.approx(25.0, abs=0.5)
    pieces = [e for e in fills if abs(e[3] - 25.0) < 0.5 and e[2] < 186]
    assert len(pieces) >= 2 and sum(e[2] for e in pieces) == pytest.approx(2 * np.pi * 60.0, abs=0.5)


@pytest.mark.parametrize("markers, out, message", [
    ({"B": {"position": [0, 0, 0], "color": [255, 0, 0]}}, "sheet.pdf", "nothing printable"),
    ({"T": {"position": [0, 0, 0], "tag": {"family": "tag36h11", "id": 1, "size": 0.3}}}, "sheet.pdf",
     "does not fit"),
    ({"T": {"position": [0, 0, 0], "tag": {"family": "tag36h11", "id": 1, "size": 0.05}}}, "sheet.png", ".pdf"),
], ids=["balls-only", "too-big", "not-pdf"])
def test_refusals_are_one_line(tmp_path, capsys, markers, out, message):
    rig = _rig(tmp_path, markers, {"L": {"position": [0, 0, 0], "color": [0, 255, 0], "blink_hz": 5.0}})
    assert main(["markers", "--rig", rig, "--out", str(tmp_path / out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mutloc: error:") and message in err and err.count("\n") == 1
    assert not (tmp_path / out).exists()
