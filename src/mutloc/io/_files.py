"""Shared helpers of :mod:`mutloc.io`: reading YAML/JSON with one-line errors,
checking plain-data numbers, converting results to JSON-able builtins.

Private: the public readers and writers are in :mod:`mutloc.io.rig`,
:mod:`mutloc.io.observations` and :mod:`mutloc.io.results`.
"""

from __future__ import annotations

import json
import math
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np
import yaml

from ..errors import FileFormatError, InputError

PathLike = str | os.PathLike

__all__ = [
    "PathLike",
    "is_path",
    "read_text",
    "parse_text",
    "load_file",
    "is_number",
    "as_float_array",
    "as_rotation",
    "ROTATION_TOL",
    "short",
    "one_line",
    "key_name",
    "to_builtin",
    "output_folder",
    "writable_path",
]


def output_folder(path: PathLike, create: bool = True, what: str = "") -> Path:
    """``path`` as a folder to write into (created if missing and
    ``create``); a one-line error if it, or a folder above it, is a file, or
    nothing can be written there (``what``: the option, for the message)."""
    p = writable_path(path, what, folder=True)
    if create:
        p.mkdir(parents=True, exist_ok=True)
    return p


def writable_path(path: PathLike, what: str = "", *, folder: bool = False, new: bool = False) -> Path:
    """``path`` checked for writing before any work: FileFormatError in one
    line (naming ``what``, e.g. the option) if a folder above it is a file,
    it is a folder and a file is wanted (or the reverse), it exists and
    ``new`` is asked, or the place refuses a file (read-only, ``/proc``, no
    permission: tried with a probe file, removed at once).  Nothing is
    created: missing folders are made by the writer."""
    p = Path(path).expanduser()
    label = f" ({what})" if what else ""
    tail = f" ({what} {p})" if what else f" (writing {p})"
    for d in p.parents:
        if d.exists() and not d.is_dir():
            raise FileFormatError(f"{d}: exists and is not a folder{tail}")
    if p.exists() or p.is_symlink():
        if new:
            raise FileFormatError(f"{p}: already exists{label}: give a new path")
        if folder and not p.is_dir():
            raise FileFormatError(f"{p}: exists and is not a folder{tail}")
        if not folder and p.is_dir():
            raise FileFormatError(f"{p}: is a folder, not a file{label}")
    place = p if p.exists() else next(d for d in p.parents if d.exists())
    try:
        if p.is_file():
            with open(p, "ab"):
                pass
        else:
            fd, probe = tempfile.mkstemp(prefix=".mutloc-probe-", dir=place)
            os.close(fd)
            os.unlink(probe)
    except OSError as exc:
        where = "" if place == p else f"nothing can be created in {place}: "
        raise FileFormatError(f"{p}: cannot be written{label}: {where}{exc.strerror or exc}") from None
    return p


def is_path(source: Any) -> bool:
    """True for ``str`` / ``os.PathLike`` (what the loaders read as a file)."""
    return isinstance(source, (str, os.PathLike))


def one_line(text: Any) -> str:
    """``text`` with every run of whitespace (newlines included) turned into one space."""
    return " ".join(str(text).split())


