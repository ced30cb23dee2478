"""Read and validate rosbag2 bags (raw CDR out, optional deserialisation).

Bags from anywhere: MCAP or sqlite3 storage, file or message compression, split files, old
'pkg/Type' names and QoS strings in metadata.yaml that differ from those in the storage file.
Storage topics are matched to metadata.yaml's by name and type only (as rosbag2 plays them);
the counts read from the storage are compared with metadata.yaml's (count_differences()).
Message types are built from the bag's embedded definitions only when a command needs them.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, NamedTuple

from rosbags.interfaces import MessageDefinitionFormat, Nodetype
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from .errors import BagError, one_line
from .metadata import load_metadata
from .typestore import normalize_type, types_from_definition

if TYPE_CHECKING:   # imported where a bag is opened: rosbags.rosbag2 loads sqlite3, apsw, lz4 (tens of ms)
    from rosbags.rosbag2 import Reader

#: rosbag2's file/message compressors (MCAP chunks may also be lz4: the storage reads those).
COMPRESSORS = ('zstd',)
#: Characters of a library's message quoted in one of our error lines.
DETAIL_CHARS = 120


def brief(exc: object) -> str:
    """A library error in at most DETAIL_CHARS characters, on one line."""
    text = one_line(exc) or type(exc).__name__
    return text if len(text) <= DETAIL_CHARS else text[:DETAIL_CHARS - 3] + '...'


class TopicSummary(NamedTuple):
    type_name: str
    count: int


class BagMessage(NamedTuple):
    topic: str
    type_name: str
    stamp_ns: int
    cdr: bytes


class CountDifference(NamedTuple):
    """A topic whose message count in metadata.yaml differs from what its storage holds."""

    topic: str
    metadata_count: int | None  # None: the topic is not in metadata.yaml
    stored_count: int


def _referenced(field: Any) -> str:
    """The message type a rosbags field definition (nodetype, detail) refers to, else ''."""
    kind, detail = field
    while kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):  # (element field, length)
        kind, detail = detail[0]
    return detail if kind == Nodetype.NAME else ''


class BagReaderHandle:
    """An open bag. Use as a context manager or call close()."""

    def __init__(self, path: Path, reader: Reader, typestore: Typestore | None,
                 info: dict | None = None) -> None:
        self.path = path
        self._reader = reader
        self._typestore = typestore
        self._own_store = typestore is None
        self._type_errors: dict[str, str] = {}
        self.metadata: dict = info or {}
        try:
            directory = reader.storage
            self._storages = list(getattr(directory, 'storages', None) or [directory])
            mode = directory.metadata.compression_mode
            self._message_compressed = mode == 'message'
            self._meta_topics = {
                c.topic: TopicSummary(normalize_type(c.msgtype), int(c.msgcount))
                for c in reader.connections}
            stored: dict[str, list] = {}
            self._definitions: dict[str, str] = {}
            starts, ends = [], []
            for storage in self._storages:
                for c in storage.connections:
                    type_name = normalize_type(c.msgtype)
                    entry = stored.setdefault(c.topic, [type_name, 0])
                    entry[1] += int(c.msgcount)
                    if c.msgdef.format == MessageDefinitionFormat.MSG and c.msgdef.data:
                        self._definitions.setdefault(type_name, c.msgdef.data)
                m = storage.metadata
                if int(m.message_count) > 0:
                    starts.append(int(m.start_time))
                    ends.append(int(m.end_time) - 1)  # rosbags: last stamp + 1
            self._stored = {t: TopicSummary(ty, n) for t, (ty, n) in stored.items()}
            self._topics = {t: TopicSummary(
                self._meta_topics[t].type_name if t in self._meta_topics else s.type_name,
                s.count) for t, s in self._stored.items()}
            for t, s in self._meta_topics.items():  # listed but absent from the storage
                self._topics.setdefault(t, TopicSummary(s.type_name, 0))
            self._topics = dict(sorted(self._topics.items()))
            self.message_count: int = sum(s.count for s in self._stored.values())
            self.metadata_message_count: int = int(reader.message_count)
            if self.message_count > 0 and starts:
                self.start_ns: int = min(starts)
                self.end_ns: int = max(ends)
            else:
                self.start_ns = self.end_ns = 0
        except Exception as exc:  # noqa: BLE001
            self.close()
            raise BagError(f'cannot read bag {str(path)!r}: {brief(exc)}') from None

    @property
    def duration_ns(self) -> int:
        """Last stamp - first stamp (0 for a single message)."""
        return self.end_ns - self.start_ns

    def topics(self) -> dict[str, TopicSummary]:
        """topic name -> (type_name, count): the full 'pkg/msg/Type' name (metadata.yaml's,
        normalised) and the messages the storage holds."""
        return dict(self._topics)

    def count_differences(self) -> list[CountDifference]:
        """Topics whose metadata.yaml count differs from the storage's, and topics that only
        one of them lists. Empty for a consistent bag."""
        out = []
        for topic in self._topics:
            meta = self._meta_topics.get(topic)
            stored = self._stored.get(topic)
            n = stored.count if stored else 0
            if meta is None or meta.count != n:
                out.append(CountDifference(topic, meta.count if meta else None, n))
        return out

    # -- message types, built on demand -----------------------------------------------------
    def _store(self) -> Typestore:
        if self._typestore is None:
            self._typestore = get_typestore(Stores.ROS2_JAZZY)
        return self._typestore

    def type_error(self, type_name: str) -> str | None:
        """None when type_name can be built (from the typestore or the bag's embedded
        definition), else why not, briefly."""
        store = self._store()
        if type_name in store.types:
            return None
        if type_name in self._type_errors:
            return self._type_errors[type_name]
        text = self._definitions.get(type_name)
        if text is None:
            reason = 'the bag embeds no definition of it'
        elif not self._own_store:
            reason = 'not in the given typestore'
        else:
            try:
                types = types_from_definition(type_name, text)
                store.register({k: v for k, v in types.items() if k not in store.types})
                return None
            except Exception as exc:  # noqa: BLE001 - the parser raises many types
                reason = f'its embedded definition does not parse ({brief(exc)})'
        self._type_errors[type_name] = reason
        return reason

    def type_class(self, type_name: str) -> Any:
        """The message class of type_name, built on first use; None if it cannot be built."""
        return None if self.type_error(type_name) else self._store().types.get(type_name)

    def type_closure(self, type_name: str) -> dict:
        """rosbags field definitions of type_name and every type it uses (for registering it
        into another typestore); BagError when it cannot be built."""
        reason = self.type_error(type_name)
        if reason is not None:
            raise BagError(f'cannot build message type {type_name!r}: {reason}')
        defs = self._store().fielddefs
        out: dict = {}
        todo = [type_name]
        while todo:
            name = todo.pop()
            if name in out or name not in defs:
                continue
            out[name] = defs[name]
            todo.extend(_referenced(field) for _name, field in defs[name][1])
        return out

    @property
    def typestore(self) -> Typestore:
        """Jazzy + every topic type whose definition parses (the rest are left out; see
        type_error())."""
        for t in {s.type_name for s in self._topics.values()}:
            self.type_error(t)
        return self._store()

    def messages(self, topics: Iterable[str] | str | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[BagMessage]:
        """Yield (topic, type_name, stamp_ns, cdr_bytes) in time order.

        topics: names to read (None = all); an unknown name raises BagError.
        start_ns inclusive, end_ns exclusive (both integer ns since epoch).
        """
        if isinstance(topics, str):
            topics = [topics]
        if topics is None:
            wanted = set(self._topics)
        else:
            wanted = set(topics)
            missing = sorted(t for t in wanted if t not in self._topics)
            if missing:
                shown = sorted(self._topics)
                more = f' and {len(shown) - 8} more' if len(shown) > 8 else ''
                raise BagError(f'topic {missing[0]!r} not in bag {str(self.path)!r}; '
                               f'expected one of {shown[:8]!r}{more}')
        for name, val in (('start_ns', start_ns), ('end_ns', end_ns)):
            if val is not None and (isinstance(val, bool) or not isinstance(val, int)):
                raise BagError(f'{name} {val!r} is not an integer nanosecond count')
        return self._iter(wanted, start_ns, end_ns)

    def _storage_iter(self, storage, wanted: set, start_ns, end_ns):
        conns = [c for c in storage.connections if c.topic in wanted]
        if not conns:  # an empty list would mean every connection to some readers
            return
        types = {c.id: self._topics[c.topic].type_name for c in conns}
        if self._message_compressed:
            from rosbags.rosbag2.storage_mcap import DECOMPRESSORS  # name -> f(data, size): rosbags' zstd
        for conn, stamp, data in storage.messages(conns, start_ns, end_ns):
            if self._message_compressed:
                data = DECOMPRESSORS['zstd'](data, 0)
            yield int(stamp), conn.topic, types[conn.id], data

    def _iter(self, wanted: set, start_ns: int | None,
              end_ns: int | None) -> Iterator[BagMessage]:
        try:
            streams = [self._storage_iter(s, wanted, start_ns, end_ns) for s in self._storages]
            merged = streams[0] if len(streams) == 1 else heapq.merge(*streams,
                                                                      key=lambda m: m[0])
            for stamp, topic, type_name, data in merged:
                yield BagMessage(topic, type_name, stamp, bytes(data))
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'bag {str(self.path)!r} is corrupt while reading messages: '
                           f'{brief(exc)}') from None

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
        reason = self.type_error(type_name)
        if reason is not None:
            raise BagError(f'cannot decode message type {type_name!r}: {reason}')
        store = self._store()
        try:
            return store.deserialize_cdr(cdr, type_name)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'cannot deserialize {len(cdr)} bytes as {type_name!r}: '
                           f'{brief(exc)}') from None

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

    typestore: used by deserialize(); default = Jazzy + the definitions embedded in the bag,
    each built when first needed.
    Raises BagError (one line) for a missing path, a non-bag, a missing metadata.yaml,
    truncated/corrupt storage, or (unless allow_empty) a bag without messages.
    """
    path = Path(path)
    info = load_metadata(path)
    fmt, mode = info.get('compression_format') or '', info.get('compression_mode') or ''
    if mode and str(mode).lower() != 'none' and fmt not in COMPRESSORS:
        raise BagError(f'bag {str(path)!r} uses {fmt!r} {mode} compression; expected one of '
                       f'{sorted(COMPRESSORS)!r} (the compressors rosbag2 ships)')
    from rosbags.rosbag2 import Reader
    try:
        reader = Reader(path)
        reader.open()
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot open bag {str(path)!r} (truncated or corrupt?): '
                       f'{brief(exc)}') from None
    handle = BagReaderHandle(path, reader, typestore, info)
    if handle.message_count <= 0 and not allow_empty:
        handle.close()
        raise BagError(f'bag {str(path)!r} contains no messages')
    return handle
