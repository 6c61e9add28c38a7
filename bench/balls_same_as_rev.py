"""pytest plugin: every ``detect_balls`` call of a test run also made with another revision's detector, and compared.

    BALLS_REV=REV PYTHONPATH=bench python -m pytest -p balls_same_as_rev -n 0 tests/test_detect_balls.py

Wraps :func:`mutloc.detect.balls.detect_balls` (before the tests import
it): each call runs this tree's detector, then ``REV``'s (imported as in
``bench_balls_speed.py``) on a copy of the same image with the same
arguments, and records the largest differences of the detections' pixels,
radii and scores, the markers found by one only and calls where one raised
and the other did not.  The tests see this tree's results.  Prints a
summary and writes ``bench/results/balls_same_as_rev_<test files>.json``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from bench_balls_speed import load_rev

STATS: dict = {"calls": 0, "detections_compared": 0, "found_by_one_only": 0, "raised_differently": 0,
               "missing_reasons_differ": 0, "max_abs_diff_uv_px": 0.0, "max_abs_diff_radius_px": 0.0,
               "max_abs_diff_score": 0.0}


def _compare(a, b) -> None:
    STATS["missing_reasons_differ"] += a.missing_reasons != b.missing_reasons
    pairs = [(a.detections, b.detections)] + [
        (dict(enumerate(a.alternatives.get(k, []))), dict(enumerate(b.alternatives.get(k, []))))
        for k in set(a.alternatives) | set(b.alternatives)]
    for da_map, db_map in pairs:
        STATS["found_by_one_only"] += len(set(da_map) ^ set(db_map))
        for k in set(da_map) & set(db_map):
            da, db = da_map[k], db_map[k]
            STATS["detections_compared"] += 1
            for key, diff in (("max_abs_diff_uv_px", np.max(np.abs(np.asarray(da.uv) - np.asarray(db.uv)))),
                              ("max_abs_diff_radius_px", abs(da.info["radius_px"] - db.info["radius_px"])),
                              ("max_abs_diff_score", abs(da.score - db.score))):
                STATS[key] = max(STATS[key], float(diff))


def pytest_configure(config) -> None:
    import mutloc.detect.balls as balls
    import mutloc.detect.balls.detector as detector

    rev = os.environ.get("BALLS_REV", "main")
    old, OldParams, sha = load_rev(rev)
    STATS["rev"], STATS["commit"] = rev, sha
    new = detector.detect_balls

    def both(image, markers, **kw):
        kw_old = dict(kw)
        if dataclasses.is_dataclass(kw.get("params")):
            p = kw["params"]
            kw_old["params"] = OldParams(**{f.name: getattr(p, f.name) for f in dataclasses.fields(p)})
        copy = image.copy() if isinstance(image, np.ndarray) else image
        STATS["calls"] += 1
        try:
            res = new(image, markers, **kw)
        except Exception as exc:
            try:
                old(copy, markers, **kw_old)
                STATS["raised_differently"] += 1
            except Exception as exc_old:
                STATS["raised_differently"] += type(exc_old).__name__ != type(exc).__name__
            raise
        try:
            _compare(old(copy, markers, **kw_old), res)
        except Exception:
            STATS["raised_differently"] += 1
        return res

    balls.detect_balls = detector.detect_balls = both


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    terminalreporter.write_line(f"detect_balls against {STATS.get('rev')} ({str(STATS.get('commit'))[:10]}): "
                                + ", ".join(f"{k} {v}" for k, v in STATS.items() if k not in ("rev", "commit")))
    names = "_".join(Path(str(a)).stem for a in config.args) or "tests"
    out = Path(__file__).resolve().parent / "results" / f"balls_same_as_rev_{names}.json"
    out.write_text(json.dumps({"command": " ".join(["pytest"] + list(config.invocation_params.args)), **STATS},
                              indent=2))
