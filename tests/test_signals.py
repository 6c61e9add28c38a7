"""mutloc.signals: SIGTERM is Ctrl-C for the time of a command, a row being
written is finished before either stops the run, and children are stopped
by process group whatever signals they ignore."""

import os
import signal
import subprocess
import sys
import time

import pytest

from mutloc.signals import deferred_interrupt, sigterm_as_interrupt, stop_process_group


@pytest.fixture
def sigterm_default():
    old = signal.signal(signal.SIGTERM, signal.SIG_DFL)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def test_sigterm_raises_keyboard_interrupt_inside_only(sigterm_default):
    with pytest.raises(KeyboardInterrupt):
        with sigterm_as_interrupt():
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(10**6):  # the handler runs between two bytecodes
                pass
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_an_ignored_sigterm_stays_ignored():
    old = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with sigterm_as_interrupt():
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGTERM)
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, old)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_waits_for_the_row_being_written(sigterm_default, sig):
    """Either stop signal during a deferred block: the block runs to its end,
    then KeyboardInterrupt; the handlers are Ctrl-C's again after."""
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        old_int = signal.signal(signal.SIGINT, signal.default_int_handler)  # e.g. a background job's SIG_IGN
    else:
        old_int = None
    steps = []
    try:
        with sigterm_as_interrupt():
            with pytest.raises(KeyboardInterrupt):
                with deferred_interrupt():
                    steps.append("first half")
                    os.kill(os.getpid(), sig)
                    for _ in range(10**6):
                        pass
                    steps.append("second half")
            assert signal.getsignal(signal.SIGTERM) is signal.default_int_handler
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        if old_int is not None:
            signal.signal(signal.SIGINT, old_int)
    assert steps == ["first half", "second half"]


#: A child that ignores SIGINT and (with "stubborn") SIGTERM, with a grandchild in its group; says "up".
CHILD = """
import signal, subprocess, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)
if sys.argv[1] == "stubborn":
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
grandchild = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
print(grandchild.pid, flush=True)
time.sleep(600)
"""


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:
        return f.read().rsplit(")", 1)[1].split()[0] != "Z"  # a zombie waits for its parent only


@pytest.mark.parametrize("kind", ["polite", "stubborn"])
def test_children_stopped_by_process_group(kind):
    """SIGTERM to the group stops a child ignoring SIGINT and its grandchild;
    one ignoring SIGTERM too is killed after the timeout."""
    child = subprocess.Popen([sys.executable, "-c", CHILD, kind], stdout=subprocess.PIPE, text=True,
                             start_new_session=True)
    grandchild = None
    try:
        grandchild = int(child.stdout.readline())
        stop_process_group([child], timeout=2.0)
        assert child.returncode == (-signal.SIGTERM if kind == "polite" else -signal.SIGKILL)
        for _ in range(600):  # the grandchild, orphaned, is reaped by init: wait for it to go
            if not _alive(grandchild):
                break
            time.sleep(0.05)
        assert not _alive(grandchild)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
        child.stdout.close()


_EXIT_ON_STOP = """
import os, signal, sys, time
from mutloc.signals import exit_on_stop, sigterm_as_interrupt
signal.signal(signal.SIGINT, signal.default_int_handler)  # (a background job starts with SIGINT ignored)
with sigterm_as_interrupt():
    try:
        with exit_on_stop("interrupted while compiling"):
            os.kill(os.getpid(), {sig})
            time.sleep(5)
            print("the block went on")
        print("after the block")
    finally:
        print("a finally block ran")
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_signal_in_an_exit_on_stop_block_ends_the_process_with_one_line(sig):
    """Inside exit_on_stop (a node loading its kernels) a stop signal ends the
    process at once: its one line, status 130, no KeyboardInterrupt raised
    into the block (nothing after it runs, no traceback)."""
    p = subprocess.run([sys.executable, "-c", _EXIT_ON_STOP.format(sig=int(sig))], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 130
    assert p.stderr == "interrupted while compiling\n"
    assert p.stdout == ""


def test_exit_on_stop_restores_ctrl_c_after_the_block():
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        from mutloc.signals import exit_on_stop

        with exit_on_stop("x"):
            assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, old)
