"""rosbag2 (MCAP, metadata version 9) writer that splits the bag by size and/or duration.

Like `ros2 bag record --max-bag-size/--max-bag-duration`: ONE bag directory holding several
storage files `<name>_0.mcap`, `<name>_1.mcap`, ... and ONE metadata.yaml listing them all
(`relative_file_paths` and `files:` with per-file start, duration and message count).

Each split is written as its own single-file bag (BagWriter) in a hidden temporary directory
next to the target; when a split is full it is closed and its .mcap moved into the target
directory under its final name. metadata.yaml is written only by close(), so nothing looks
like a complete bag before then; abort(), an exception leaving the `with` block or a failed
close() removes the target and the temporary directory.
"""

from __future__ import annotations

import operator
import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.interfaces import Qos
from rosbags.typesys.store import Typestore

from .errors import BagError, one_line
from .metadata import METADATA_VERSION, ROS_DISTRO, load_metadata, write_metadata
from .sources import check_new_bag_path
from .writer import STORAGE_ID, BagWriter

#: Approximate MCAP bytes per message besides its payload (message record + chunk index).
MESSAGE_OVERHEAD_BYTES = 31 + 16
_NO_START = 2**63 - 1


class SplitBagWriter:
    """Write one rosbag2 bag split into several .mcap files by size and/or duration.

    max_bytes: start a new file once the current one holds >= max_bytes of message records
        (payload + ~47 bytes each; checked after each write). 0 = no size limit.
    max_duration_ns: start a new file before a message whose stamp is >= first stamp of the
        current file + max_duration_ns. 0 = no duration limit.
    Same interface as BagWriter (open, add_topic, write, close, abort, `with`).
    """

    def __init__(self, path: str | Path, typestore: Typestore, *, max_bytes: int = 0,
                 max_duration_ns: int = 0) -> None:
        self.path = Path(path)
        self.typestore = typestore
        for name, value in (('max_bytes', max_bytes), ('max_duration_ns', max_duration_ns)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                raise BagError(f'{name} {value!r} is invalid; expected an integer >= 0 '
                               '(0 = no limit)')
        self.max_bytes = max_bytes
        self.max_duration_ns = max_duration_ns
        check_new_bag_path(self.path)
        self._tmp: Path | None = None
        self._split: BagWriter | None = None
        self._split_start: int | None = None
        self._split_bytes = 0
        self._files: list[dict[str, Any]] = []      # closed splits' metadata (in order)
        self._topics: dict[str, tuple[str, Qos | Sequence[Qos] | None]] = {}
        self._opened = False
        self._closed = False
        self.message_count = 0

    # -- lifecycle -------------------------------------------------------------------
    def open(self) -> SplitBagWriter:
        if self._opened or self._closed:
            raise BagError(f'bag writer for {str(self.path)!r} was already opened')
        try:
            self.path.mkdir()
        except FileExistsError:
            raise BagError(f'bag output path {str(self.path)!r} exists already; '
                           'expected a new directory name') from None
        except OSError as exc:
            raise BagError(f'cannot create bag {str(self.path)!r}: {one_line(exc)}') from None
        self._opened = True
        try:
            self._tmp = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.', suffix='.splits',
                                              dir=self.path.parent))
            self._open_split()
        except BaseException as exc:
            self._remove()
            self._closed = True
            if isinstance(exc, BagError):
                raise
            raise BagError(f'cannot create bag {str(self.path)!r}: {one_line(exc)}') from None
        return self

    def _require_open(self) -> None:
        if not self._opened or self._closed:
            state = 'closed' if self._closed else 'not opened'
            raise BagError(f'bag writer for {str(self.path)!r} is {state}')

    def _split_name(self, index: int) -> str:
        return f'{self.path.name}_{index}'

    def _open_split(self) -> BagWriter:
        assert self._tmp is not None
        split = BagWriter(self._tmp / self._split_name(len(self._files)), self.typestore).open()
        try:
            for topic, (type_name, qos) in self._topics.items():
                split.add_topic(topic, type_name, qos)
        except BaseException:
            split.abort()
            raise
        self._split, self._split_start, self._split_bytes = split, None, 0
        return split

    def _close_split(self) -> None:
        """Finish the current split, move its .mcap into the bag, remember its metadata."""
        split, self._split = self._split, None
        assert split is not None and self._tmp is not None
        name = split.path.name
        split_dir = split.close()
        info = load_metadata(split_dir)
        src = split_dir / f'{name}.mcap'
        os.replace(src, self.path / src.name)
        shutil.rmtree(split_dir, ignore_errors=True)
        self._files.append(info)

    def add_topic(self, topic: str, type_name: str,
                  qos: Qos | Sequence[Qos] | None = None) -> None:
        """Register a topic (see BagWriter.add_topic); it goes into every following file."""
        self._require_open()
        split = self._split if self._split is not None else self._open_split()
        split.add_topic(topic, type_name, qos)
        self._topics.setdefault(topic, (type_name, qos))

    def write(self, topic: str, stamp_ns: int, cdr_bytes: bytes | bytearray | memoryview) -> None:
        """Append one serialized (CDR) message (see BagWriter.write), splitting as configured."""
        self._require_open()
        try:
            stamp = None if isinstance(stamp_ns, bool) else operator.index(stamp_ns)
        except TypeError:
            stamp = None
        if (self.max_duration_ns and stamp is not None and self._split is not None
                and self._split_start is not None
                and stamp - self._split_start >= self.max_duration_ns
                and topic in self._topics):
            self._roll()
        fresh = self._split is None
        split = self._open_split() if fresh else self._split
        try:
            split.write(topic, stamp_ns, cdr_bytes)
        except BaseException:
            if fresh and split.message_count == 0:   # don't leave an empty file behind
                split.abort()
                self._split = None
            raise
        self.message_count += 1
        if self._split_start is None:
            self._split_start = stamp
        self._split_bytes += len(cdr_bytes) + MESSAGE_OVERHEAD_BYTES
        if self.max_bytes and self._split_bytes >= self.max_bytes:
            self._roll()

    def _roll(self) -> None:
        try:
            self._close_split()
        except BagError:
            raise
        except Exception as exc:  # noqa: BLE001
            raise BagError(f'cannot finish split {len(self._files)} of bag '
                           f'{str(self.path)!r}: {one_line(exc)}') from None

    def close(self) -> Path:
        """Finish the last file and write the combined metadata.yaml. Returns the bag path."""
        self._require_open()
        self._closed = True
        try:
            if self._split is not None and (self._split.message_count or not self._files):
                self._close_split()
            elif self._split is not None:
                self._split.abort()
                self._split = None
            write_metadata(self.path, self._metadata())
        except BaseException as exc:  # noqa: BLE001 - any failure (Ctrl-C too) removes the half-written bag
            if self._split is not None:
                self._split.abort()
                self._split = None
            self._remove()
            raise BagError(f'cannot finalise bag {str(self.path)!r} (removed): '
                           f'{one_line(exc)}') from None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
        return self.path

    def abort(self) -> None:
        """Discard the bag being written (removes its directory and temporary files)."""
        if not self._opened or self._closed:
            self._closed = True
            return
        self._closed = True
        split, self._split = self._split, None
        if split is not None:
            split.abort()
        self._remove()

    def _remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    @property
    def topics(self) -> dict[str, str]:
        return {t: type_name for t, (type_name, _) in self._topics.items()}

    @property
    def file_count(self) -> int:
        """Storage files finished so far (+1 while a file is being written)."""
        return len(self._files) + (self._split is not None)

    # -- metadata --------------------------------------------------------------------
    def _metadata(self) -> dict[str, Any]:
        return combined_metadata(self._files)

    # -- context manager -------------------------------------------------------------
    def __enter__(self) -> SplitBagWriter:
        return self.open()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            if not self._closed:
                self.close()
        else:
            self.abort()


