"""recorder node: writes chosen topics, as received (serialized CDR), to a rosbag2 MCAP bag.

Topic names resolve as in any ROS node: a relative name (the defaults: ``force``, ``pull_event``, ...) in the
node's namespace (``-r __ns:=/rig2`` records ``/rig2/force``), and through the node's remap rules
(``-r force:=/rig2/force``); the bag holds the resolved names. Topics are subscribed as soon as they appear
on the graph (their type is taken from it); the bag is closed, metadata.yaml written, when the node shuts
down (Ctrl-C included), so the bag is playable by `ros2 bag play` on a full ROS 2 install and by `./ft bag
play` here.

The chunk in progress is written every FLUSH_S (and once it holds CHUNK_BYTES), so a killed
recorder loses at most that much (`./ft bag reindex` recovers the rest). When the disk fills,
the recorder stops recording, finishes the bag with what reached the disk, says so on
/diagnostics (a latched ERROR) and in its log, and stays up until it is stopped
(core/recording.py).
"""
from __future__ import annotations

import errno
import os
import sys
import threading

from rclpy.node import Node

from force_tester_common.conversions import message_class
from force_tester_common.core.channels import GRAPH_TOPICS
from force_tester_common.core.clock import seconds_to_ns
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import BLOCK_QOS, ERROR, OK, Diagnostics, in_namespace, main_for, steady_timer

from .core.errors import BagError
from .core.recording import FLUSH_S, Recording, dated_bag_path
from .core.typestore import default_typestore

DEFAULT_TOPICS = [in_namespace(t) for t in GRAPH_TOPICS]   # relative: in the node's namespace

SPECS = [
    ParamSpec('bag_path', '', 'directory of the bag to write (must not exist yet; empty: rosbag2_YYYY_MM_DD-HH_MM_SS '
                              'in the working directory, as ros2 bag record names it)', read_only=True),
    ParamSpec('topics', DEFAULT_TOPICS, 'topics to record (relative names: in the node\'s namespace; remaps '
                                        'apply)', read_only=True),
    ParamSpec('max_bag_size_mb', 0.0, 'start a new .mcap file in the bag once the current one '
              'holds this many MB (1e6 bytes); 0 = no size split', range=(0.0, 1.0e6),
              read_only=True),
    ParamSpec('max_bag_duration_s', 0.0, 'start a new .mcap file in the bag once the current '
              'one spans this many seconds; 0 = no duration split', range=(0.0, 1.0e6),
              read_only=True),
]


def check(values: dict) -> dict:
    """The values, bag_path made a dated name when empty (a second launch in the same folder writes a new bag; a
    fixed default name was refused as existing), else BagError (one line)."""
    values = {**values, 'bag_path': values['bag_path'] or dated_bag_path()}
    if os.path.exists(values['bag_path']):
        raise BagError(f"bag_path {values['bag_path']!r} exists already; expected a new directory name")
    parent = os.path.dirname(os.path.abspath(values['bag_path']))
    if not os.path.isdir(parent):
        raise BagError(f"bag_path {values['bag_path']!r}: its directory {parent!r} does not exist; expected "
                       'a new directory in an existing one')
    if not values['topics']:
        raise BagError('topics [] is empty; expected one or more topic names')
    for name in ('max_bag_size_mb', 'max_bag_duration_s'):
        if not 0 <= values[name] <= 1.0e6:
            raise BagError(f'{name} {values[name]!r} out of range; expected 0 (no split) '
                           'to 1e6')
    if 0 < values['max_bag_size_mb'] * 1e6 < 1:
        raise BagError(f"max_bag_size_mb {values['max_bag_size_mb']!r} is below 1 byte; "
                       'expected 0 (no split) or a positive size')
    return values


def split_limits(values: dict) -> dict:
    """max_bag_size_mb / max_bag_duration_s -> open_bag_writer's max_bytes / max_duration_ns."""
    return {'max_bytes': int(round(values['max_bag_size_mb'] * 1e6)),
            'max_duration_ns': seconds_to_ns(values['max_bag_duration_s'])}


def split_description(max_bag_size_mb: float, max_bag_duration_s: float) -> str:
    """' (new .mcap file every 50 MB or 10 s)' for the split limits set; '' for none."""
    parts = [f'{max_bag_size_mb:g} MB'] if max_bag_size_mb else []
    parts += [f'{max_bag_duration_s:g} s'] if max_bag_duration_s else []
    return f" (new .mcap file every {' or '.join(parts)})" if parts else ''


PROGRESS_S = 0.5  # period of the recorder's progress report on /diagnostics


