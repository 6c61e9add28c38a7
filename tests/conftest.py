"""Test-suite settings.

Hypothesis draws its examples from a fixed seed (``derandomize``), so a run
of ``make test`` is reproducible: a property that fails, fails every time and
on every machine, instead of now and then in CI.  Set
``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples.

A test that joins DDS takes its domain id from the ``dds_domain`` fixture:
an id no other running process holds (tests/dds_domains.py).
"""

import os

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
