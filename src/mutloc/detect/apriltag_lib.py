"""The AprilTag 3 library (the C library the ``pupil-apriltags`` wheel ships), called directly.

Why not ``pupil_apriltags.Detector``: it builds one detector per family (the
library can decode several families in one pass over the image), always
corrects 2 bits -- for ``tagStandard52h13`` that builds a 23 s, multi-GB
lookup table at construction (measured) -- and passes
``decode_sharpening`` through ``int()`` (0.25 becomes 0).  The C API is small
and stable (``apriltag.h`` of AprilTag 3.1), so this module declares the few
structs it needs and talks to the same shared library.

Pixel convention: the library's coordinates put ``(0, 0)`` at the top-left
*corner* of the image (pixel centres at ``+0.5``); :func:`detect` returns
mutloc's (``(0, 0)`` = centre of the top-left pixel).  Corners come in
OpenCV's order (top-left, top-right, bottom-right, bottom-left of the tag as
printed), not the library's (bottom-left first, counter-clockwise).
"""

from __future__ import annotations

import ctypes
import functools
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._extras import require
from ..errors import InputError

__all__ = ["APRILTAG_FAMILIES", "AprilTagDetection", "FamilyLayout", "detect", "family_layout", "peer_detector",
           "tag_image"]

#: Families the AprilTag 3 library decodes (its own spelling).
APRILTAG_FAMILIES = ("tag16h5", "tag25h9", "tag36h11", "tagCircle21h7", "tagCircle49h12", "tagCustom48h12",
                     "tagStandard41h12", "tagStandard52h13")

# Bits the library may correct per family.  Its lookup table holds every code
# with every pattern of up to that many flipped bits: for the families with
# tens of thousands of codes 2 bits cost seconds and gigabytes at start-up
# (measured: 52h13 23 s, 49h12 60 s), 1 bit ~100 MB, so they correct 1; the
# minimum Hamming distance (12-13) keeps false positives negligible either way.
_MAX_BITS = {"tagCircle49h12": 1, "tagCustom48h12": 1, "tagStandard52h13": 1}
_DEFAULT_BITS = 2
# The library's default decode sharpening (pupil-apriltags' 0.25 truncates to 0).
_SHARPENING = 0.25
# Local contrast (grey levels, max - min over a 4x4 tile) below which the
# library leaves a tile unsegmented.  Its default, 5, segments every faint
# texture of a room, and the clusters that follow cost most of its time; a
# printed tag has far more contrast even in dim light (sRGB expands the
# darks).  Measured with bench/bench_tags.py (960x540, 6 scenes of 14 tags):
# 20 instead of 5 is ~1.5x faster at the same recall, also at exposure 0.15.
_MIN_WHITE_BLACK_DIFF = 20
# The library's pixel-centre offset (see the module docstring).
_ORIGIN = 0.5
# Library corner k -> OpenCV corner order (TL, TR, BR, BL of the printed tag).
_TO_OPENCV = [3, 2, 1, 0]


class _Image(ctypes.Structure):
    _fields_ = [("width", ctypes.c_int32), ("height", ctypes.c_int32), ("stride", ctypes.c_int32),
                ("buf", ctypes.POINTER(ctypes.c_uint8))]


class _Family(ctypes.Structure):
    _fields_ = [("ncodes", ctypes.c_uint32), ("codes", ctypes.POINTER(ctypes.c_uint64)),
                ("width_at_border", ctypes.c_int), ("total_width", ctypes.c_int),
                ("reversed_border", ctypes.c_bool), ("nbits", ctypes.c_uint32),
                ("bit_x", ctypes.POINTER(ctypes.c_uint32)), ("bit_y", ctypes.POINTER(ctypes.c_uint32)),
                ("h", ctypes.c_int32), ("name", ctypes.c_char_p)]


class _QuadParams(ctypes.Structure):
    _fields_ = [("min_cluster_pixels", ctypes.c_int), ("max_nmaxima", ctypes.c_int),
                ("critical_rad", ctypes.c_float), ("cos_critical_rad", ctypes.c_float),
                ("max_line_fit_mse", ctypes.c_float), ("min_white_black_diff", ctypes.c_int),
                ("deglitch", ctypes.c_int)]


class _Detector(ctypes.Structure):
    _fields_ = [("nthreads", ctypes.c_int), ("quad_decimate", ctypes.c_float), ("quad_sigma", ctypes.c_float),
                ("refine_edges", ctypes.c_int), ("decode_sharpening", ctypes.c_double), ("debug", ctypes.c_int),
                ("qtp", _QuadParams)]


class _Detection(ctypes.Structure):
    _fields_ = [("family", ctypes.POINTER(_Family)), ("id", ctypes.c_int), ("hamming", ctypes.c_int),
                ("decision_margin", ctypes.c_float), ("H", ctypes.c_void_p), ("c", ctypes.c_double * 2),
                ("p", (ctypes.c_double * 2) * 4)]


