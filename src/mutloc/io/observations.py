"""Reading observation files (JSON or YAML), see SPEC "Observations file".

Only the structure is checked here (there is no rig): whether the markers
exist, belong to the other robot, are enough, ... is checked by
:func:`mutloc.localize`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping, Union

import numpy as np

from ..errors import ObservationError
from ._files import PathLike, is_number, is_path, load_file, named_items, short

__all__ = ["load_observations", "Pixel", "Observations"]

Pixel = tuple[float, float]
#: ``{observer: {marker: (u, v)}}``; an observer may instead hold a list of
#: ``(u, v)`` for markers of unknown identity.
Observations = dict[str, Union[dict[str, Pixel], list[Pixel]]]


def load_observations(source: PathLike | Mapping[str, Any]) -> Observations:
    """Load observations from a JSON/YAML file path or a mapping.

    Returns ``{observer: {marker: (u, v)}}`` with plain Python floats; an
    observer whose value is a list of ``[u, v]`` pairs (markers of unknown
    identity) gives a list of ``(u, v)`` tuples.  Raises FileFormatError for an
    unreadable/unparsable file and ObservationError (naming observer and
    marker) for a wrong structure or a pixel that is not two finite numbers.
    """
    if is_path(source):
        where = str(source)
        data = load_file(Path(source).expanduser(), where, duplicate_error=ObservationError)
    elif isinstance(source, Mapping):
        where = "observations"
        data = source
    else:
        raise ObservationError(
            f"observations must be a file path or a mapping {{observer: {{marker: [u, v]}}}}, "
            f"got {type(source).__name__}"
        )
    if data is None:
        raise ObservationError(f"{where}: empty (expected a mapping {{observer: {{marker: [u, v]}}}})")
    if not isinstance(data, Mapping):
        raise ObservationError(
            f"{where}: expected a mapping {{observer: {{marker: [u, v]}}}}, got {type(data).__name__}"
        )

    out: Observations = {}
    for observer, oval in named_items(data, "observer", where, ObservationError):
        w = f"{where}: observer {observer!r}"
        if isinstance(oval, Mapping):
            out[observer] = {marker: _pixel(pix, f"{w}: marker {marker!r}")
                             for marker, pix in named_items(oval, "marker", w, ObservationError)}
        elif isinstance(oval, (list, tuple)) or (isinstance(oval, np.ndarray) and oval.ndim == 2):
            out[observer] = [_pixel(pix, f"{w}: point {i}") for i, pix in enumerate(oval)]
        else:
            raise ObservationError(
                f"{w}: expected a mapping {{marker: [u, v]}} or a list of [u, v], got {short(oval)}"
            )
    return out


def _pixel(value: Any, w: str) -> Pixel:
    if isinstance(value, np.ndarray):
        items = value.tolist() if value.ndim == 1 else None
    elif isinstance(value, (list, tuple)):
        items = list(value)
    else:
        items = None
    if items is None or len(items) != 2 or not all(is_number(x) for x in items):
        raise ObservationError(f"{w}: pixel must be two numbers [u, v], got {short(value)}")
    u, v = float(items[0]), float(items[1])
    if not (math.isfinite(u) and math.isfinite(v)):
        raise ObservationError(f"{w}: pixel must be finite, got {short(value)}")
    return (u, v)
