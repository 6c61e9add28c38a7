"""Stopping a run: SIGTERM is Ctrl-C, and child processes stopped by group.

One place for the process's stop signals:

- :func:`sigterm_as_interrupt`: SIGTERM (what systemd, ``docker stop`` and
  ``kill`` send) raises ``KeyboardInterrupt`` as Ctrl-C (SIGINT) does, so
  every command ends the same way on both: the current record finished, the
  outputs and the summary written, exit status 130.  The ``mutloc`` command
  installs it for the time of the command.
- :func:`deferred_interrupt`: both held back until a block that writes one
  row in several steps ends.
- :func:`exit_on_stop`: within a block that must not be interrupted half
  way and has nothing to write yet (Numba compiling or loading kernels: a
  ``KeyboardInterrupt`` raised inside its callbacks leaves it broken), a
  stop signal prints one line and ends the process at once, status 130.
- :func:`stop_process_group`: a child started with ``start_new_session=True``
  is stopped with SIGTERM to its whole process group, then SIGKILL after a
  timeout.  SIGTERM, not SIGINT: a background job (``cmd &`` in a script)
  and everything it starts ignore SIGINT, never SIGTERM.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from contextlib import contextmanager
from typing import Iterable, Iterator

__all__ = ["STOP_SIGNALS", "sigterm_as_interrupt", "deferred_interrupt", "exit_on_stop", "stop_process_group", "kill_process_group",
           "STOP_TIMEOUT"]

#: The signals that stop a run as Ctrl-C does.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: Seconds a child group has to finish its files after SIGTERM before it is killed.
STOP_TIMEOUT = 10.0


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises ``KeyboardInterrupt`` as Ctrl-C does
    (the same handler: :func:`signal.default_int_handler`); the previous
    handler is restored after.  Only in the main thread, and only where
    SIGTERM has its default action (an ignored or handled SIGTERM is left
    alone)."""
    if not _main_thread() or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        yield
        return
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


@contextmanager
def deferred_interrupt() -> Iterator[None]:
    """Hold a stop signal (Ctrl-C, or SIGTERM under
    :func:`sigterm_as_interrupt`) back until the block ends, so a row written
    in several steps is written whole; then raise the ``KeyboardInterrupt``.
    Only in the main thread, and only for the signals whose handler is
    Python's own Ctrl-C handler (anything else is left alone)."""
    held = [s for s in STOP_SIGNALS if signal.getsignal(s) is signal.default_int_handler] if _main_thread() else []
    got: list[int] = []
    for s in held:
        signal.signal(s, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, signal.default_int_handler)
        if got:
            raise KeyboardInterrupt


@contextmanager
def exit_on_stop(line: str) -> Iterator[None]:
    """Within the block, a stop signal (Ctrl-C, or SIGTERM under
    :func:`sigterm_as_interrupt`) writes ``line`` to stderr and ends the
    process at once with status 130, instead of raising
    ``KeyboardInterrupt`` wherever the block happens to be.  For work with
    nothing to save that an exception must not cut in half -- Numba
    compiling a kernel, which a ``KeyboardInterrupt`` in its callbacks
    leaves unusable (``RuntimeError: no compiled object yet``).  Only in the
    main thread, and only for the signals whose handler is Python's own
    Ctrl-C handler; restored after."""
    held = [s for s in STOP_SIGNALS if signal.getsignal(s) is signal.default_int_handler] if _main_thread() else []

    def stop(signum: int, frame: object) -> None:
        try:
            os.write(2, (line.rstrip("\n") + "\n").encode())
        finally:
            os._exit(130)

    for s in held:
        signal.signal(s, stop)
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, signal.default_int_handler)


def _signal_group(p: subprocess.Popen, sig: int) -> None:
    if p.poll() is None:
        try:
            os.killpg(p.pid, sig)
        except ProcessLookupError:
            pass


def kill_process_group(p: subprocess.Popen) -> None:
    """SIGKILL the process group ``p`` leads (started with ``start_new_session=True``), as a crash would end
    it, and reap ``p``.  Nothing happens to a group whose leader has already ended."""
    _signal_group(p, signal.SIGKILL)
    p.wait()


def stop_process_group(procs: subprocess.Popen | Iterable[subprocess.Popen], timeout: float = STOP_TIMEOUT) -> None:
    """Stop every process of ``procs`` (each the leader of its own process
    group: started with ``start_new_session=True``) and what it started:
    SIGTERM to each group, then SIGKILL to the groups whose leader has not
    ended ``timeout`` seconds later.  Returns once every leader is reaped."""
    procs = [procs] if isinstance(procs, subprocess.Popen) else list(procs)
    for p in procs:
        _signal_group(p, signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            _signal_group(p, signal.SIGKILL)
            p.wait()