class _ZArray(ctypes.Structure):
    _fields_ = [("el_sz", ctypes.c_size_t), ("size", ctypes.c_int), ("alloc", ctypes.c_int),
                ("data", ctypes.c_void_p)]


@functools.cache
def _lib() -> Any:
    pupil_apriltags = require("pupil_apriltags", "detecting and drawing AprilTag-library tags")
    root = Path(pupil_apriltags.__file__).parent
    for pattern in ("lib*/libapriltag.so*", "lib*/libapriltag*.dylib", "lib*/*apriltag*.dll"):
        for path in sorted(root.glob(pattern)):
            lib = ctypes.CDLL(str(path))
            break
        else:
            continue
        break
    else:  # pragma: no cover
        raise InputError(f"pupil-apriltags is installed but its AprilTag library was not found under {root}")
    lib.apriltag_detector_create.restype = ctypes.POINTER(_Detector)
    lib.apriltag_detector_add_family_bits.argtypes = [ctypes.POINTER(_Detector), ctypes.POINTER(_Family),
                                                      ctypes.c_int]
    lib.apriltag_detector_add_family_bits.restype = None
    lib.apriltag_detector_detect.argtypes = [ctypes.POINTER(_Detector), ctypes.POINTER(_Image)]
    lib.apriltag_detector_detect.restype = ctypes.POINTER(_ZArray)
    lib.apriltag_detections_destroy.argtypes = [ctypes.POINTER(_ZArray)]
    lib.apriltag_detections_destroy.restype = None
    lib.apriltag_to_image.argtypes = [ctypes.POINTER(_Family), ctypes.c_uint32]
    lib.apriltag_to_image.restype = ctypes.POINTER(_Image)
    lib.image_u8_destroy.argtypes = [ctypes.POINTER(_Image)]
    lib.image_u8_destroy.restype = None
    for fam in APRILTAG_FAMILIES:
        getattr(lib, f"{fam}_create").restype = ctypes.POINTER(_Family)
    return lib


@functools.cache
def _family(name: str) -> Any:
    # Created once and never destroyed: detectors keep pointers to it.
    return getattr(_lib(), f"{name}_create")()


@dataclass(frozen=True)
class FamilyLayout:
    """How a family's tags are drawn: ``total_cells`` across the whole tag,
    ``square_cells`` across the square the detector finds (its corners are
    the tag's corners, its side the rig's ``size``), ``reversed_border``:
    that square is light inside, dark outside (the ``tagStandard``/``Circle``
    families)."""

    name: str
    n_codes: int
    total_cells: int
    square_cells: int
    reversed_border: bool


@functools.cache
def family_layout(name: str) -> FamilyLayout:
    """Layout of an AprilTag-library family (:data:`APRILTAG_FAMILIES` spelling)."""
    f = _family(name).contents
    return FamilyLayout(name, int(f.ncodes), int(f.total_width), int(f.width_at_border), bool(f.reversed_border))


@functools.lru_cache(maxsize=512)
def tag_image(name: str, tag_id: int) -> np.ndarray:
    """The printed tag, one pixel per cell, uint8 0/255 ``(total_cells, total_cells)``.

    Drawn from the family's codes and bit positions as the library's
    ``tag_to_image`` intends (its 3.1 version scrambles the border of the
    classic families): a black ring on the detected square's outside edge
    for the classic families, a black ring around it and a white ring just
    inside for the reversed-border ones; a set bit is a white cell.
    """
    lay = family_layout(name)
    if not 0 <= tag_id < lay.n_codes:
        raise InputError(f"{name} has no tag id {tag_id} (ids 0..{lay.n_codes - 1})")
    f = _family(name).contents
    n, w = lay.total_cells, lay.square_cells
    b = (n - w) // 2
    img = np.zeros((n, n), np.uint8)
    lo, hi = (b, b + w - 1) if lay.reversed_border else (b - 1, b + w)  # the white ring
    img[lo:hi + 1, lo:hi + 1] = 255
    if lay.reversed_border:
        img[lo + 1:hi, lo + 1:hi] = 0
    else:
        img[lo + 1:hi, lo + 1:hi] = 0  # the black ring, and a black interior the bits paint over
    code = int(f.codes[tag_id])
    nbits = int(f.nbits)
    for i in range(nbits):
        if code >> (nbits - 1 - i) & 1:
            # Bit positions are stored unsigned; cells outside the square wrap below zero.
            x = int(np.int32(np.uint32(f.bit_x[i]))) + b
            y = int(np.int32(np.uint32(f.bit_y[i]))) + b
            img[y, x] = 255
    img.flags.writeable = False
    return img


