"""rosbag2 (MCAP storage, metadata version 9) writer taking raw CDR bytes."""

from __future__ import annotations

import operator
import shutil
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING

from rosbags.interfaces import Connection, Qos
from rosbags.typesys.store import Typestore

from force_tester_common.core.partial import Marked, clear_stale, tell

from .errors import BagError, one_line
from .metadata import METADATA_VERSION, ROS_DISTRO, load_metadata, write_metadata
from .sources import check_new_bag_path

if TYPE_CHECKING:   # imported where a bag is opened: rosbags.rosbag2 loads sqlite3, apsw, lz4 (tens of ms)
    from rosbags.rosbag2 import Writer

STORAGE_ID = 'mcap'
_MAX_STAMP = 2**63 - 1
# First two bytes of a CDR encapsulation header: CDR_BE / CDR_LE (plain CDR, as rmw uses).
_CDR_HEADERS = (b'\x00\x00', b'\x00\x01')


def _record_distro(writer: Writer) -> None:
    """Make the copy of the bag information that rosbags embeds in the MCAP file (its
    'rosbag2' metadata record) name ROS_DISTRO instead of 'rosbags'."""
    storage = writer.storage
    close = storage.close

    def close_with_distro(version: int, metadata: str) -> None:
        close(version, metadata.replace('ros_distro: rosbags', f'ros_distro: {ROS_DISTRO}'))
    storage.close = close_with_distro


