"""Reading recorded ROS 1 and ROS 2 bags as one time-ordered message stream.

:class:`BagSet` opens any mix of

* ROS 1 bag files (``.bag``, format 2.0),
* ROS 2 bag folders (a directory with ``metadata.yaml`` and sqlite3 ``.db3``
  or ``.mcap`` storage files; a path to the ``metadata.yaml`` itself is
  accepted too),
* bare ROS 2 storage files: ``.mcap`` files (profile ``ros2``) and ``.db3``
  files without their ``metadata.yaml``. The reader of ``rosbags`` reads those
  directly from their own schema records / tables, no synthesized metadata is
  needed.

Each input is read with its own typestore: message types are registered from
the definitions stored in that bag (ROS 1 connection headers, MCAP schemas,
the ``message_definitions`` table of recent sqlite3 bags). Types whose
definition is not stored in the bag (older ROS 2 sqlite3 bags) fall back to the
builtin ROS 1 Noetic or latest ROS 2 typestore of ``rosbags``.

Everything that goes wrong while opening or reading raises :class:`BagError`,
whose message names the offending file.
"""

from __future__ import annotations

import contextlib
import heapq
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

from rosbags.interfaces import Connection
from rosbags.rosbag1 import Reader as Reader1
from rosbags.rosbag2 import Reader as Reader2
from rosbags.typesys import Stores, get_typestore

from .msgtypes import definition_mismatch, normalize_msgtype, register_types

__all__ = ["BagError", "BagMessage", "BagSet", "TopicInfo"]

PathLike = str | os.PathLike[str]

_ROS1_MAGIC = b"#ROSBAG V2.0\n"
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"


class BagError(Exception):
    """An input bag is missing, unreadable, damaged, or lacks a wanted topic.

    The message always names the file (or the topics) concerned.
    """


@dataclass(frozen=True)
class TopicInfo:
    """Summary of one topic over all inputs of a :class:`BagSet`.

    Attributes
    ----------
    msgtype : str or None
        Message type in ``pkg/msg/Name`` form, ``None`` if the inputs disagree
        on the type (see ``types``).
    count : int
        Number of messages on the topic, summed over the inputs.
    paths : tuple of pathlib.Path
        The inputs that contain the topic, in the order they were given.
    types : tuple of str
        Every distinct message type seen for the topic.
    """

    msgtype: str | None
    count: int
    paths: tuple[Path, ...]
    types: tuple[str, ...]


class BagMessage(NamedTuple):
    """One deserialized message, as yielded by :meth:`BagSet.messages`.

    Attributes
    ----------
    topic : str
        Topic name.
    log_time_ns : int
        Time the recorder logged the message (ns since the epoch). Sensor data
        should be placed in time with ``msg.header.stamp`` instead.
    msg : object
        The deserialized message (a ``rosbags`` dataclass). ROS 1 and ROS 2
        messages have the same field names except for ROS 1 only fields such
        as ``Header.seq``; stamps are ``builtin_interfaces/msg/Time`` with
        ``sec`` and ``nanosec`` in both.
    """

    topic: str
    log_time_ns: int
    msg: Any


def _describe_error(err: BaseException) -> str:
    text = " ".join(str(err).split())
    if len(text) > 300:  # parser errors quote whole definitions
        text = text[:300] + "..."
    return f"{type(err).__name__}: {text}" if text else type(err).__name__


