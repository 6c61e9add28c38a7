"""Where Numba keeps mutloc's compiled kernels.

Numba's on-disk cache checks only the timestamp of the file that defines a
function, not of the functions it calls, so a kernel compiled against an older
version of a callee in another file is silently reused.  Keying the cache
folder on a hash of mutloc's own sources makes every change of the package
start from a clean cache, and keeps compiled code out of site-packages.
Imported by ``mutloc/__init__`` before any kernel is defined.

The first use of each kernel after a change compiles it, for up to a minute
in all: when that happens (a cold cache) and stderr is a terminal, one line
says so (:func:`announce_compiling`); a warm cache compiles nothing and says
nothing.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import os
import sys
import tempfile
from pathlib import Path
from typing import Any


def _source_hash() -> str:
    root = Path(__file__).resolve().parent
    h = hashlib.sha1()
    for path in sorted(root.rglob("*.py")):
        data = path.read_bytes()
        # Only files that compile kernels matter to the cache.
        if b"numba" not in data:
            continue
        h.update(str(path.relative_to(root)).encode())
        h.update(data)
    return h.hexdigest()[:16]


def configure() -> str | None:
    """Point Numba's cache at a folder specific to this version of the sources.

    Does not import Numba: when it is not loaded yet the folder is handed over
    through ``NUMBA_CACHE_DIR`` (read when Numba loads), so importing mutloc
    stays cheap for commands that never compile anything.
    """
    tag = f"numba-{_source_hash()}"
    base = os.environ.get("MUTLOC_CACHE_DIR") or os.environ.get("NUMBA_CACHE_DIR")
    if base and os.path.basename(os.path.normpath(base)) == tag:
        base = os.path.dirname(os.path.normpath(base))  # set by a parent mutloc process
    if not base:
        xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        base = os.path.join(xdg, "mutloc")
    for candidate in (base, os.path.join(tempfile.gettempdir(), "mutloc-cache")):
        path = os.path.join(candidate, tag)
        try:
            os.makedirs(path, exist_ok=True)
        except OSError:
            continue
        if os.access(path, os.W_OK):
            numba = sys.modules.get("numba")
            if numba is not None:
                numba.config.CACHE_DIR = path
            else:
                os.environ["NUMBA_CACHE_DIR"] = path
            return path
    return None


def _notice_on_compile(numba: Any, folder: str | None) -> None:
    """Register with Numba's events: the first compilation (a kernel not in
    the cache) writes one line to stderr, if stderr is a terminal."""
    from numba.core import event

    class Notice(event.Listener):
        said = False

        def on_start(self, ev: Any) -> None:
            if Notice.said:
                return
            Notice.said = True
            stream = sys.stderr
            if stream is not None and getattr(stream, "isatty", lambda: False)():
                where = f" (cached in {folder})" if folder else ""
                stream.write(f"mutloc: compiling numerical kernels once{where}; this can take a minute\n")
                stream.flush()

        def on_end(self, ev: Any) -> None:
            pass

    event.register("numba:compile", Notice())


class _AfterNumbaImport:
    """A ``sys.meta_path`` finder that lets Numba load as usual, then calls
    :func:`_notice_on_compile` (Numba is not imported before it is needed)."""

    def __init__(self, folder: str | None) -> None:
        self.folder = folder

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != "numba":
            return None
        sys.meta_path.remove(self)
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        loader = getattr(spec, "loader", None)
        if loader is None or not hasattr(loader, "exec_module"):
            return spec
        run = loader.exec_module
        folder = self.folder

        def exec_module(module: Any) -> None:
            run(module)
            _notice_on_compile(module, folder)

        loader.exec_module = exec_module
        return spec


def announce_compiling(folder: str | None) -> None:
    """Say so on stderr when Numba compiles a kernel (once per process)."""
    numba = sys.modules.get("numba")
    if numba is not None:
        _notice_on_compile(numba, folder)
    elif not any(isinstance(f, _AfterNumbaImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterNumbaImport(folder))


CACHE_DIR = configure()
announce_compiling(CACHE_DIR)
