"""Test-suite settings.

Hypothesis draws its examples from a fixed seed (``derandomize``), so a run
of ``make test`` is reproducible: a property that fails, fails every time and
on every machine, instead of now and then in CI.  Set
``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples.

A test that joins DDS takes its domain id from the ``dds_domain`` fixture:
an id no other running process holds (tests/dds_domains.py).

With a cold Numba cache (a fresh clone, or the kernels' sources changed) and
``-n 2`` or more, the controller first compiles the kernels once in two
processes (tests/warm_kernels.py), so that the workers do not each compile
the same ones; with a warm cache it does nothing.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from dds_domains import allocate
from hypothesis import settings

settings.register_profile("repeatable", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))


@pytest.fixture
def dds_domain():
    """A DDS domain id no other running process holds (tests/dds_domains.py), held until the test ends."""
    with allocate() as lease:
        yield lease.domain


_WARM_STAMP = "tests-warmed"


def pytest_configure(config):
    """On the xdist controller with two or more workers: warm a cold Numba cache (tests/warm_kernels.py)."""
    if hasattr(config, "workerinput"):
        return
    workers = getattr(config.option, "numprocesses", None)
    if not isinstance(workers, int) or workers < 2:
        return
    from mutloc import CACHE_DIR

    if not CACHE_DIR or os.path.exists(os.path.join(CACHE_DIR, _WARM_STAMP)):
        return
    script = Path(__file__).with_name("warm_kernels.py")
    env = dict(os.environ, MUTLOC_CACHE_DIR=os.path.dirname(CACHE_DIR))
    procs = [subprocess.Popen([sys.executable, str(script), group], env=env, start_new_session=True)
             for group in ("balls", "others")]
    try:
        codes = [p.wait() for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, 9)
                except ProcessLookupError:
                    pass
                p.wait()
    if all(c == 0 for c in codes):
        Path(CACHE_DIR, _WARM_STAMP).touch()