def combined_metadata(files: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One bag information mapping from those of single-file bags (in file order)."""
    if not files:
        raise BagError('no storage files to describe')
    topics: dict[str, dict[str, Any]] = {}
    entries = []
    for info in files:
        for path in info['relative_file_paths']:
            entries.append({
                'path': path,
                'starting_time': dict(info['starting_time']),
                'duration': dict(info['duration']),
                'message_count': int(info['message_count']),
            })
        for t in info['topics_with_message_count']:
            name = t['topic_metadata']['name']
            if name in topics:
                topics[name]['message_count'] += int(t['message_count'])
            else:
                topics[name] = {'topic_metadata': dict(t['topic_metadata']),
                                'message_count': int(t['message_count'])}
    full = [e for e in entries if e['message_count']]
    total = sum(e['message_count'] for e in entries)
    if full:
        start = min(e['starting_time']['nanoseconds_since_epoch'] for e in full)
        end = max(e['starting_time']['nanoseconds_since_epoch'] + e['duration']['nanoseconds']
                  for e in full)
        duration = end - start
    else:
        start, duration = _NO_START, 0
    first = files[0]
    return {
        'version': METADATA_VERSION,
        'storage_identifier': STORAGE_ID,
        'relative_file_paths': [e['path'] for e in entries],
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': total,
        'topics_with_message_count': list(topics.values()),
        'compression_format': first.get('compression_format', ''),
        'compression_mode': first.get('compression_mode', ''),
        'files': entries,
        'custom_data': first.get('custom_data'),
        'ros_distro': first.get('ros_distro', ROS_DISTRO),
    }


def open_bag_writer(path: str | Path, typestore: Typestore, *, max_bytes: int = 0,
                    max_duration_ns: int = 0) -> BagWriter | SplitBagWriter:
    """A BagWriter (one file) when no limit is set, else a SplitBagWriter. Not yet opened."""
    if max_bytes or max_duration_ns:
        return SplitBagWriter(path, typestore, max_bytes=max_bytes,
                              max_duration_ns=max_duration_ns)
    return BagWriter(path, typestore)
