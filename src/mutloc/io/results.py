"""Writing results as JSON (what the command line prints)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from ._files import PathLike, to_builtin

__all__ = ["write_json", "dumps_json"]


def dumps_json(obj: Any) -> str:
    """``obj`` as strict JSON text (indent 2, trailing newline).

    numpy arrays/scalars become lists/numbers, objects with ``to_dict()`` their
    dict, and NaN/inf become ``null`` (JSON has no such numbers).
    """
    return json.dumps(to_builtin(obj, nonfinite_to_none=True), indent=2, allow_nan=False) + "\n"


def write_json(obj: Any, path: PathLike | None = None) -> None:
    """Write ``obj`` as JSON to ``path``, or to stdout when ``path`` is None or
    ``"-"``.  Missing parent folders are created; OSError propagates."""
    text = dumps_json(obj)
    if path is None or str(path) == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    p = Path(path).expanduser()
    if p.parent != Path(""):
        p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding="utf-8")
