"""PLY point clouds (binary little-endian; MeshLab, CloudCompare, Open3D read them)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FileFormatError, InputError

__all__ = ["write_ply", "read_ply"]


def write_ply(path: str | Path, points: Any, colors: Any | None = None) -> None:
    """Write ``points`` (n, 3) and optional sRGB ``colors`` (n, 3, uint8 RGB) as PLY."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(P)):
        raise InputError("point cloud has non-finite coordinates")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        C = np.asarray(colors).reshape(-1, 3)
        if len(C) != len(P):
            raise InputError(f"{len(C)} colours for {len(P)} points")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    data = np.empty(len(P), dtype=fields)
    data["x"], data["y"], data["z"] = P.T
    if colors is not None:
        data["red"], data["green"], data["blue"] = np.clip(C, 0, 255).astype(np.uint8).T
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(P)}"]
    head += [f"property {'float' if t == '<f4' else 'uchar'} {n}" for n, t in fields]
    head.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        f.write(data.tobytes())


def read_ply(path: str | Path) -> tuple[np.ndarray, np.ndarray | None]:
    """Points (n, 3) and colours (n, 3) or None of a PLY written by :func:`write_ply`."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise FileFormatError(f"{path}: not a PLY file")
    head = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in head:
        raise FileFormatError(f"{path}: only binary little-endian PLY is supported")
    n = next((int(h.split()[2]) for h in head if h.startswith("element vertex")), None)
    props = [h.split() for h in head if h.startswith("property")]
    types = {"float": "<f4", "uchar": "u1", "double": "<f8"}
    try:
        dt = np.dtype([(p[2], types[p[1]]) for p in props])
        data = np.frombuffer(raw[end + len("end_header\n"):], dtype=dt, count=n)
    except (KeyError, ValueError, TypeError, IndexError) as e:
        raise FileFormatError(f"{path}: malformed PLY ({e})") from None
    pts = np.stack([data["x"], data["y"], data["z"]], axis=1).astype(float)
    cols = np.stack([data["red"], data["green"], data["blue"]], axis=1) if "red" in dt.names else None
    return pts, cols
