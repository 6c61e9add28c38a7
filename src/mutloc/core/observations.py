"""The one observation set: what each robot's camera saw of the others' markers.

An observation says: at ``time``, robot ``observer``'s camera saw marker
``marker`` (of another robot) at raw, distorted pixel ``uv`` (SPEC pixel
convention), with a detector ``score``.  A marker may have several scored
candidates at one time (a detector that is unsure hands over each, and the
localizer picks what the mutual geometry supports); a marker of unknown
identity has ``marker=None``.

An :class:`ObservationSet` is built once at the edge -- from the SPEC's dict
(:meth:`ObservationSet.from_dict`), from detector output, or from records --
and validated there; everything after it (``localize``, the tracker, logs)
takes it without checking again.  :meth:`ObservationSet.check` ties it to a
rig (known robots and markers, no robot seeing its own marker, pixels on the
image) and :meth:`ObservationSet.pair` turns it into the solver's form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np

from ..errors import InputError, ObservationError, TooFewObservationsError

__all__ = ["Observation", "ObservationSet", "PairObservations", "MIN_OBSERVATIONS"]

#: A relative pose has six degrees of freedom and each marker gives two.
MIN_OBSERVATIONS = 3

#: Two or more observations of one camera all within this many pixels of
#: (0, 0) are not pixels: normalised coordinates or image fractions (a unit
#: mistake, as millimetres in a rig), unless the camera's principal point
#: is there too (a camera given in normalised units).
NOT_PIXELS_PX = 2.0


@dataclass(frozen=True)
class Observation:
    """One marker seen by one robot's camera (``marker=None``: identity unknown).

    ``sigma_scale``: this detection's noise relative to the stated
    ``pixel_sigma`` (a detector that knows a measurement is worse, e.g. a
    partly hidden ball, says so here; 1 for given pixels).
    """

    observer: str
    marker: str | None
    uv: tuple[float, float]
    time: float | None = None
    score: float = 1.0
    sigma_scale: float = 1.0


def _short(value: Any, limit: int = 60) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


_isfinite = math.isfinite


def _pixel(value: Any, where: str) -> tuple[float, float]:
    """Two finite numbers, else an ObservationError naming ``where``."""
    tv = type(value)
    if (tv is tuple or tv is list) and len(value) == 2:
        u, v = value
        if type(u) is float and type(v) is float and _isfinite(u) and _isfinite(v):
            return u, v  # the common case, checked in full below otherwise
    elif tv is np.ndarray and value.shape == (2,) and value.dtype == np.float64:
        u, v = value.tolist()
        if _isfinite(u) and _isfinite(v):
            return u, v
    if isinstance(value, np.ndarray):
        items = value.tolist() if value.ndim == 1 else None
    elif isinstance(value, (list, tuple)):
        items = value
    else:
        items = None
    if items is None or len(items) != 2 or any(isinstance(x, (bool, str, bytes)) for x in items):
        raise ObservationError(f"{where}: pixel must be two numbers [u, v], got {_short(value)}")
    try:
        u, v = float(items[0]), float(items[1])
    except (TypeError, ValueError, OverflowError):
        raise ObservationError(f"{where}: pixel must be two numbers [u, v], got {_short(value)}") from None
    if not (math.isfinite(u) and math.isfinite(v)):
        raise ObservationError(f"{where}: pixel must be finite, got {_short(value)}")
    return u, v


def _name(key: Any, kind: str, where: str) -> str:
    if type(key) is str and key.strip():
        return key
    if isinstance(key, bool) or not isinstance(key, (str, int, np.integer)) or str(key).strip() == "":
        raise ObservationError(f"{where}: {kind} name must be a non-empty string, got {_short(key)}")
    return str(key)


_ONES: dict[int, np.ndarray] = {}


def unit_scales(n: int) -> np.ndarray:
    """A read-only array of ``n`` ones (one per size, kept): the scales of a set built without, the
    weights of a problem without."""
    w = _ONES.get(n)
    if w is None:
        w = np.ones(n)
        w.flags.writeable = False
        if n <= 4096:
            _ONES[n] = w
    return w


class ObservationSet:
    """Observations keyed by (time, observer, marker); immutable.

    Columns: ``observer`` and ``marker`` (tuples of names; ``None`` for a
    marker of unknown identity), ``uv`` (n, 2) raw pixels, ``time`` (n,)
    seconds (NaN: untimed), ``score`` (n,) detector confidence (1 for given
    pixels), ``sigma_scale`` (n,) each detection's noise relative to the
    stated ``pixel_sigma`` (1 for given pixels; the solvers weigh each
    observation by its inverse and the covariance follows).  Iterating
    yields :class:`Observation` records.

    What is derived from the columns alone or with one rig (whether a marker
    has alternatives, a pair's solver form) is computed once and kept: a set
    localized again, or in every iteration of a filter, is not scanned again.
    """

    __slots__ = ("observer", "marker", "uv", "time", "score", "sigma_scale", "_memo")

    def __init__(self, observer: Sequence[str], marker: Sequence[str | None], uv: Any,
                 time: Any = None, score: Any = None, sigma_scale: Any = None) -> None:
        n = len(observer)
        uv = np.asarray(uv, dtype=float).reshape(-1, 2) if n else np.empty((0, 2))
        time = np.full(n, np.nan) if time is None else np.broadcast_to(np.asarray(time, float), (n,)).copy()
        score = np.ones(n) if score is None else np.broadcast_to(np.asarray(score, float), (n,)).copy()
        unit = sigma_scale is None
        scale = unit_scales(n) if unit else np.broadcast_to(np.asarray(sigma_scale, float), (n,)).copy()
        if len(marker) != n or uv.shape[0] != n:
            raise InputError(f"ObservationSet: {n} observers, {len(marker)} markers and {uv.shape[0]} pixels")
        if not np.all(np.isfinite(uv)):
            i = int(np.flatnonzero(~np.all(np.isfinite(uv), axis=1))[0])
            raise ObservationError(f"observations[{observer[i]!r}][{marker[i]!r}]: pixel must be finite")
        if np.any(np.isinf(time)) or np.any(~np.isfinite(score)):
            raise ObservationError("observations: times and scores must be finite")
        if not unit and not np.all(np.isfinite(scale) & (scale > 0.0)):
            raise ObservationError("observations: every sigma_scale must be finite and positive")
        uv.flags.writeable = False
        time.flags.writeable = False
        score.flags.writeable = False
        scale.flags.writeable = False
        for k, v in (("observer", tuple(observer)), ("marker", tuple(marker)), ("uv", uv), ("time", time),
                     ("score", score), ("sigma_scale", scale), ("_memo", {"unit": True} if unit else {})):
            object.__setattr__(self, k, v)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("ObservationSet is immutable")

    def __reduce__(self) -> tuple:
        return (ObservationSet, (self.observer, self.marker, self.uv, self.time, self.score, self.sigma_scale))

    # -- construction -------------------------------------------------------

    @classmethod
    def from_dict(cls, data: Any, *, time: float | None = None, where: str = "observations") -> "ObservationSet":
        """From the SPEC's form ``{observer: {marker: [u, v]}}`` (an observer may
        hold a list of ``[u, v]`` for markers of unknown identity).  An
        ObservationSet is returned unchanged."""
        if isinstance(data, ObservationSet):
            return data
        if not isinstance(data, (dict, Mapping)):
            raise ObservationError(
                f"{where}: expected a mapping {{observer: {{marker: [u, v]}}}}, got {type(data).__name__}")
        obs: list[str] = []
        mk: list[str | None] = []
        uv: list[tuple[float, float]] = []
        for okey, entries in data.items():
            observer = _name(okey, "observer", where)
            w = f"{where}[{observer!r}]"
            if isinstance(entries, (dict, Mapping)):
                for mkey, value in entries.items():
                    marker = _name(mkey, "marker", w)
                    obs.append(observer)
                    mk.append(marker)
                    uv.append(_pixel(value, f"{w}[{marker!r}]"))
            elif isinstance(entries, (list, tuple)) or (isinstance(entries, np.ndarray) and entries.ndim == 2):
                for i, value in enumerate(entries):
                    obs.append(observer)
                    mk.append(None)
                    uv.append(_pixel(value, f"{w}: point {i}"))
            else:
                raise ObservationError(
                    f"{w}: expected a mapping {{marker: [u, v]}} or a list of [u, v], got {_short(entries)}")
        return cls.trusted(obs, mk, uv, time)

    @classmethod
    def trusted(cls, observer: Sequence[str], marker: Sequence[str | None], uv: Any, time: Any = None,
                score: Any = None, sigma_scale: Any = None) -> "ObservationSet":
        """Build from columns already checked (finite pixels, times and scores, positive scales)."""
        n = len(observer)
        obj = cls.__new__(cls)
        uv = np.array(uv, dtype=float).reshape(n, 2)
        time = np.full(n, np.nan if time is None else float(time))
        score = np.ones(n) if score is None else np.asarray(score, dtype=float)
        unit = sigma_scale is None
        scale = unit_scales(n) if unit else np.asarray(sigma_scale, dtype=float)
        for k, v in (("observer", tuple(observer)), ("marker", tuple(marker)), ("uv", uv), ("time", time),
                     ("score", score), ("sigma_scale", scale), ("_memo", {"unit": True} if unit else {})):
            if isinstance(v, np.ndarray):
                v.flags.writeable = False
            object.__setattr__(obj, k, v)
        return obj

    @classmethod
    def from_records(cls, records: Iterable[Observation]) -> "ObservationSet":
        """From :class:`Observation` records (pixels checked here)."""
        recs = list(records)
        uv = [_pixel(r.uv, f"observations[{r.observer!r}][{r.marker!r}]") for r in recs]
        return cls([r.observer for r in recs], [r.marker for r in recs], uv,
                   [np.nan if r.time is None else r.time for r in recs], [r.score for r in recs],
                   [r.sigma_scale for r in recs])

    @classmethod
    def concatenate(cls, sets: Sequence["ObservationSet"]) -> "ObservationSet":
        """One set from several (e.g. one per observer or per frame)."""
        sets = [s for s in sets if len(s)]
        if not sets:
            return cls((), (), np.empty((0, 2)))
        return cls(sum((s.observer for s in sets), ()), sum((s.marker for s in sets), ()),
                   np.concatenate([s.uv for s in sets]), np.concatenate([s.time for s in sets]),
                   np.concatenate([s.score for s in sets]),
                   None if all(s._memo.get("unit") for s in sets) else np.concatenate([s.sigma_scale for s in sets]))

    # -- a collection -------------------------------------------------------

    def __len__(self) -> int:
        return len(self.observer)

    def __iter__(self) -> Iterator[Observation]:
        for i in range(len(self)):
            t = float(self.time[i])
            yield Observation(self.observer[i], self.marker[i], (float(self.uv[i, 0]), float(self.uv[i, 1])),
                              None if math.isnan(t) else t, float(self.score[i]), float(self.sigma_scale[i]))

    def __eq__(self, other: object) -> bool:
        """Same observations in the same order (a mapping is read as the SPEC's form)."""
        if isinstance(other, Mapping):
            try:
                other = ObservationSet.from_dict(other)
            except ObservationError:
                return False
        if not isinstance(other, ObservationSet):
            return NotImplemented
        return (self.observer == other.observer and self.marker == other.marker
                and np.array_equal(self.uv, other.uv) and np.array_equal(self.time, other.time, equal_nan=True)
                and np.array_equal(self.score, other.score) and np.array_equal(self.sigma_scale, other.sigma_scale))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"ObservationSet({len(self)} observations by {sorted(set(self.observer))})"

    def take(self, index: Any) -> "ObservationSet":
        """The rows ``index`` (indices or a boolean mask)."""
        idx = np.arange(len(self))[index]
        return ObservationSet([self.observer[i] for i in idx], [self.marker[i] for i in idx], self.uv[idx],
                              self.time[idx], self.score[idx], self.scales_of(idx))

    @property
    def observers(self) -> list[str]:
        """The observing robots, in first-seen order."""
        return list(dict.fromkeys(self.observer))

    @property
    def times(self) -> np.ndarray:
        """The distinct times, sorted (NaN, untimed, excluded)."""
        t = self.time[~np.isnan(self.time)]
        return np.unique(t)

    def at_time(self, t: float) -> "ObservationSet":
        """The observations made at time ``t``."""
        return self.take(self.time == t)

    def with_time(self, t: float | None) -> "ObservationSet":
        """The same observations stamped with time ``t``."""
        return ObservationSet(self.observer, self.marker, self.uv, np.nan if t is None else t, self.score,
                              self.scales_of())

    def scales_of(self, idx: Any = None) -> np.ndarray | None:
        """The ``sigma_scale`` of rows ``idx`` (None: all rows), or None for a set built without scales
        (every one 1): what a solver needs to know without looking at every row."""
        if self._memo.get("unit"):
            return None
        return self.sigma_scale if idx is None else self.sigma_scale[idx]

    def with_sigma_scale(self, scale: Any) -> "ObservationSet":
        """The same observations with each one's ``sigma_scale`` (a number for all, one per row, or None:
        1 for all, what an observations file, an observation log or the live message can hold)."""
        return ObservationSet(self.observer, self.marker, self.uv, self.time, self.score, scale)

    def best(self) -> "ObservationSet":
        """One candidate per (time, observer, marker): the highest-scored
        (markers of unknown identity are all kept)."""
        seen: dict[tuple, int] = {}
        keep: list[int] = []
        for i in range(len(self)):
            if self.marker[i] is None:
                keep.append(i)
                continue
            key = (self.time[i] if not math.isnan(self.time[i]) else None, self.observer[i], self.marker[i])
            j = seen.get(key)
            if j is None:
                seen[key] = len(keep)
                keep.append(i)
            elif self.score[i] > self.score[keep[j]]:
                keep[j] = i
        if len(keep) == len(self):
            return self
        return self.take(np.array(keep, dtype=np.int64))

    @property
    def has_alternatives(self) -> bool:
        """Whether some marker has more than one candidate at one time."""
        alt = self._memo.get("alternatives")
        if alt is None:
            alt = self._memo["alternatives"] = len(self.best()) != len(self)
        return alt

    def to_dict(self) -> dict[str, Any]:
        """The SPEC's form ``{observer: {marker: (u, v)}}`` (best candidates;
        markers of unknown identity as a list of ``(u, v)``)."""
        out: dict[str, Any] = {}
        best = self.best()
        for o, m, (u, v) in zip(best.observer, best.marker, best.uv.tolist()):
            if m is None:
                entry = out.setdefault(o, [])
                if isinstance(entry, dict):
                    raise ObservationError(f"observations[{o!r}]: named and unnamed markers cannot share one dict")
                entry.append((u, v))
            else:
                out.setdefault(o, {})[m] = (u, v)
        return out

    # -- against a rig ------------------------------------------------------

    def check(self, rig: Any) -> "ObservationSet":
        """Raise ObservationError (naming observer and marker) for an unknown
        robot or marker, a robot seeing its own marker, or a pixel far outside
        the observer's image, or pixels that are not pixels (see
        :func:`_check_pixels`); returns ``self``."""
        rows: dict[str, list[int]] = {}
        for i in range(len(self)):
            o, m = self.observer[i], self.marker[i]
            where = f"observations[{o!r}]" + ("" if m is None else f"[{m!r}]")
            robot = rig.observer(o)[0]
            if m is not None:
                owner = rig.owner(m)
                if owner == robot:
                    raise ObservationError(f"{where}: robot {robot!r} cannot observe its own marker {m!r}")
            rows.setdefault(o, []).append(i)
        for o, idx in rows.items():
            camera = rig.mount(o).camera
            _check_pixels(self, idx, camera.K, camera.size)
        return self

    def pair(self, rig: Any, source: str, target: str) -> "PairObservations":
        """The observations between ``source`` (p) and ``target`` (q) in
        solver form, checked against the rig on the way (unknown robot or
        marker, a robot seeing its own marker, a pixel far outside the image:
        ObservationError naming observer and marker).  Rows of markers of
        unknown identity are returned apart; other robots' rows are skipped.
        Kept for the last rig asked about (rigs, like sets, are not changed
        once built)."""
        key = ("pair", source, target)
        hit = self._memo.get(key)
        if hit is not None and hit[0] is rig:
            return _with_parent(hit[1], self)
        result = self._pair(rig, source, target)
        if result.parent is self:
            # Kept without its parent: a set holding a pair that holds the set
            # is a reference cycle, and a set used once and dropped (a frame,
            # a dict turned into a set) would then wait for the cyclic garbage
            # collector instead of being freed at once.  What the solver reads
            # is computed now, so every pair handed out has it.
            result.points, result.uv, result.names, result.count  # noqa: B018
            template = _with_parent(result, None)
        else:
            template = result  # of the set of best candidates, not of this one
        self._memo[key] = (rig, template)
        return result

    def _pair(self, rig: Any, source: str, target: str) -> "PairObservations":
        """:meth:`pair` without the memo: rows keyed by an observer of the pair (``ROBOT``, or ``ROBOT/CAMERA``
        for a robot with several cameras), each camera's checked against its own image."""
        table = rig.pair_table(source, target)
        index, observers = table.index, table.observers
        side: list[int] = []
        prow: list[int] = []
        rows: list[int] = []
        anonymous: dict[int, list[int]] = {}
        seen: set[tuple[str, str]] = set()
        duplicates = False
        per_camera: dict[str, list[int]] = {}
        for i, (o, m) in enumerate(zip(self.observer, self.marker)):
            entry = observers.get(o)
            if entry is None:
                robot, _ = rig.observer(o)  # unknown robot or camera: raises
                if m is not None and rig.owner(m) == robot:
                    raise ObservationError(f"observations[{o!r}][{m!r}]: robot {robot!r} cannot observe its own "
                                           f"marker {m!r}")
                continue  # a third robot's camera
            s = entry[0]
            per_camera.setdefault(o, []).append(i)
            if m is None:
                anonymous.setdefault(s, []).append(i)
                continue
            mark = index.get(m)
            if mark is None:
                rig.owner(m)  # unknown marker: raises; else a third robot's marker
                continue
            if mark[0] != s:
                raise ObservationError(f"observations[{o!r}][{m!r}]: robot {(source, target)[s]!r} cannot observe "
                                       f"its own marker {m!r}")
            if (o, m) in seen:
                duplicates = True
            seen.add((o, m))
            side.append(s)
            prow.append(mark[1])
            rows.append(i)
        for o, idx in per_camera.items():
            _, K, size = observers[o]
            _check_pixels(self, idx, K, size)
        if duplicates and not np.all(np.isnan(self.time)) and len(self.times) > 1:
            raise ObservationError("observations of several times: localize one frame at a time (at_time)")
        if duplicates:
            return self.best().pair(rig, source, target)
        scale = self.scales_of(rows)
        if scale is not None:
            scale = None if np.all(scale == 1.0) else np.ascontiguousarray(scale)
        return PairObservations(self, source, target, np.array(side, dtype=np.int64), np.array(prow, dtype=np.int64),
                                np.array(rows, dtype=np.int64), anonymous, table, scale)


def _check_pixels(obs: ObservationSet, rows: Sequence[int], K: np.ndarray, size: tuple[int, int] | None,
                  pts: list[list[float]] | None = None) -> None:
    """ObservationError unless the rows ``rows`` (one camera's observations,
    of intrinsics ``K`` and image ``size``) look like raw pixels: each within
    half an image of the image (noise may push a detection just past the
    border; only a pixel far outside -- wrong camera, swapped u/v, wrong
    units -- is wrong), and not all near (0, 0) (:data:`NOT_PIXELS_PX`).
    An image of unknown size is checked for the second only.  ``pts``: the
    rows' pixels as lists, if the caller has them."""
    if not len(rows):
        return
    # A few rows per frame, checked for every frame a tracker sees: plain floats are faster than array ops.
    if pts is None:
        pts = obs.uv[rows].tolist()
    near = len(pts) >= 2
    for k, (u, v) in enumerate(pts):
        if size is not None and not (-0.5 * size[0] <= u <= 1.5 * size[0] and -0.5 * size[1] <= v <= 1.5 * size[1]):
            o, m = obs.observer[rows[k]], obs.marker[rows[k]]
            where = f"observations[{o!r}]" + ("" if m is None else f"[{m!r}]")
            raise ObservationError(f"{where}: pixel ({u:.2f}, {v:.2f}) is outside the {size[0]}x{size[1]} image "
                                   "(observations are raw pixels)")
        if near and not (abs(u) <= NOT_PIXELS_PX and abs(v) <= NOT_PIXELS_PX):
            near = False
    if near and math.hypot(float(K[0, 2]), float(K[1, 2])) > 4 * NOT_PIXELS_PX:
        raise ObservationError(f"observations[{obs.observer[rows[0]]!r}]: all {len(pts)} pixels are within "
                               f"{NOT_PIXELS_PX:g} px of (0, 0): not pixels (normalised coordinates or image "
                               "fractions given?); observations are raw pixels")


def outside_by(u: float, v: float, size: tuple[int, int]) -> float:
    """How far (px) the pixel ``(u, v)`` lies outside an image of ``size``
    (width, height; pixel centres at integers, so the image spans -0.5 to
    width - 0.5); 0 inside."""
    du = max(-0.5 - u, u - (size[0] - 0.5), 0.0)
    dv = max(-0.5 - v, v - (size[1] - 0.5), 0.0)
    return math.hypot(du, dv)


def _with_parent(pair: "PairObservations", parent: ObservationSet | None) -> "PairObservations":
    """A copy of ``pair`` (and what it has computed) whose parent is ``parent``
    (a parent-less copy keeps nothing of its set alive); a pair whose parent
    is another set is returned as is."""
    if pair.parent is not None and parent is not None:
        return pair
    obj = object.__new__(PairObservations)
    obj.__dict__.update(pair.__dict__)
    obj.__dict__["parent"] = parent
    return obj


@dataclass(frozen=True)
class PairObservations:
    """The observations between robots p (``source``) and q (``target``):
    ``side[k]`` is 0 when p saw marker ``names[k]`` of q, 1 when q saw p's;
    ``rows`` index the parent set.  ``anonymous`` maps a side to the rows of
    markers of unknown identity it saw."""

    parent: ObservationSet
    source: str
    target: str
    side: np.ndarray
    points_index: np.ndarray
    rows: np.ndarray
    anonymous: dict[int, list[int]]
    table: Any
    #: (n,) each row's noise relative to the stated pixel sigma, or None when all are 1.
    sigma_scale: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        """The observed markers' names, row by row."""
        return list(self._names)

    @cached_property
    def _names(self) -> tuple[str, ...]:
        return tuple(self.parent.marker[i] for i in self.rows.tolist())

    @cached_property
    def points(self) -> np.ndarray:
        """(n, 3) position of each row's marker in its owner's frame (shared: do not modify)."""
        return np.ascontiguousarray(self.table.points[self.points_index])

    @cached_property
    def uv(self) -> np.ndarray:
        """(n, 2) each row's raw pixel (shared: do not modify)."""
        return np.ascontiguousarray(self.parent.uv[self.rows])

    @cached_property
    def count(self) -> int:
        """Observations between the pair, named and anonymous."""
        return len(self.rows) + sum(len(v) for v in self.anonymous.values())

    def farthest_outside(self, margin: float = 0.0) -> tuple[int, float, tuple[int, int]] | None:
        """``(k, px, size)``: the row whose pixel lies farthest outside its
        camera's image (of ``size``), by ``px`` > ``margin``; None when every
        pixel is within ``margin`` of its image (or no image size is known).
        Such a pixel passes :meth:`ObservationSet.check` (a detection may
        lie a little past the border) but is the first suspect when the
        observations do not fit one pose."""
        best = None
        for k, (s, i) in enumerate(zip(self.side.tolist(), self.rows.tolist())):
            if self.table.mounts is not None:
                size = self.table.mounts[self.parent.observer[i]][1].camera.size
            else:
                size = self.table.sizes[s]
            if size is None:
                continue
            px = outside_by(*self.parent.uv[i].tolist(), size)
            if px > margin and (best is None or px > best[1]):
                best = (k, px, tuple(size))
        return best

    def require(self, needed: int = MIN_OBSERVATIONS) -> None:
        """TooFewObservationsError unless at least ``needed`` observations tie the pair."""
        if self.count < needed:
            # observers keyed ROBOT or ROBOT/CAMERA: each robot's rows whatever camera saw them
            seen = {r: [self.parent.marker[i] or "?" for i in range(len(self.parent))
                        if self.parent.observer[i].split("/", 1)[0] == r and (i in self.rows or
                                                                               i in self.anonymous.get(k, ()))]
                    for k, r in enumerate((self.source, self.target))}
            found = ", ".join(f"{r} saw {sorted(v)}" for r, v in seen.items())
            raise TooFewObservationsError(
                f"{self.count} marker observation{'s' if self.count != 1 else ''} between {self.source!r} "
                f"and {self.target!r} ({found}); at least {needed} are needed")