class RecorderNode(Node):
    def __init__(self, **kwargs):
        super().__init__('recorder', **kwargs)
        self.diag = Diagnostics(self, 'bag recorder', counters=self._progress, period_s=PROGRESS_S)
        self.params = NodeParams(self, SPECS, check)
        self.lock = threading.Lock()
        self.writer = Recording(self.params.config['bag_path'], default_typestore(),
                                **split_limits(self.params.values)).open()
        self.wanted = [self._resolve(t) for t in self.params.values['topics']]
        self.subscribed = {}
        self.counts = {}  # topic -> messages written
        self._discover()
        steady_timer(self, 0.1, self._discover)
        steady_timer(self, FLUSH_S, self._flush)
        split = split_description(self.params.values['max_bag_size_mb'],
                                  self.params.values['max_bag_duration_s'])
        self.diag.report(OK, f"recording {', '.join(self.wanted)} to {self.writer.path}{split}")

    def _resolve(self, topic: str) -> str:
        """The full name of ``topic`` as this node sees it: its namespace and remap rules applied."""
        try:
            return self.resolve_topic_name(topic)
        except Exception as exc:  # noqa: BLE001 - rclpy raises its own types for a malformed name
            raise BagError(f'topic {topic!r} is not a valid topic name ({exc}); expected a ROS name such as '
                           "'force' or '/rig1/force'") from None

    @property
    def count(self) -> int:
        """Messages written so far."""
        return sum(self.counts.values())

    def _discover(self):
        if self.writer is None:
            return
        graph = dict(self.get_topic_names_and_types())
        for topic in self.wanted:
            if topic in self.subscribed or topic not in graph:
                continue
            type_name = graph[topic][0]
            try:
                cls = message_class(type_name)
                self.writer.add_topic(topic, type_name)
            except (ImportError, AttributeError, BagError) as exc:
                self.diag.report(ERROR, f'cannot record {topic} of type {type_name}: {exc}')
                self.subscribed[topic] = None
                continue
            self.subscribed[topic] = self.create_subscription(
                cls, topic, lambda data, t=topic: self._write(t, data), BLOCK_QOS, raw=True)

    def _progress(self) -> dict:
        """How many messages are in the bag so far, in all and per topic (the heartbeat's values on
        /diagnostics): a monitor can see the recording advance, and tell when it has caught up."""
        with self.lock:
            return {'messages': self.count, **self.counts}

    def _write(self, topic: str, data: bytes):
        with self.lock:
            if self.writer is not None:
                try:
                    self.writer.write(topic, self.get_clock().now().nanoseconds, data)
                except BagError as exc:
                    if self.writer.failed is not None:
                        self._stop_on_io_failure(self.writer.failed)
                    else:
                        self.diag.report(ERROR, f'cannot record a {topic} message: {exc}')
                    return
                except OSError as exc:
                    self._stop_on_io_failure(exc)
                    return
                self.counts[topic] = self.counts.get(topic, 0) + 1

    def _flush(self):
        """Write the chunk in progress: what a killed recorder would lose is bounded by this."""
        with self.lock:
            if self.writer is not None:
                try:
                    self.writer.flush()
                except OSError as exc:
                    self._stop_on_io_failure(exc)

    def _stop_on_io_failure(self, exc: OSError):
        """The disk failed a write (full, most likely): stop recording and finish the bag with
        what reached the disk. Called with the lock held."""
        writer, self.writer = self.writer, None
        for topic, sub in self.subscribed.items():
            if sub is not None:
                self.destroy_subscription(sub)
                self.subscribed[topic] = None
        report = writer.salvage()
        what = 'disk full' if getattr(exc, 'errno', None) == errno.ENOSPC else 'I/O failure'
        if report is not None:
            kept = (f'bag {writer.path} finished with the {report.message_count} messages that '
                    'reached the disk (metadata.yaml written)')
        else:
            kept = (f'bag {writer.path} could not be finished (no metadata.yaml); free space '
                    f'and run ./ft bag reindex {writer.path}')
        self.diag.report(ERROR, f'{what}: recording stopped after {self.count} messages '
                         f'({exc.strerror or exc}); {kept}', latch=True,
                         messages=self.count, kept=report.message_count if report else -1)

    def close(self):
        with self.lock:
            if self.writer is not None:
                try:
                    path = self.writer.close()
                except OSError as exc:
                    self._stop_on_io_failure(exc)
                    return
                self.writer = None
                print(f'recorder: bag closed: {path} ({self.count} messages)', file=sys.stderr)


main = main_for(RecorderNode)
