"""Read and validate rosbag2 bags (raw CDR out, optional deserialisation)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .errors import BagError, one_line
from .metadata import load_metadata


class TopicSummary(NamedTuple):
    type_name: str
    count: int


class BagMessage(NamedTuple):
    topic: str
    type_name: str
    stamp_ns: int
    cdr: bytes


def _typestore_from_connections(connections: Iterable[Connection]) -> Typestore:
    """Jazzy store + the types whose definitions are embedded in the bag."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for conn in connections:
        if conn.msgtype in store.types or conn.msgdef.format != MessageDefinitionFormat.MSG:
            continue
        types.update(get_types_from_msg(conn.msgdef.data, conn.msgtype))
    if types:
        store.register(types)
    return store


class BagReaderHandle:
    """An open bag. Use as a context manager or call close()."""

    def __init__(self, path: Path, reader: Reader, typestore: Typestore | None) -> None:
        self.path = path
        self._reader = reader
        self._typestore = typestore
        try:
            self.start_ns: int = int(reader.start_time)
            # rosbags reports end as last stamp + 1; we expose the last stamp.
            self.end_ns: int = int(reader.end_time) - 1
            self.message_count: int = int(reader.message_count)
            if self.message_count <= 0:
                self.start_ns = self.end_ns = 0
            self._topics = {
                name: TopicSummary(str(info.msgtype), int(info.msgcount))
                for name, info in reader.topics.items()
            }
        except Exception as exc:  # noqa: BLE001
            self.close()
            raise BagError(f'cannot read bag {str(path)!r}: {one_line(exc)}') from None

    @property
    def duration_ns(self) -> int:
        """Last stamp - first stamp (0 for a single message)."""
        return self.end_ns - self.start_ns

    def topics(self) -> dict[str, TopicSummary]:
        """topic name -> (type_name, count)."""
        return dict(self._topics)

    @property
    def typestore(self) -> Typestore:
        if self._typestore is None:
            try:
                self._typestore = _typestore_from_connections(self._reader.connections)
            except Exception as exc:  # noqa: BLE001
                raise BagError(f'cannot build message types from the definitions in bag '
                               f'{str(self.path)!r}: {one_line(exc)}') from None
        return self._typestore

    def messages(self, topics: Iterable[str] | str | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[BagMessage]:
        """Yield (topic, type_name, stamp_ns, cdr_bytes) in time order.

        topics: names to read (None = all); an unknown name raises BagError.
        start_ns inclusive, end_ns exclusive (both integer ns since epoch).
        """
        if isinstance(topics, str):
            topics = [topics]
        conns = self._reader.connections
        if topics is not None:
            wanted = list(topics)
            missing = [t for t in wanted if t not in self._topics]
            if missing:
                raise BagError(f'topic {missing[0]!r} not in bag {str(self.path)!r}; '
                               f'expected one of {sorted(self._topics)!r}')
            conns = [c for c in conns if c.topic in set(wanted)]
            if not conns:
                return iter(())
        for name, val in (('start_ns', start_ns), ('end_ns', end_ns)):
            if val is not None and (isinstance(val, bool) or not isinstance(val, int)):
                raise BagError(f'{name} {val!r} is not an integer nanosecond count')
        return self._iter(conns, start_ns, end_ns)

    def _iter(self, conns: list[Connection], start_ns: int | None,
              end_ns: int | None) -> Iterator[BagMessage]:
        try:
            for conn, stamp, data in self._reader.messages(conns, start=start_ns, stop=end_ns):
                yield BagMessage(conn.topic, conn.msgtype, int(stamp), bytes(data))
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'bag {str(self.path)!r} is corrupt while reading messages: '
                           f'{one_line(exc) or type(exc).__name__}') from None

    def single_mcap_path(self) -> Path | None:
        """The storage file when the bag is one MCAP file (for the batch readers), else None."""
        inner = getattr(self._reader, 'storage', None)  # rosbags >= 0.10: DirectoryReader
        storages = getattr(inner, 'storages', None) or getattr(self._reader, 'storages', None) \
            or []
        if len(storages) != 1 or type(storages[0]).__name__ != 'McapReader':
            return None
        path = getattr(storages[0], 'path', None)
        return Path(path) if path is not None else None

    def deserialize(self, cdr: bytes, type_name: str) -> Any:
        """CDR bytes -> message object of the typestore."""
        store = self.typestore
        if type_name not in store.types:
            raise BagError(f'unknown message type {type_name!r}; expected a full '
                           "'pkg/msg/Type' name defined in the bag or the typestore")
        try:
            return store.deserialize_cdr(cdr, type_name)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'cannot deserialize {len(cdr)} bytes as {type_name!r}: '
                           f'{one_line(exc) or type(exc).__name__}') from None

    def close(self) -> None:
        reader, self._reader = self._reader, None
        if reader is not None and reader.is_open:
            try:
                reader.close()
            except Exception:  # noqa: BLE001, S110
                pass

    def __enter__(self) -> BagReaderHandle:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def open_bag(path: str | Path, typestore: Typestore | None = None,
             allow_empty: bool = False) -> BagReaderHandle:
    """Open and validate a rosbag2 directory.

    typestore: used by deserialize(); default = Jazzy + the definitions embedded in the bag.
    Raises BagError (one line) for a missing path, a non-bag, a missing metadata.yaml,
    truncated/corrupt storage, or (unless allow_empty) a bag without messages.
    """
    path = Path(path)
    load_metadata(path)
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot open bag {str(path)!r} (truncated or corrupt?): '
                       f'{one_line(exc) or type(exc).__name__}') from None
    handle = BagReaderHandle(path, reader, typestore)
    if handle.message_count <= 0 and not allow_empty:
        handle.close()
        raise BagError(f'bag {str(path)!r} contains no messages')
    return handle
