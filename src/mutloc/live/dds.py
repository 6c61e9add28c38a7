"""One DDS participant with ROS 2's conventions: topics ``rt/<ros topic>``,
QoS reliable, volatile, keep-last 10 (SPEC "Live operation").

``Bus(domain)`` joins DDS domain ``domain`` (ROS 2's ``ROS_DOMAIN_ID``);
``loopback=True`` keeps it on this machine (the loopback interface, unicast
discovery: what tests and ``demo --live`` use).  Otherwise Cyclone DDS's own
configuration applies (``CYCLONEDDS_URI``; see the guide "Running on your
robots" for isolating a domain and DDS Security).

A reader's :meth:`Reader.take` returns the valid samples and counts the
samples it could not decode (malformed bytes on the topic) instead of
raising: a network message is input, and bad input never stops a node.
"""

from __future__ import annotations

from functools import cache
from typing import Any, Callable

from .._extras import require
from ..errors import InputError
from .messages import dds_topic, observations_from_cdr, ros_types

__all__ = ["Bus", "Reader", "LOOPBACK_CONFIG", "HISTORY_DEPTH", "WRITE_MAX_BLOCKING", "check_domain"]

#: ROS 2's default QoS profile for topics: keep-last 10, reliable, volatile.
HISTORY_DEPTH = 10
#: Nanoseconds a reliable writer's ``write`` may block (never, for a keep-last writer in Cyclone DDS:
#: only a keep-all writer waits for acknowledgements; not part of QoS matching).
WRITE_MAX_BLOCKING = 10_000_000

#: Cyclone DDS on the loopback interface only, peers found by unicast on 127.0.0.1.
LOOPBACK_CONFIG = (
    "<CycloneDDS><Domain><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General>"
    "<Discovery><Peers><Peer address=\"127.0.0.1\"/></Peers><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex></Discovery></Domain></CycloneDDS>")


def check_domain(domain: Any) -> int:
    """A DDS domain id (ROS 2 allows 0-232 on Linux; 0-101 keep clear of ephemeral ports)."""
    try:
        d = int(domain)
    except (TypeError, ValueError):
        raise InputError(f"--domain must be an integer from 0 to 232, got {domain!r}") from None
    if not 0 <= d <= 232 or str(domain).strip() not in (str(d), f"+{d}"):
        raise InputError(f"--domain must be an integer from 0 to 232, got {domain!r}")
    return d


class Reader:
    """A topic's reader: :meth:`take` returns decoded samples, counting the undecodable ones in :attr:`malformed`.

    ``decode``: bytes (CDR with its encapsulation header) to a message,
    raising for bytes that are not one (default: the type's own
    ``deserialize``).  The samples are taken from DDS in one call as bytes and
    decoded here one by one, so that each undecodable sample is counted and
    skipped while the others are kept."""

    def __init__(self, reader: Any, decode: Callable[[bytes], Any] | None = None) -> None:
        self._reader = reader
        self._decode = decode if decode is not None else reader.topic.data_type.deserialize
        self._take_raw, self._mask = _raw_take()
        self.malformed = 0

    def take(self, limit: int = 256) -> list[Any]:
        """Up to ``limit`` waiting samples, oldest first (never blocks)."""
        if self._take_raw is None:
            return self._take_one_by_one(limit)
        out: list[Any] = []
        for data, info in self.take_bytes(limit):
            sample = self.decode(data, info)
            if sample is not None:
                out.append(sample)
        return out

    def take_bytes(self, limit: int = 256) -> list[tuple[bytes, Any]]:
        """Up to ``limit`` waiting samples as ``(CDR bytes, sample info)``, oldest first, not
        decoded (:meth:`decode` each one kept); empty when this binding cannot take bytes
        (:attr:`raw`)."""
        if self._take_raw is None:
            return []
        got = self._take_raw(self._reader._ref, self._mask, limit)
        if isinstance(got, int):  # a DDS error code (not the data's fault)
            from cyclonedds.core import DDSException

            raise DDSException(got, f"Occurred while taking data in {self._reader!r}")
        return [(data, info) for data, info in got if info.valid_data]  # (else a writer gone: no data)

    @property
    def raw(self) -> bool:
        """Whether :meth:`take_bytes` can take samples undecoded."""
        return self._take_raw is not None

    def decode(self, data: bytes, info: Any = None) -> Any:
        """A sample from its bytes (``info``: its sample info, set on it), or None -- counted in
        :attr:`malformed` -- for bytes that do not decode."""
        try:
            sample = self._decode(data)
        except Exception:  # noqa: BLE001 -- bytes that do not decode: counted, never raised
            self.malformed += 1
            return None
        sample.sample_info = info
        return sample

    def _take_one_by_one(self, limit: int) -> list[Any]:
        # (a binding without the raw take: its own take decodes, a sample at a
        # time so that one that fails is the only one lost)
        out: list[Any] = []
        for _ in range(limit):
            try:
                got = self._reader.take(N=1)
            except Exception:  # noqa: BLE001 -- bytes that do not decode: counted, never raised
                self.malformed += 1
                continue
            if not got:
                break
            sample = got[0]
            if getattr(getattr(sample, "sample_info", None), "valid_data", True):
                out.append(sample)
        return out

    @property
    def native(self) -> Any:
        """The cyclonedds DataReader (for waitsets and listeners)."""
        return self._reader


def _reliable(depth: int, max_blocking: int = 100_000_000) -> Any:
    """Reliable, volatile, keep-last ``depth`` (``max_blocking``: ns a writer's ``write`` may wait)."""
    from cyclonedds.core import Policy, Qos

    return Qos(Policy.Reliability.Reliable(max_blocking_time=max_blocking), Policy.Durability.Volatile,
               Policy.History.KeepLast(depth))


