"""Tag families and a rig's tag specifications: names, cell counts, id counts, OpenCV dictionaries.

What :mod:`mutloc.detect.tags` (the detector), the renderer and the marker sheets share about a printed
tag without detecting anything.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from ..core.rig import Marker
from ..errors import RigError
from . import apriltag_lib

__all__ = ["aruco_dictionary", "canonical_family", "has_aruco_dictionary", "tag_cells", "tag_id_count", "tag_library",
           "tag_spec"]

# The AprilTag library's families in lower case -> its spelling.
_APRILTAG = {f.lower(): f for f in apriltag_lib.APRILTAG_FAMILIES}

# Canonical family name -> cv2.aruco predefined dictionary attribute.
_DICTIONARIES: dict[str, str] = {
    "tag16h5": "DICT_APRILTAG_16h5",
    "tag25h9": "DICT_APRILTAG_25h9",
    "tag36h10": "DICT_APRILTAG_36h10",
    "tag36h11": "DICT_APRILTAG_36h11",
    "aruco_original": "DICT_ARUCO_ORIGINAL",
    "aruco_mip_36h12": "DICT_ARUCO_MIP_36h12",
}
for _bits in (4, 5, 6, 7):
    for _n in (50, 100, 250, 1000):
        _DICTIONARIES[f"{_bits}x{_bits}_{_n}"] = f"DICT_{_bits}X{_bits}_{_n}"


# ---------------------------------------------------------------------------
# families
# ---------------------------------------------------------------------------


def canonical_family(family: Any) -> str:
    """The canonical spelling of a tag family name, or :class:`RigError`.

    Accepts AprilTag names (``tag36h11``, ``apriltag_36h11``, ``36h11``,
    ``DICT_APRILTAG_36h11``, ``tagStandard41h12``, ``Standard52h13``) and
    ArUco names (``4x4_50``, ``aruco_5x5_100``, ``DICT_6X6_250``,
    ``aruco_original``), case-insensitively.  The AprilTag library's own
    families keep its spelling (``tagStandard41h12``).
    """
    if not isinstance(family, str) or not family.strip():
        raise RigError(f"tag family must be a non-empty string (e.g. tag36h11), got {family!r}")
    s = family.strip().lower().replace("-", "_")
    s = s.removeprefix("dict_")
    candidates = [s]
    for prefix in ("apriltag_", "apriltag", "tag_", "tag"):
        if s.startswith(prefix):
            candidates.append("tag" + s[len(prefix):])
    candidates.append("tag" + s)  # bare "36h11", "standard41h12"
    if s.startswith("aruco_"):
        candidates.append(s[6:])  # "aruco_4x4_50"
    for c in candidates:
        if c in _DICTIONARIES:
            return c
        if c in _APRILTAG:
            return _APRILTAG[c]
    known = ", ".join(sorted(set(_DICTIONARIES) | set(_APRILTAG.values())))
    raise RigError(f"unknown tag family {family!r} (known: {known})")


def tag_library(family: str) -> str:
    """``"apriltag"`` when the AprilTag 3 library decodes ``family`` (canonical spelling), else ``"opencv"``."""
    return "apriltag" if family in apriltag_lib.APRILTAG_FAMILIES else "opencv"


def tag_cells(family: str) -> int:
    """Cells across the square whose corners are the tag's corners (its side is the rig's ``size``):
    the black square of the classic families, the inner edge of the black ring for the
    reversed-border ones (``tagStandard41h12``: 5 of its 9 cells)."""
    if family in _DICTIONARIES:
        return int(_dictionary(family).markerSize) + 2  # data bits plus the one-cell black border
    return apriltag_lib.family_layout(family).square_cells


@functools.cache
def tag_id_count(family: str) -> int:
    """How many ids ``family`` (canonical spelling) has."""
    if family in _DICTIONARIES:
        return int(_dictionary(family).bytesList.shape[0])
    return apriltag_lib.family_layout(family).n_codes


@functools.cache
def _dictionary(family: str) -> Any:
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, _DICTIONARIES[family]))


def has_aruco_dictionary(family: str) -> bool:
    """Whether OpenCV's aruco module has a dictionary of ``family`` (canonical spelling)."""
    return family in _DICTIONARIES


def aruco_dictionary(family: str) -> Any:
    """The ``cv2.aruco.Dictionary`` of a tag family (any spelling :func:`canonical_family` accepts);
    :class:`RigError` for the families only the AprilTag library has."""
    fam = canonical_family(family)
    if fam not in _DICTIONARIES:
        raise RigError(f"OpenCV's aruco module has no {fam} dictionary (the AprilTag library decodes it)")
    return _dictionary(fam)


def tag_spec(marker: Marker) -> tuple[str, int, float]:
    """(canonical family, id, size) of a tag marker, validated."""
    tag = marker.tag
    where = f"marker {marker.name!r}"
    if not isinstance(tag, Mapping):
        raise RigError(f"{where}: tag must be a mapping {{family, id, size}}")
    for key in ("family", "id", "size"):
        if key not in tag:
            raise RigError(f"{where}: tag: missing key {key!r}")
    try:
        family = canonical_family(tag["family"])
    except RigError as exc:
        raise RigError(f"{where}: {exc}") from None
    tid = tag["id"]
    if isinstance(tid, (bool, np.bool_)) or not isinstance(tid, (int, np.integer)) or tid < 0:
        raise RigError(f"{where}: tag id must be a non-negative integer, got {tid!r}")
    n_ids = tag_id_count(family)
    if tid >= n_ids:
        raise RigError(f"{where}: tag id {tid} does not exist in {family} (ids 0..{n_ids - 1})")
    size = tag["size"]
    if isinstance(size, bool) or not isinstance(size, (int, float, np.integer, np.floating)) or \
            not (math.isfinite(float(size)) and float(size) > 0):
        raise RigError(f"{where}: tag size must be a finite number > 0 (metres), got {size!r}")
    return family, int(tid), float(size)
