"""What the Blender set makers share (bench/make_blender_set.py, bench/make_blender_lights.py): their
command line and the crops of the committed test subsets."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np


def set_parser(description: str, out: Path, only_help: str) -> argparse.ArgumentParser:
    """The options every set maker has: where the set goes, Cycles' samples, a subset, the interpreter
    with bpy, and the export of test crops instead of rendering."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--out", type=Path, default=out)
    ap.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel (denoised)")
    ap.add_argument("--only", default=None, help=only_help)
    ap.add_argument("--python", default=None, help="the interpreter with bpy (default $MUTLOC_BLENDER_PYTHON)")
    ap.add_argument("--export-test", type=Path, default=None, metavar="DIR",
                    help="write crops of --scenes (already rendered) with their truth to DIR, render nothing")
    ap.add_argument("--scenes", default="", help="comma-separated scene names for --export-test")
    return ap


def write_crop(path: Path, img: np.ndarray, x0: int, y0: int, x1: int, y1: int, K) -> np.ndarray:
    """Write ``img[y0:y1, x0:x1]`` to ``path`` (PNG, smallest) and return the crop's intrinsics: ``K``
    with the principal point moved by the crop's corner."""
    cv2.imwrite(str(path), img[y0:y1, x0:x1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    Kc = np.array(K, float)
    Kc[0, 2] -= x0
    Kc[1, 2] -= y0
    return Kc


def subset_or_export(args: argparse.Namespace, export, allowed, what: str) -> list[str] | None:
    """With ``--export-test``: ``export(out, dest, scenes)`` and None (render nothing); else the
    ``--only`` subset of ``allowed`` (all by default), a one-line exit naming an unknown ``what``."""
    if args.export_test is not None:
        export(args.out, args.export_test, [s for s in args.scenes.split(",") if s])
        return None
    chosen = args.only.split(",") if args.only else list(allowed)
    bad = [c for c in chosen if c not in allowed]
    if bad:
        raise SystemExit(f"unknown {what} {bad[0]!r} (one of {', '.join(allowed)})")
    return chosen