class _Input:
    """One opened input: a reader plus the typestore matching it."""

    def __init__(self, path: Path, index: int) -> None:
        self.path = path
        self.index = index
        self.kind, self.reader = self._make_reader(path)
        self.is_ros2 = self.kind != "ROS 1 bag"
        self._deserializers: dict[str, Callable[[bytes], Any]] = {}
        self.fallback: Any = None
        self.connections: list[Connection] = []
        self.start_ns: int | None = None
        self.end_ns: int | None = None

    def _fail(self, what: str) -> BagError:
        return BagError(f"{self.path}: {what}")

    def _make_reader(self, path: Path) -> tuple[str, Reader1 | Reader2]:
        if not path.exists():
            raise BagError(f"{path}: no such file or directory")
        if path.is_file() and path.name == "metadata.yaml":
            path = path.parent
            self.path = path
        if not path.is_dir() and not path.is_file():
            raise BagError(
                f"{path}: not a regular file or folder (a device, FIFO or socket);"
                " give a bag file or a ROS 2 bag folder"
            )
        if path.is_dir():
            if not (path / "metadata.yaml").is_file():
                raise BagError(f"{path}: directory is not a ROS 2 bag (it has no metadata.yaml)")
            return "ROS 2 bag", Reader2(path)
        try:
            with path.open("rb") as fh:
                head = fh.read(16)
        except OSError as err:
            raise BagError(f"{path}: cannot read file ({err.strerror})") from err
        if not head:
            raise BagError(f"{path}: file is empty, not a bag")
        if head.startswith(_ROS1_MAGIC):
            return "ROS 1 bag", Reader1(path)
        for magic, kind, suffix in (
            (_MCAP_MAGIC, "MCAP file", ".mcap"),
            (_SQLITE_MAGIC, "sqlite3 ROS 2 storage file", ".db3"),
        ):
            if head.startswith(magic):
                if path.suffix != suffix:
                    raise BagError(
                        f"{path}: file is a {kind} but is named {path.suffix or 'without suffix'!r}"
                        f"; rename it to end in {suffix!r}"
                    )
                return kind, Reader2(path)
        if head.startswith(b"#ROSBAG"):
            version = head.split(b"\n")[0].decode(errors="replace")
            raise BagError(
                f"{path}: unsupported ROS 1 bag version {version!r} (only V2.0 is supported)"
            )
        raise BagError(
            f"{path}: not a bag (unrecognized file header {head[:12]!r}; expected a ROS 1 bag,"
            " an MCAP file, a sqlite3 .db3 file or a ROS 2 bag folder)"
        )

    def open(self) -> None:
        try:
            self.reader.open()
        except Exception as err:
            raise self._fail(
                f"cannot open {self.kind} (damaged or truncated?): {_describe_error(err)}"
            ) from err
        try:
            self.connections = list(self.reader.connections)
            self.typestore, self.lacking = register_types(self.connections)
            self.start_ns = self.reader.start_time if self.reader.message_count else None
            self.end_ns = self.reader.end_time - 1 if self.reader.message_count else None
        except Exception as err:
            self.close()
            raise self._fail(
                f"cannot read the message definitions: {_describe_error(err)}"
            ) from err

    def close(self) -> None:
        # Closing a damaged file must not mask the error that led here.
        with contextlib.suppress(Exception):
            self.reader.close()

    def deserializer(self, msgtype: str) -> Callable[[bytes], Any]:
        func = self._deserializers.get(msgtype)
        if func is not None:
            return func
        store = self.typestore
        if msgtype in self.lacking:
            if self.fallback is None:
                self.fallback = get_typestore(Stores.LATEST if self.is_ros2 else Stores.ROS1_NOETIC)
            store = self.fallback
            if msgtype not in store.fielddefs:
                raise self._fail(
                    f"message type {msgtype!r} has no definition in the bag and is not a"
                    " standard ROS type; cannot deserialize it"
                )
        if self.is_ros2:
            func = lambda raw: store.deserialize_cdr(raw, msgtype)  # noqa: E731
        else:
            func = lambda raw: store.deserialize_ros1(raw, msgtype)  # noqa: E731
        self._deserializers[msgtype] = func
        return func

    def check_definition(self, topic: str, msgtype: str) -> None:
        """Refuse a standard message type whose definition in the bag is not the standard one."""
        if msgtype in self.lacking:
            return
        why = definition_mismatch(self.typestore, msgtype)
        if why:
            raise self._fail(
                f"topic {topic!r}: the bag's definition of {msgtype} is not the standard one"
                f" ({why}); damaged or foreign message definition"
            )

    def raw_messages(
        self, connections: Sequence[Connection], start_ns: int | None, stop_ns: int | None
    ) -> Iterator[tuple[int, int, int, Connection, bytes]]:
        """Yield ``(log_time, input index, sequence, connection, raw)``, wrapping read errors."""
        try:
            messages = self.reader.messages(connections, start=start_ns, stop=stop_ns)
            for seq, (conn, stamp, raw) in enumerate(messages):
                yield stamp, self.index, seq, conn, raw
        except Exception as err:
            raise self._fail(
                f"error while reading messages (damaged or truncated bag?): {_describe_error(err)}"
            ) from err