def short(value: Any, limit: int = 60) -> str:
    """A short ``repr`` of ``value`` for error messages."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    r = one_line(repr(value))
    return r if len(r) <= limit else r[: limit - 3] + "..."


# ---------------------------------------------------------------------------
# YAML / JSON parsing
# ---------------------------------------------------------------------------

# PyYAML follows YAML 1.1, where ``1e-3`` (no dot) is a *string*; accept the
# YAML 1.2 / JSON spelling of floats too so ``position: [1e-3, 0, 2]`` works.
_FLOAT_RE = re.compile(
    r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
    re.X,
)


class _DuplicateKey(Exception):
    def __init__(self, key: Any, line: int | None):
        super().__init__(key, line)
        self.key = key
        self.line = line


class _Loader(yaml.SafeLoader):
    """Safe YAML loader that rejects duplicate keys and reads ``1e-3`` as a float."""

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict:
        if isinstance(node, yaml.MappingNode):
            seen: set = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue
                key = self.construct_object(key_node, deep=deep)
                try:
                    dup = key in seen
                except TypeError:  # unhashable: the base class reports it
                    continue
                if dup:
                    raise _DuplicateKey(key, key_node.start_mark.line + 1)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_RE, list("-+0123456789."))


def _json_pairs(pairs: list[tuple[str, Any]]) -> dict:
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(k, None)
        out[k] = v
    return out


# Rig, calibration and observation files are small; anything larger (or a
# device such as /dev/zero, which never ends) is not one of them.
MAX_TEXT_BYTES = 16 * 1024 * 1024


def read_text(path: Path, where: str, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of ``path`` (at most ``limit`` bytes); FileFormatError
    (one line) if it cannot be read or is larger."""
    try:
        if path.is_dir():
            raise FileFormatError(f"{where}: is a folder, not a file")
        with open(path, "rb") as f:
            data = f.read(limit + 1)
        if len(data) > limit:
            raise FileFormatError(f"{where}: larger than {limit // (1024 * 1024)} MiB: not a mutloc input file")
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FileFormatError(f"{where}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        reason = exc.strerror or one_line(exc)
        raise FileFormatError(f"{where}: cannot read file: {reason}") from None


def parse_text(text: str, where: str, *, as_json: bool, duplicate_error: type[InputError]) -> Any:
    """Parse YAML (or strict JSON when ``as_json``) text.

    Syntax errors raise FileFormatError; a key repeated in one mapping raises
    ``duplicate_error`` (it would otherwise silently replace the first one).
    """
    try:
        if as_json:
            return json.loads(text, object_pairs_hook=_json_pairs)
        return yaml.load(text, Loader=_Loader)  # noqa: S506 -- _Loader is a SafeLoader
    except _DuplicateKey as exc:
        at = f" (line {exc.line})" if exc.line is not None else ""
        raise duplicate_error(f"{where}: duplicate key {exc.key!r}{at}") from None
    except json.JSONDecodeError as exc:
        raise FileFormatError(
            f"{where}: invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}"
        ) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or one_line(exc)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise FileFormatError(f"{where}: invalid YAML{at}: {one_line(problem)}") from None
    except RecursionError:
        raise FileFormatError(f"{where}: document is nested too deeply") from None


def load_file(path: Path, where: str, *, duplicate_error: type[InputError]) -> Any:
    """Read and parse a YAML or JSON file (JSON when the name ends in ``.json``)."""
    text = read_text(path, where)
    return parse_text(text, where, as_json=path.suffix.lower() == ".json", duplicate_error=duplicate_error)


# ---------------------------------------------------------------------------
# plain-data checks
# ---------------------------------------------------------------------------


def is_number(x: Any) -> bool:
    """A real number (int/float or numpy scalar), but not a bool."""
    if isinstance(x, (bool, np.bool_)):
        return False
    return isinstance(x, (int, float, np.integer, np.floating))


def _nested_numbers(v: Any) -> bool:
    if is_number(v):
        return True
    if isinstance(v, (list, tuple)):
        return all(_nested_numbers(x) for x in v)
    if isinstance(v, np.ndarray):
        return v.dtype.kind in "iuf"
    return False


def as_float_array(value: Any) -> np.ndarray | None:
    """``value`` (number, nested lists/tuples of numbers, or numeric ndarray) as a
    float array; None if it holds anything else (strings, bools, None, ragged)."""
    if isinstance(value, np.ndarray):
        return value.astype(float) if value.dtype.kind in "iuf" else None
    if not _nested_numbers(value):
        return None
    try:
        return np.array(value, dtype=float)
    except (ValueError, TypeError, OverflowError):
        return None


#: A rotation read from a file may be off orthonormal by this much (rounding); it is then made exact.
ROTATION_TOL = 1e-6


def as_rotation(R: np.ndarray) -> np.ndarray | None:
    """``R`` (3x3, finite) as an exact rotation if it is one within
    :data:`ROTATION_TOL` (orthonormal, determinant +1): the nearest rotation
    (polar factor) when off by rounding, ``R`` itself when exact; else None."""
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        return None
    off = float(np.abs(R @ R.T - np.eye(3)).max())
    if off > ROTATION_TOL or np.linalg.det(R) <= 0.0:
        return None
    if off <= 1e-15:
        return R
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def key_name(key: Any) -> str | None:
    """A mapping key usable as a robot/marker name: a non-empty string, or an
    integer (YAML reads ``1:`` as one) turned into its string; else None."""
    if isinstance(key, str):
        return key if key.strip() else None
    if isinstance(key, (int, np.integer)) and not isinstance(key, (bool, np.bool_)):
        return str(int(key))
    return None


def named_items(mapping: Mapping, kind: str, where: str, error: type[Exception]) -> Iterator[tuple[str, Any]]:
    """``(name, value)`` of a mapping keyed by robot/marker names, rejecting
    keys that are not names and names given twice (after ``key_name``)."""
    seen: set[str] = set()
    for key, value in mapping.items():
        name = key_name(key)
        if name is None:
            raise error(f"{where}: {kind} name must be a non-empty string, got {key!r}")
        if name in seen:
            raise error(f"{where}: {kind} {name!r} given twice")
        seen.add(name)
        yield name, value


# ---------------------------------------------------------------------------
# JSON-able conversion
# ---------------------------------------------------------------------------


def to_builtin(obj: Any, *, nonfinite_to_none: bool = False) -> Any:
    """``obj`` as plain JSON/YAML data: numpy arrays and scalars become lists and
    Python numbers, tuples/sets lists, paths strings, objects with ``to_dict()``
    their dict.  With ``nonfinite_to_none`` NaN/inf become None (strict JSON)."""

    def conv(o: Any) -> Any:
        if isinstance(o, Mapping):
            return {(k if isinstance(k, str) else str(conv(k))): conv(v) for k, v in o.items()}
        if isinstance(o, np.ndarray):
            return conv(o.tolist())
        if isinstance(o, (list, tuple, set, frozenset)):
            return [conv(x) for x in o]
        if isinstance(o, np.generic):
            return conv(o.item())
        if isinstance(o, bool) or o is None or isinstance(o, (int, str)):
            return o
        if isinstance(o, float):
            if nonfinite_to_none and not math.isfinite(o):
                return None
            return o
        if isinstance(o, os.PathLike):
            return os.fspath(o)
        to_dict = getattr(o, "to_dict", None)
        if callable(to_dict):
            return conv(to_dict())
        if isinstance(o, complex):
            return [conv(o.real), conv(o.imag)]
        return str(o)

    return conv(obj)
