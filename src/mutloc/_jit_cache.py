"""Where Numba keeps mutloc's compiled kernels.

Numba's on-disk cache checks only the timestamp of the file that defines a
function, not of the functions it calls, so a kernel compiled against an older
version of a callee in another file is silently reused.  Keying the cache
folder on a hash of mutloc's own sources makes every change of the package
start from a clean cache, and keeps compiled code out of site-packages.
Imported by ``mutloc/__init__`` before any kernel is defined.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from pathlib import Path


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


CACHE_DIR = configure()