@dataclass
class AprilTagDetection:
    """One tag the library decoded, corners in mutloc's convention and OpenCV's order."""

    family: str
    id: int
    corners: np.ndarray  # (4, 2)
    hamming: int
    decision_margin: float


class _Handle:
    """A configured library detector (not thread-safe: one call at a time).

    Never destroyed: the library keeps each family's decode table in the
    family itself and frees it with any detector that holds the family, so
    detectors sharing a family must outlive each other.  A new setting
    combination rebuilds the (same) table and leaks the old one (36h11:
    ~19 MB), hence the small cache of handles.
    """

    def __init__(self, families: tuple[str, ...], params: tuple[tuple[str, Any], ...]) -> None:
        lib = _lib()
        self.ptr = lib.apriltag_detector_create()
        self.lock = threading.Lock()
        d = self.ptr.contents
        d.nthreads = 1
        d.decode_sharpening = _SHARPENING
        d.qtp.min_white_black_diff = _MIN_WHITE_BLACK_DIFF
        for key, value in params:
            target = d.qtp if hasattr(d.qtp, key) else d
            setattr(target, key, value)
        for fam in families:
            lib.apriltag_detector_add_family_bits(self.ptr, _family(fam), _MAX_BITS.get(fam, _DEFAULT_BITS))


#: Detector settings that may be overridden (the library's names).
PARAMS = ("nthreads", "quad_decimate", "quad_sigma", "refine_edges", "decode_sharpening",
          "min_cluster_pixels", "max_nmaxima", "critical_rad", "max_line_fit_mse", "min_white_black_diff",
          "deglitch")


@functools.lru_cache(maxsize=16)
def _handle(families: tuple[str, ...], params: tuple[tuple[str, Any], ...]) -> _Handle:
    return _Handle(families, params)


def check_params(params: dict[str, Any] | None) -> tuple[tuple[str, Any], ...]:
    """Validated, hashable detector settings (InputError on an unknown name or a bad value)."""
    if not params:
        return ()
    out = []
    for key, value in params.items():
        if key not in PARAMS:
            raise InputError(f"params: {key!r} is not an AprilTag detector setting (one of {', '.join(PARAMS)})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
            raise InputError(f"params[{key!r}]: expected a number >= 0, got {value!r}")
        if key == "critical_rad":
            out.append(("cos_critical_rad", float(np.cos(value))))
        out.append((key, value))
    return tuple(sorted(out))


def detect(gray: np.ndarray, families: tuple[str, ...],
           params: tuple[tuple[str, Any], ...] = ()) -> list[AprilTagDetection]:
    """Every tag of ``families`` the library decodes in the uint8 image ``gray`` (one pass, one thread)."""
    if gray.dtype != np.uint8 or gray.ndim != 2:
        raise InputError("the AprilTag library needs a uint8 grey image")
    gray = np.ascontiguousarray(gray)
    h, w = gray.shape
    handle = _handle(tuple(sorted(families)), params)
    lib = _lib()
    # The library reads the NumPy buffer in place (no copy).
    im = _Image(w, h, w, gray.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8)))
    with handle.lock:
        za = lib.apriltag_detector_detect(handle.ptr, ctypes.byref(im))
    try:
        n = za.contents.size
        ptrs = (ctypes.POINTER(_Detection) * n).from_address(za.contents.data) if n else []
        out = []
        for p in ptrs:
            d = p.contents
            corners = np.array(d.p, dtype=float)[_TO_OPENCV] - _ORIGIN
            out.append(AprilTagDetection(d.family.contents.name.decode(), int(d.id), corners, int(d.hamming),
                                         float(d.decision_margin)))
    finally:
        lib.apriltag_detections_destroy(za)
    return out


def peer_detector(family: str = "tag36h11") -> Any:
    """``pupil_apriltags.Detector(families=family, nthreads=1)`` as shipped (its defaults), for comparisons
    (tests, benchmarks), with its destructor made safe.

    pupil-apriltags 1.0.4 frees a detector's families *before* the detector,
    whose destruction then reads and frees through the freed families (a use
    after free that corrupted the heap and aborted a test run much later);
    here the detector goes first.
    """
    pupil_apriltags = require("pupil_apriltags", "the pupil-apriltags peer detector")

    class _Peer(pupil_apriltags.Detector):  # type: ignore[misc]
        def __del__(self) -> None:
            if getattr(self, "tag_detector_ptr", None) is None:
                return
            self.libc.apriltag_detector_destroy.restype = None
            self.libc.apriltag_detector_destroy(self.tag_detector_ptr)
            self.tag_detector_ptr = None
            for fam, ptr in self.tag_families.items():
                getattr(self.libc, f"{fam}_destroy").restype = None
                getattr(self.libc, f"{fam}_destroy")(ptr)
            self.tag_families = {}

    return _Peer(families=family, nthreads=1)
