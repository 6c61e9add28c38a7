"""DDS domain ids for tests that no other running process holds.

Every test that joins DDS takes its domain id from here (the ``dds_domain``
fixture of tests/conftest.py), so two pytest workers, or two test runs on one
machine, never meet on a domain.  An id is taken by an exclusive ``flock`` on
its lock file (``<tmp>/mutloc-dds-domains/<id>.lock``), held until the test
ends: the kernel releases it when the holder closes it or dies, so a crashed
run leaves nothing behind.  An id whose DDS ports some process has bound (a
run that did not come through here: an older checkout, a benchmark, a ROS
system) is passed over too.

The ids are :data:`DOMAIN_IDS` (1..100): CycloneDDS maps domain ``d`` to the
UDP ports ``7400 + 250 d`` and up (a participant ``i`` at ``7410 + 250 d +
2 i``; the loopback configuration allows indices up to 60), so domain 100
ends at port 32531, below Linux's ephemeral range (from 32768), where a
port could be in use by any socket of the machine.
"""

from __future__ import annotations

import errno
import fcntl
import os
import socket
import tempfile
from pathlib import Path

__all__ = ["DOMAIN_IDS", "DomainLease", "allocate", "lock_dir", "ports_in_use"]

#: The domain ids handed out: their ports stay below the ephemeral range.
DOMAIN_IDS = range(1, 101)
#: Participant indices whose ports are probed (the first participants of a domain take the lowest).
PROBED_PARTICIPANTS = 4


def lock_dir() -> Path:
    """Where the lock files are (one per domain id): shared by every process of the machine."""
    return Path(os.environ.get("MUTLOC_DDS_LOCK_DIR") or Path(tempfile.gettempdir()) / "mutloc-dds-domains")


def _ports(domain: int) -> list[int]:
    base = 7400 + 250 * domain
    return [base, base + 1, *(p for i in range(PROBED_PARTICIPANTS) for p in (base + 10 + 2 * i, base + 11 + 2 * i))]


def ports_in_use(domain: int) -> bool:
    """Whether some socket of the machine holds one of ``domain``'s first DDS ports (a participant in it)."""
    for port in _ports(domain):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.bind(("0.0.0.0", port))  # no SO_REUSEADDR: refused while any socket holds the port
        except OSError as e:
            if e.errno in (errno.EADDRINUSE, errno.EACCES):
                return True
            raise
        finally:
            s.close()
    return False


class DomainLease:
    """A domain id held by this process until :meth:`release` (or the process ends)."""

    def __init__(self, domain: int, fd: int) -> None:
        self.domain, self._fd = domain, fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the lock
            self._fd = None

    def __enter__(self) -> "DomainLease":
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"DomainLease({self.domain}, {'held' if self._fd is not None else 'released'})"


def _try_lock(path: Path) -> int | None:
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except PermissionError:
        return None  # another user's lock file: theirs
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as e:
        os.close(fd)
        if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    return fd


def allocate(ids: range = DOMAIN_IDS) -> DomainLease:
    """The first id of ``ids`` no process holds (lock or ports), held by the returned lease.

    A lock is per open file, so two leases in one process exclude each other
    as well as leases of other processes.  RuntimeError when every id is taken."""
    folder = lock_dir()
    folder.mkdir(parents=True, exist_ok=True)
    try:
        os.chmod(folder, 0o1777)  # every user's runs share the folder (sticky: each keeps its own files)
    except PermissionError:
        pass
    for domain in ids:
        fd = _try_lock(folder / f"{domain}.lock")
        if fd is None:
            continue
        if ports_in_use(domain):
            os.close(fd)
            continue
        return DomainLease(domain, fd)
    raise RuntimeError(f"every DDS domain id {ids.start}..{ids.stop - 1} is held by a running process")
