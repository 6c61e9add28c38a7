"""Reading observation files (JSON or YAML), see SPEC "Observations file".

Only the structure is checked here (there is no rig): whether the markers
exist, belong to the other robot, are enough, ... is checked against the rig
by :func:`mutloc.localize` (:meth:`ObservationSet.check`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from ..core.observations import ObservationSet
from ..errors import ObservationError
from ._files import PathLike, is_path, load_file

__all__ = ["load_observations"]


def load_observations(source: PathLike | Mapping[str, Any] | ObservationSet) -> ObservationSet:
    """An :class:`ObservationSet` from a JSON/YAML file path or a mapping in the
    SPEC's form ``{observer: {marker: [u, v]}}`` (an observer may hold a list
    of ``[u, v]`` for markers of unknown identity).

    Raises FileFormatError for an unreadable/unparsable file and
    ObservationError (naming file, observer and marker) for a wrong structure
    or a pixel that is not two finite numbers.
    """
    if isinstance(source, ObservationSet):
        return source
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
    return ObservationSet.from_dict(data, where=where)
