"""A bag being recorded live: bounded loss when the recorder is killed, a clean stop when the
disk fills.

**Chunks.** An MCAP writer keeps the chunk in progress in memory and writes it whole. What a
SIGKILL (or a power cut) loses is that chunk; every chunk written before it is recovered by
`./ft bag reindex`. rosbags closes a chunk at 1 MiB, rosbag2's MCAP plugin at 768 KiB; here a
chunk is closed and handed to the OS once it holds CHUNK_BYTES of records, and at least every
FLUSH_S by the recorder's timer (flush()), whichever comes first. So a kill loses at most
CHUNK_BYTES of records and at most FLUSH_S of data (plus the timer's lateness on a busy
machine); docs/speed.md states the figures at the live rate.

**Full disk.** A file of RESERVE_BASE_BYTES + RESERVE_PER_CHUNK_BYTES per chunk written is kept
allocated in the bag directory (`.reserve`), grown at each flush(). When a write fails with an
OSError (ENOSPC, or the reserve cannot grow), salvage() closes the files without finishing
them, deletes the reserve and reindexes the bag: the messages whose chunks reached the disk
get a summary and a metadata.yaml, nothing else does. If even that fails, the bag is left with
no metadata.yaml, which `./ft bag info` reports as needing `./ft bag reindex`.

The chunk control reaches into the rosbags MCAP storage writer (its pending chunk and its
close_chunk()), rosbags being pinned in requirements.lock; tests/bag_tools/
test_recording_survives.py fails if that stops working.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from rosbags.typesys.store import Typestore

from .errors import BagError
from .reindex import RESERVE_NAME, ReindexReport, reindex
from .split_writer import SplitBagWriter, open_bag_writer

#: a chunk is closed and written once it holds this many bytes of records
CHUNK_BYTES = 256 * 1024
#: ... and at least this often (the recorder's timer calls flush())
FLUSH_S = 0.1
#: space kept free for the summary and metadata.yaml written when the disk is full
RESERVE_BASE_BYTES = 256 * 1024
RESERVE_PER_CHUNK_BYTES = 256  # a chunk index record in the summary is about 170 bytes

#: the folder name `ros2 bag record` gives a bag when none is named (local time): a new one a second
DATED_BAG_FORMAT = 'rosbag2_%Y_%m_%d-%H_%M_%S'


def dated_bag_path(now: float | None = None) -> str:
    """The bag folder a recorder given no bag_path writes, in the working directory, as `ros2 bag record` names
    it: rosbag2_YYYY_MM_DD-HH_MM_SS (NOW, seconds since the epoch, default the clock's)."""
    return time.strftime(DATED_BAG_FORMAT, time.localtime(now))


class Recording:
    """open_bag_writer() plus the chunk policy, the disk reserve and salvage() (see above).

    write() and flush() raise OSError when the disk fails them; the recording is then stopped
    and salvage() makes what reached the disk a readable bag.
    """

    def __init__(self, path: str | Path, typestore: Typestore, *, max_bytes: int = 0,
                 max_duration_ns: int = 0, chunk_bytes: int = CHUNK_BYTES) -> None:
        if isinstance(chunk_bytes, bool) or not isinstance(chunk_bytes, int) or chunk_bytes < 1:
            raise BagError(f'chunk_bytes {chunk_bytes!r} is invalid; expected an integer >= 1')
        self.path = Path(path)
        self.chunk_bytes = chunk_bytes
        self.writer = open_bag_writer(path, typestore, max_bytes=max_bytes,
                                      max_duration_ns=max_duration_ns)
        self.chunks = 0           # chunks written by this class
        self.failed: OSError | None = None
        self._reserve_fd = -1
        self._reserved = 0

    # -- lifecycle ---------------------------------------------------------------------
    def open(self) -> Recording:
        self.writer.open()
        try:
            self._flush_file()  # the MCAP magic and header reach the disk at once
            self._reserve_fd = os.open(self.path / RESERVE_NAME, os.O_CREAT | os.O_WRONLY, 0o600)
            self._grow_reserve()
        except OSError as exc:
            self._free_reserve()
            self.writer.abort()
            raise BagError(f'cannot reserve {RESERVE_BASE_BYTES} bytes in {str(self.path)!r} '
                           f'for finishing the bag: {exc}') from None
        return self

    def add_topic(self, topic: str, type_name: str) -> None:
        self.writer.add_topic(topic, type_name)

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """Append one message; its chunk is written once full. OSError: the disk failed."""
        self._require_running()
        try:
            self.writer.write(topic, stamp_ns, data)
        except BagError as exc:
            if isinstance(exc.__context__, OSError):  # the writer's wrapped I/O failure
                self._fail(exc.__context__)
            raise
        storage = self._storage()
        if storage is not None and storage.chunk.bio.tell() >= self.chunk_bytes:
            self._close_chunk(storage)

    def flush(self) -> None:
        """Write the chunk in progress (if it has messages) and grow the reserve."""
        self._require_running()
        storage = self._storage()
        if storage is not None and storage.chunk.msgs:
            self._close_chunk(storage)
        try:
            self._grow_reserve()
        except OSError as exc:
            self._fail(exc)
            raise

    def close(self) -> Path:
        """Finish the bag (summary, metadata.yaml) after releasing the reserve for it."""
        self._require_running()
        self.flush()
        self._free_reserve()
        return self.writer.close()

    def salvage(self) -> ReindexReport | None:
        """After an OSError: finish what reached the disk (see the module docstring). None when
        that fails too (the bag then has no metadata.yaml)."""
        self._abandon()
        self._free_reserve()
        try:
            return reindex(self.path)
        except (OSError, BagError):
            return None

    # -- internals ---------------------------------------------------------------------
    def _require_running(self) -> None:
        if self.failed is not None:
            raise BagError(f'recording to {str(self.path)!r} stopped after an I/O failure: '
                           f'{self.failed}')

    def _fail(self, exc: OSError) -> None:
        self.failed = exc

    def _file_writer(self):
        """The BagWriter of the file being written (None between split files)."""
        w = self.writer
        return w._split if isinstance(w, SplitBagWriter) else w

    def _storage(self):
        """rosbags' MCAP storage writer of the file being written, or None."""
        fw = self._file_writer()
        rw = getattr(fw, '_writer', None) if fw is not None else None
        return getattr(rw, 'storage', None) if rw is not None else None

    def _close_chunk(self, storage) -> None:
        try:
            storage.close_chunk()
            storage.bio.flush()
        except OSError as exc:
            self._fail(exc)
            raise
        self.chunks += 1

    def _flush_file(self) -> None:
        storage = self._storage()
        if storage is not None:
            storage.bio.flush()

    def _grow_reserve(self) -> None:
        want = RESERVE_BASE_BYTES + RESERVE_PER_CHUNK_BYTES * self.chunks
        if self._reserve_fd >= 0 and want > self._reserved:
            os.posix_fallocate(self._reserve_fd, 0, want)
            self._reserved = want

    def _free_reserve(self) -> None:
        if self._reserve_fd >= 0:
            os.close(self._reserve_fd)
            self._reserve_fd = -1
        (self.path / RESERVE_NAME).unlink(missing_ok=True)

    def _abandon(self) -> None:
        """Close the file being written without finishing it (its buffered bytes are dropped)."""
        storage = self._storage()
        if storage is not None:
            try:
                storage.bio.close()   # flushes what it can, closes the file in any case
            except OSError:
                pass
        fw = self._file_writer()
        if fw is not None:
            fw._writer, fw._closed = None, True
        w = self.writer
        if isinstance(w, SplitBagWriter):
            w._split, w._closed = None, True
