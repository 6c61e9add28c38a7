"""The cylinder detector's stages, each against geometry built by hand."""

import math

import numpy as np
import pytest

from mutloc.core.camera import Camera
from mutloc.detect.cylinders.edges import axis_u
from mutloc.detect.cylinders.runs import Run, code_runs, dark_mask, dark_runs, match, placements, stack_chains

CODE = np.array([1, 0, 1, 1, 0, 1])


def _banded(code, x0=200, width=24, band=10, top=60, shape=(240, 400)):
    """A light image with the code's dark bands as rectangles (a cylinder seen head on)."""
    img = np.full(shape, 200, np.uint8)
    for k, bit in enumerate(code):
        if bit:
            img[top + k * band: top + (k + 1) * band, x0: x0 + width] = 20
    return img


def test_dark_runs_recover_the_rectangles():
    img = _banded(CODE)
    runs = sorted(dark_runs(dark_mask(img)), key=lambda r: r.top)
    # dark runs of the code: bands 0, 2-3, 5
    assert [(r.top, r.bot) for r in runs] == [(60, 69), (80, 99), (110, 119)]
    for r in runs:
        assert r.left == 200 and r.right == 223 and r.width == 24 and r.xc == pytest.approx(211.5)


def test_stacked_runs_chain_and_a_far_run_does_not():
    runs = [Run(0, 9, 100, 123), Run(20, 39, 100, 123), Run(50, 59, 101, 124), Run(20, 30, 300, 323)]
    chains = stack_chains(runs)
    assert [[(r.top, r.left) for r in c] for c in chains if len(c) == 3] == [[(0, 100), (20, 100), (50, 101)]]
    assert any(len(c) == 1 and c[0].left == 300 for c in chains)


def test_code_runs():
    assert code_runs(CODE) == (0, 6, [(0, 1), (2, 4), (5, 6)])
    assert code_runs(np.array([0, 0, 1, 0])) == (2, 3, [(2, 3)])
    assert code_runs(np.zeros(4, int)) is None


def test_match_accepts_its_own_code_and_refuses_another():
    runs = sorted(dark_runs(dark_mask(_banded(CODE, width=24, band=10))), key=lambda r: r.top)
    aspect = 24 / 10  # diameter over band height
    got = match(runs, CODE, aspect)
    assert got is not None and got[0] < 0.2 and [r.top for r in got[1]] == [60, 80, 110]
    assert match(runs, np.array([1, 1, 0, 1, 0, 1]), aspect) is None or \
        match(runs, np.array([1, 1, 0, 1, 0, 1]), aspect)[0] > got[0]
    assert match(runs, CODE, 4 * aspect) is None  # a cylinder four times as wide is not this one


@pytest.mark.parametrize("x", [-0.4, -0.1, 0.0, 0.2, 0.5])
def test_axis_from_the_silhouette(x):
    """An upright cylinder of radius 3 cm at 1.2 m, x metres to the side: its
    silhouette's edges are the tangent rays; axis_u maps their middle to the
    axis's image."""
    f, cx = 800.0, 479.5
    cam = Camera(np.array([[f, 0, cx], [0, f, 269.5], [0, 0, 1]]), None, (960, 540))
    r, z = 0.03, 1.2
    d = math.hypot(x, z)
    phi = math.atan2(x, z)
    half = math.asin(r / d)
    u_edges = [cx + f * math.tan(phi + s * half) for s in (-1, 1)]
    u_mid, R = 0.5 * sum(u_edges), 0.5 * (u_edges[1] - u_edges[0])
    assert axis_u(u_mid, R, cam) == pytest.approx(cx + f * x / z, abs=1e-9)


def test_match_scores_shared_placements_once_with_the_same_result():
    """The detector scores each placement of a code once across the chains of an image (``memo``): the
    chains of a cluttered image share runs.  Every chain's best match must be what matching it alone gives,
    on many chains through the same runs: bands whose heights and gaps vary, some a band apart."""
    rng = np.random.default_rng(5)
    codes = [CODE, np.array([1, 0, 1, 0, 0, 1]), np.array([1, 1, 0, 1, 0, 1]), np.array([1, 0, 0, 1, 1, 1])]
    found = 0
    for trial in range(3):
        runs, v = [], 0
        for _ in range(9):
            v += int(rng.integers(3, 14))
            h = int(rng.integers(6, 22))
            x = 100 + float(rng.normal(0.0, 0.6))
            runs.append(Run(v, v + h - 1, x, x + 23 + float(rng.normal(0.0, 0.6))))
            if rng.uniform() < 0.5:  # a run beside it, as clutter makes: paths branch and join again
                runs.append(Run(v + 1, v + h - 2, x + 1, x + 24))
            v += h
        chains = stack_chains(runs)
        assert len(chains) > 20
        for code in codes:
            aspect = 24 / 10
            memo: dict = {}
            for chain in chains:
                alone = match(chain, code, aspect)
                shared = match(chain, code, aspect, memo)
                assert (alone is None) == (shared is None)
                if alone is not None:
                    found += 1
                    assert shared[0] == alone[0]
                    assert [(r.top, r.bot, r.left, r.right, r.synthetic) for r in shared[1]] == \
                        [(r.top, r.bot, r.left, r.right, r.synthetic) for r in alone[1]]
    print(f"{found} chains matched")
    assert found > 50


def test_placements_hold_every_chains_best_match():
    """:func:`placements` scores each placement of a code once on the links between runs (no chains walked):
    whatever the best match on any chain through those runs is (:func:`match`, chain by chain), it is one of
    the placements, at the same cost; and no placement fits that no chain's part would."""
    rng = np.random.default_rng(11)
    codes = [CODE, np.array([1, 0, 1, 0, 0, 1]), np.array([1, 1, 0, 1, 0, 1]), np.array([1, 0, 0, 1, 1, 1])]
    checked = 0
    for trial in range(3):
        runs, v = [], 0
        for _ in range(8):
            v += int(rng.integers(3, 14))
            h = int(rng.integers(6, 22))
            x = 100 + float(rng.normal(0.0, 0.6))
            runs.append(Run(v, v + h - 1, x, x + 23 + float(rng.normal(0.0, 0.6))))
            if rng.uniform() < 0.5:
                runs.append(Run(v + 1, v + h - 2, x + 1, x + 24))
            v += h
        chains = stack_chains(runs)
        for code in codes:
            got = {tuple((r.top, r.bot, r.left, r.right, r.synthetic) for r in part): cost
                   for cost, part in placements(runs, [], code, 24 / 10)}
            for chain in chains:
                best = match(chain, code, 24 / 10)
                if best is not None:
                    key = tuple((r.top, r.bot, r.left, r.right, r.synthetic) for r in best[1])
                    assert got.get(key) == pytest.approx(best[0])
                    checked += 1
            for key, cost in got.items():
                part = [Run(*k) for k in key]
                seen = [r for r in part if not r.synthetic]
                # a placement fits a chain made of its own runs
                assert match(seen, code, 24 / 10) is not None
    assert checked > 50
