"""The DDS domain ids tests take (tests/dds_domains.py): never one another running process holds.

Each test uses a lock folder of its own (``MUTLOC_DDS_LOCK_DIR``), so the ids
it sees taken are the ones it took, whatever else runs on the machine.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import dds_domains
from dds_domains import allocate

HOLDER = """
import sys
sys.path.insert(0, {tests!r})
from dds_domains import allocate
lease = allocate()
print(lease.domain, flush=True)
sys.stdin.read()  # held until the test closes our stdin (or kills us)
"""


@pytest.fixture
def own_locks(tmp_path, monkeypatch):
    monkeypatch.setenv("MUTLOC_DDS_LOCK_DIR", str(tmp_path / "locks"))
    return tmp_path / "locks"


def _holder():
    """A process holding a domain id until its stdin closes: (process, its id)."""
    code = HOLDER.format(tests=str(Path(__file__).parent))
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = proc.stdout.readline()
    assert line.strip().isdigit(), line
    return proc, int(line)


def test_ids_held_at_once_never_coincide_within_a_process_or_across_processes(own_locks):
    a, b = allocate(), allocate()
    proc, theirs = _holder()
    try:
        assert len({a.domain, b.domain, theirs}) == 3
        assert all(d in dds_domains.DOMAIN_IDS for d in (a.domain, b.domain, theirs))
        # while the other process holds its id, this one is not given it either
        c = allocate()
        assert c.domain not in (a.domain, b.domain, theirs)
        c.release()
    finally:
        proc.kill()
        proc.wait(10)
    # the holder died without releasing: the kernel dropped its lock, the id is free again
    d = allocate()
    assert d.domain == theirs
    for lease in (a, b, d):
        lease.release()


def test_a_released_id_is_taken_again(own_locks):
    a = allocate()
    first = a.domain
    b = allocate()
    a.release()
    c = allocate()
    assert c.domain == first != b.domain
    with allocate() as e:
        assert e.domain not in (b.domain, c.domain)
    with allocate() as f:  # e released at the end of its block
        assert f.domain == e.domain
    b.release(), c.release()


def test_an_id_whose_ports_a_participant_holds_is_passed_over(own_locks):
    """A DDS participant that did not come through the allocator (an older checkout's test run, a
    benchmark) holds its domain's ports: that id is not handed out while it runs."""
    from mutloc.live.dds import Bus

    with allocate() as lease:
        taken = lease.domain
    bus = Bus(taken, loopback=True)
    try:
        assert dds_domains.ports_in_use(taken)
        with allocate() as lease:
            assert lease.domain != taken
    finally:
        bus.close()


def test_every_id_taken_is_one_line(own_locks):
    with allocate(range(3, 5)) as a, allocate(range(3, 5)) as b:
        assert {a.domain, b.domain} == {3, 4}
        with pytest.raises(RuntimeError, match="every DDS domain id 3..4 is held"):
            allocate(range(3, 5))