@cache
def _raw_take() -> tuple[Callable[..., Any] | None, int]:
    try:
        from cyclonedds._clayer import ddspy_take
        from cyclonedds.core import InstanceState, SampleState, ViewState
    except ImportError:  # (the binding's internals moved: the public take, one sample at a time)
        return None, 0
    return ddspy_take, SampleState.Any | ViewState.Any | InstanceState.Any


class Bus:
    """A DDS participant in ``domain`` with ROS 2 topic names and QoS."""

    def __init__(self, domain: int = 0, *, loopback: bool = False) -> None:
        require("cyclonedds", "live operation over DDS")
        from cyclonedds.domain import Domain, DomainParticipant

        self.domain_id = check_domain(domain)
        self._domain = None
        if loopback:
            from cyclonedds.core import DDSException

            try:
                self._domain = Domain(self.domain_id, LOOPBACK_CONFIG)
            except DDSException:
                pass  # this process made the domain already (another Bus or participant on it): shared
        self.participant = DomainParticipant(self.domain_id)
        self.qos = _reliable(HISTORY_DEPTH)
        self._topics: dict[str, Any] = {}

    def _topic(self, ros_topic: str, cls: type) -> Any:
        from cyclonedds.topic import Topic

        name = dds_topic(ros_topic)
        if name not in self._topics:
            self._topics[name] = Topic(self.participant, name, cls, qos=self.qos)
        return self._topics[name]

    def static_writer(self, ros_topic: str, cls: type) -> Any:
        """A DataWriter with the QoS of ROS 2's static broadcasters (tf2's
        ``StaticBroadcasterQoS``: reliable, transient-local, keep-last 1):
        a reader that joins later still gets the last message written (a
        transient-local ROS 2 subscription, as tf2's static listener's)."""
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter

        qos = Qos(Policy.Reliability.Reliable(max_blocking_time=WRITE_MAX_BLOCKING), Policy.Durability.TransientLocal,
                  Policy.History.KeepLast(1))
        return DataWriter(self.participant, self._topic(ros_topic, cls), qos=qos)

    def writer(self, ros_topic: str, cls: type, *, userdata: bytes | None = None) -> Any:
        """A DataWriter of ``cls`` messages on ROS 2 topic ``ros_topic`` (``.write(msg)``).

        Its QoS is ROS 2's default (reliable, volatile, keep-last 10: what a
        ROS 2 subscription matches); a keep-last writer never waits for a slow
        reader (Cyclone DDS keeps the last 10 samples for it to repair and
        drops older ones), and ``write`` blocks at most
        :data:`WRITE_MAX_BLOCKING` (guide "Running on your robots", QoS).
        ``userdata``: the writer's USER_DATA (what readers see of it in
        discovery: the localizer names itself there, see :func:`publisher_name`).
        """
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter

        qos = _reliable(HISTORY_DEPTH, WRITE_MAX_BLOCKING)
        if userdata is not None:
            qos += Qos(Policy.Userdata(bytes(userdata)))
        return DataWriter(self.participant, self._topic(ros_topic, cls), qos=qos)

    def reader(self, ros_topic: str, cls: type, *, sensor: bool = False, depth: int = HISTORY_DEPTH,
               static: bool = False, others_only: bool = False) -> Reader:
        """A :class:`Reader` of ``cls`` messages on ROS 2 topic ``ros_topic``.
        ``sensor``: ROS 2's sensor-data QoS (best effort, keep-last 5), which
        matches camera drivers' best-effort writers as well as reliable ones;
        ``depth``: the samples a reliable reader keeps until taken (its own
        history: a deeper one still matches ROS 2's writers, and rides out a
        pause); ``static``: transient-local, keep-last 1 (as tf2's static
        listener: gets what a :meth:`static_writer` wrote before it joined);
        ``others_only``: never the samples of this participant's own writers
        (DDS's IGNORE_LOCAL: what someone else publishes on the topic)."""
        from cyclonedds.core import Policy, Qos
        from cyclonedds.sub import DataReader

        if static:
            qos = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.TransientLocal,
                      Policy.History.KeepLast(1))
        elif sensor:
            qos = Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))
        elif depth == HISTORY_DEPTH:
            qos = self.qos
        else:
            qos = _reliable(int(depth))
        if others_only:
            qos = qos + Qos(Policy.IgnoreLocal.Participant)
        decode = observations_from_cdr if cls is ros_types().Observations else None  # (the localizer's input)
        return Reader(DataReader(self.participant, self._topic(ros_topic, cls), qos=qos), decode)

    def publisher_name(self, reader: Reader, sample: Any) -> str:
        """Who wrote ``sample`` (taken from ``reader``): the USER_DATA its writer
        gave itself (:meth:`writer`'s ``userdata``), else its participant's GUID."""
        handle = getattr(getattr(sample, "sample_info", None), "publication_handle", None)
        try:
            data = reader.native.get_matched_publication_data(handle)
        except Exception:  # noqa: BLE001 -- a writer already gone: unnamed
            data = None
        if data is None:
            return "an unknown publisher"
        for policy in data.qos or ():
            if type(policy).__name__ == "Userdata" and getattr(policy, "data", b""):
                return policy.data.decode("utf-8", "replace")
        return f"DDS participant {data.participant_key}"

    def close(self) -> None:
        """Leave the domain (readers and writers go with the participant)."""
        self._topics.clear()
        self.participant = None
        self._domain = None

    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