class BagWriter:
    """Write a rosbag2 bag (directory + metadata.yaml + one .mcap).

    The directory must not exist. Until close() succeeds the directory holds no
    metadata.yaml, so nothing reads it as a complete bag; if an exception leaves the
    `with` block (or abort() is called) the directory is removed.

    rewritable: a bag made from inputs that are kept (import, correct): while it is written
    the directory also holds a lock file (force_tester_common.core.partial), so when its
    writer is killed midway the next BagWriter of that path removes it, saying so in
    ``warnings`` (logged when None). A recording (the default) is never marked: cut off, it
    is recovered by reindex, never removed.
    """

    def __init__(self, path: str | Path, typestore: Typestore, warnings: list | None = None,
                 rewritable: bool = False) -> None:
        self.path = Path(path)
        self.typestore = typestore
        tell(clear_stale(self.path), warnings)   # what a writer that died left here
        check_new_bag_path(self.path)
        self._mark: Marked | None = None
        self._rewritable = rewritable
        self._writer: Writer | None = None
        self._connections: dict[str, Connection] = {}
        self._closed = False
        self.message_count = 0

    # -- lifecycle -------------------------------------------------------------------
    def open(self) -> BagWriter:
        if self._writer is not None or self._closed:
            raise BagError(f'bag writer for {str(self.path)!r} was already opened')
        check_new_bag_path(self.path)  # again: it may have appeared since __init__
        from rosbags.rosbag2 import StoragePlugin, Writer
        try:
            writer = Writer(self.path, version=METADATA_VERSION,
                            storage_plugin=StoragePlugin.MCAP)
            # A mapping, not null: rosbag2 (yaml-cpp) decodes custom_data as a string map.
            writer.set_custom_data('writer', 'bag_tools.core')
            writer.open()
            _record_distro(writer)
            if self._rewritable:
                self._mark = Marked(self.path).__enter__()
        except Exception as exc:  # noqa: BLE001
            if not isinstance(exc, FileExistsError) and 'exists already' not in str(exc):
                self._remove()
            raise BagError(f'cannot create bag {str(self.path)!r}: {one_line(exc)}') from None
        self._writer = writer
        return self

    def _require_open(self) -> Writer:
        if self._writer is None:
            state = 'closed' if self._closed else 'not opened'
            raise BagError(f'bag writer for {str(self.path)!r} is {state}')
        return self._writer

    def add_topic(self, topic: str, type_name: str,
                  qos: Qos | Sequence[Qos] | None = None) -> None:
        """Register a topic with its full type name ('pkg/msg/Type').

        qos: offered QoS profile(s) stored in the metadata (rosbags.interfaces.Qos);
        None stores none (ros2 bag play then uses its default QoS).
        Adding the same topic again with the same type is a no-op.
        """
        writer = self._require_open()
        if not isinstance(topic, str) or not topic.startswith('/'):
            raise BagError(f'topic name {topic!r} is invalid; expected an absolute name '
                           "like '/force'")
        if topic in self._connections:
            known = self._connections[topic].msgtype
            if known != type_name:
                raise BagError(f'topic {topic!r} already added with type {known!r}, '
                               f'cannot add it again as {type_name!r}')
            return
        if type_name not in self.typestore.types:
            raise BagError(f'unknown message type {type_name!r} for topic {topic!r}; '
                           "expected a full 'pkg/msg/Type' name known to the typestore")
        if qos is None:
            profiles: list[Qos] = []
        elif isinstance(qos, Qos):
            profiles = [qos]
        else:
            profiles = list(qos)
        try:
            conn = writer.add_connection(topic, type_name, typestore=self.typestore,
                                         offered_qos_profiles=profiles)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'cannot add topic {topic!r} ({type_name!r}) to bag '
                           f'{str(self.path)!r}: {one_line(exc)}') from None
        self._connections[topic] = conn

    def write(self, topic: str, stamp_ns: int, cdr_bytes: bytes | bytearray | memoryview) -> None:
        """Append one serialized (CDR) message received at stamp_ns (integer ns since epoch)."""
        writer = self._require_open()
        conn = self._connections.get(topic)
        if conn is None:
            raise BagError(f'topic {topic!r} was not added to bag {str(self.path)!r}; '
                           f'known topics: {sorted(self._connections)!r}')
        if isinstance(stamp_ns, bool):
            raise BagError(f'timestamp {stamp_ns!r} is not an integer nanosecond count')
        try:
            stamp = operator.index(stamp_ns)
        except TypeError:
            raise BagError(f'timestamp {stamp_ns!r} is not an integer nanosecond count') from None
        if not 0 <= stamp <= _MAX_STAMP:
            raise BagError(f'timestamp {stamp!r} out of range; expected 0..{_MAX_STAMP} ns')
        if not isinstance(cdr_bytes, (bytes, bytearray, memoryview)):
            raise BagError(f'message data for {topic!r} is {type(cdr_bytes).__name__}; '
                           'expected serialized CDR bytes')
        data = bytes(cdr_bytes)
        if len(data) < 4 or data[:2] not in _CDR_HEADERS:
            raise BagError(f'message data for {topic!r} at {stamp} ns is not CDR '
                           f'(starts {data[:4].hex()!r}, expected a 00 00 / 00 01 header)')
        try:
            writer.write(conn, stamp, data)
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'cannot write to bag {str(self.path)!r}: {one_line(exc)}') from None
        self.message_count += 1

    def close(self) -> Path:
        """Finish the MCAP summary and write metadata.yaml. Returns the bag path."""
        writer = self._require_open()
        self._writer = None
        self._closed = True
        try:
            self._unmark()
            writer.close()
            # rosbags writes ros_distro 'rosbags' into metadata.yaml; ours are Jazzy bags
            info = load_metadata(self.path)
            info['ros_distro'] = ROS_DISTRO
            write_metadata(self.path, info)
        except Exception as exc:  # noqa: BLE001
            self._remove()
            raise BagError(f'cannot finalise bag {str(self.path)!r} (removed): '
                           f'{one_line(exc)}') from None
        finally:
            self._release()
        return self.path

    def _unmark(self) -> None:
        if self._mark is not None:
            self._mark.unmark()

    def _release(self) -> None:
        if self._mark is not None:
            self._mark.__exit__()
            self._mark = None

    def abort(self) -> None:
        """Discard the bag being written (removes its directory)."""
        writer, self._writer = self._writer, None
        self._closed = True
        if writer is not None:
            try:
                writer.abort()
            except Exception:  # noqa: BLE001, S110 - removing it anyway
                pass
            self._remove()

    def _remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
        self._release()

    @property
    def topics(self) -> dict[str, str]:
        return {t: c.msgtype for t, c in self._connections.items()}

    # -- context manager -----------------------------------------------------------------
    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            if self._writer is not None:
                self.close()
        else:
            self.abort()