class BagSet:
    """Several bags read as one, with messages merged in log time order.

    Parameters
    ----------
    paths : path or sequence of paths
        ROS 1 ``.bag`` files, ROS 2 bag folders, bare ``.mcap`` / ``.db3``
        files, in any mix.

    Raises
    ------
    BagError
        When no path is given, a path is missing, or is not a supported bag
        (raised here), or cannot be opened (raised by :meth:`open`).

    Examples
    --------
    >>> with BagSet(["run1.bag", "run2_mcap/"]) as bags:      # doctest: +SKIP
    ...     for topic, t_ns, msg in bags.messages({"/scan": "sensor_msgs/msg/LaserScan"}):
    ...         ...
    """

    def __init__(self, paths: PathLike | Sequence[PathLike]) -> None:
        if isinstance(paths, (str, os.PathLike)):
            paths = [paths]
        if not paths:
            raise BagError("no input bag given")
        self.paths: tuple[Path, ...] = tuple(Path(p) for p in paths)
        self._inputs = [_Input(p, i) for i, p in enumerate(self.paths)]
        self.paths = tuple(x.path for x in self._inputs)
        self._open = False

    # -- context management ---------------------------------------------------------------
    def open(self) -> BagSet:
        """Open all inputs; called by ``with``. Returns ``self``."""
        if self._open:
            return self
        opened: list[_Input] = []
        try:
            for inp in self._inputs:
                inp.open()
                opened.append(inp)
        except BaseException:
            for inp in opened:
                inp.close()
            raise
        self._open = True
        self._topics = self._summarize()
        return self

    def close(self) -> None:
        """Close all inputs (idempotent)."""
        if self._open:
            for inp in self._inputs:
                inp.close()
            self._open = False

    def __enter__(self) -> BagSet:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _check_open(self) -> None:
        if not self._open:
            raise BagError("BagSet is not open; use it in a with statement or call open()")

    # -- metadata -------------------------------------------------------------------------
    def _summarize(self) -> dict[str, TopicInfo]:
        acc: dict[str, tuple[list[str], int, list[Path]]] = {}
        for inp in self._inputs:
            for conn in inp.connections:
                types, count, paths = acc.setdefault(conn.topic, ([], 0, []))
                if conn.msgtype not in types:
                    types.append(conn.msgtype)
                if inp.path not in paths:
                    paths.append(inp.path)
                acc[conn.topic] = (types, count + max(conn.msgcount, 0), paths)
        return {
            topic: TopicInfo(
                types[0] if len(types) == 1 else None, count, tuple(paths), tuple(types)
            )
            for topic, (types, count, paths) in sorted(acc.items())
        }

    def topics(self) -> dict[str, TopicInfo]:
        """Topics of all inputs, sorted by name.

        Returns
        -------
        dict of str to TopicInfo
        """
        self._check_open()
        return dict(self._topics)

    @property
    def start_ns(self) -> int | None:
        """Log time (ns) of the earliest message of all inputs, ``None`` if all are empty."""
        self._check_open()
        starts = [x.start_ns for x in self._inputs if x.start_ns is not None]
        return min(starts) if starts else None

    @property
    def end_ns(self) -> int | None:
        """Log time (ns) of the latest message of all inputs (inclusive), ``None`` if empty."""
        self._check_open()
        ends = [x.end_ns for x in self._inputs if x.end_ns is not None]
        return max(ends) if ends else None

    def describe_topics(self) -> str:
        """Human readable ``topic (type, count)`` listing of all inputs."""
        self._check_open()
        if not self._topics:
            return "(the bags contain no topics)"
        return ", ".join(
            f"{t} ({info.msgtype or ' | '.join(info.types)}, {info.count} msgs)"
            for t, info in self._topics.items()
        )

    def check_topics(
        self, topics: str | Iterable[str] | Mapping[str, str | Iterable[str] | None]
    ) -> dict[str, TopicInfo]:
        """Check that topics exist and, optionally, have the expected types.

        Parameters
        ----------
        topics : str, iterable of str, or mapping
            Topic names, or a mapping from topic name to the accepted message
            type(s) (``pkg/Name`` or ``pkg/msg/Name``; ``None`` accepts any).

        Returns
        -------
        dict of str to TopicInfo
            The info of each requested topic.

        Raises
        ------
        BagError
            A topic is absent (the message lists the topics of the bags with
            their types), has an unexpected type (expected vs found), or has
            different types in different inputs.
        """
        self._check_open()
        spec = _topic_spec(topics)
        out: dict[str, TopicInfo] = {}
        files = ", ".join(str(p) for p in self.paths)
        missing = [t for t in spec if t not in self._topics]
        if missing:
            raise BagError(
                f"topic(s) {', '.join(map(repr, missing))} not found in {files}; "
                f"the bags contain: {self.describe_topics()}"
            )
        for topic, accepted in spec.items():
            info = self._topics[topic]
            if info.msgtype is None:
                per_file = "; ".join(
                    f"{inp.path}: {c.msgtype}"
                    for inp in self._inputs
                    for c in inp.connections
                    if c.topic == topic
                )
                raise BagError(f"topic {topic!r} has different types in the inputs: {per_file}")
            if accepted is not None and info.msgtype not in accepted:
                raise BagError(
                    f"topic {topic!r} in {', '.join(map(str, info.paths))} has type "
                    f"{info.msgtype!r}, expected {' or '.join(map(repr, sorted(accepted)))}"
                )
            if accepted is not None:  # the message will be decoded: check its fields
                for inp in self._inputs:
                    if any(c.topic == topic for c in inp.connections):
                        inp.check_definition(topic, info.msgtype)
            out[topic] = info
        return out

    # -- messages -------------------------------------------------------------------------
    def messages(
        self,
        topics: str | Iterable[str] | Mapping[str, str | Iterable[str] | None] | None = None,
        *,
        start_ns: int | None = None,
        stop_ns: int | None = None,
    ) -> Iterator[BagMessage]:
        """Deserialized messages of all inputs, in log time order.

        Topics are checked when this method is called (not lazily at the first
        message). Messages with equal log times keep the order of the inputs
        and, within one input, the order in the file.

        Parameters
        ----------
        topics : str, iterable of str, mapping, or None
            As for :meth:`check_topics`; ``None`` reads every topic.
        start_ns, stop_ns : int, optional
            Only messages with ``start_ns <= log time < stop_ns``.

        Returns
        -------
        iterator of BagMessage
            ``(topic, log_time_ns, msg)`` tuples.

        Raises
        ------
        BagError
            For a bad topic request (immediately), and while iterating for a
            damaged input or a message that cannot be deserialized.
        """
        self._check_open()
        wanted = set(self._topics) if topics is None else set(self.check_topics(topics))
        streams = []
        for inp in self._inputs:
            conns = [c for c in inp.connections if c.topic in wanted]
            if conns:
                streams.append(inp.raw_messages(conns, start_ns, stop_ns))
        return self._iterate(streams)

    def _iterate(
        self, streams: list[Iterator[tuple[int, int, int, Connection, bytes]]]
    ) -> Iterator[BagMessage]:
        inputs = self._inputs
        for stamp, index, _seq, conn, raw in heapq.merge(*streams):
            inp = inputs[index]
            try:
                msg = inp.deserializer(conn.msgtype)(raw)
            except BagError:
                raise
            except Exception as err:
                raise inp._fail(
                    f"cannot deserialize a {conn.msgtype} message on {conn.topic!r} logged at"
                    f" {stamp} ns (damaged bag?): {_describe_error(err)}"
                ) from err
            yield BagMessage(conn.topic, stamp, msg)

    def __repr__(self) -> str:
        state = "open" if self._open else "closed"
        return f"BagSet([{', '.join(repr(str(p)) for p in self.paths)}], {state})"


def _topic_spec(
    topics: str | Iterable[str] | Mapping[str, str | Iterable[str] | None],
) -> dict[str, frozenset[str] | None]:
    if isinstance(topics, str):
        return {topics: None}
    if isinstance(topics, Mapping):
        spec: dict[str, frozenset[str] | None] = {}
        for topic, types in topics.items():
            if types is None:
                spec[topic] = None
            elif isinstance(types, str):
                spec[topic] = frozenset({normalize_msgtype(types)})
            else:
                spec[topic] = frozenset(normalize_msgtype(t) for t in types)
        return spec
    return {t: None for t in topics}
