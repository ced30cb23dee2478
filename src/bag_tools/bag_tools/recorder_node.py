"""recorder node: writes chosen topics, as received (serialized CDR), to a rosbag2 MCAP bag.

Topics are subscribed as soon as they appear on the graph (their type is taken from it); the
bag is closed, metadata.yaml written, when the node shuts down (Ctrl-C included), so the bag is
playable by `ros2 bag play` on a full ROS 2 install and by `./ft bag play` here.
"""
from __future__ import annotations

import importlib
import os
import sys
import threading

from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import BLOCK_QOS, ERROR, OK, Diagnostics, main_for
from rclpy.node import Node

from .core.errors import BagError
from .core.typestore import default_typestore
from .core.writer import BagWriter

DEFAULT_TOPICS = ['/motor', '/encoder', '/accel', '/force', '/pull_event', '/force_corrected',
                  '/pull_score', '/set_summary']

SPECS = [
    ParamSpec('bag_path', 'bag', 'directory of the bag to write (must not exist yet)', read_only=True),
    ParamSpec('topics', DEFAULT_TOPICS, 'topics to record', read_only=True),
]


def message_class(type_name: str):
    """The Python class of 'pkg/msg/Type'."""
    pkg, kind, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


def check(values: dict) -> dict:
    if not values['bag_path']:
        raise BagError("bag_path '' is empty; expected the directory of a new bag")
    if os.path.exists(values['bag_path']):
        raise BagError(f"bag_path {values['bag_path']!r} exists already; expected a new directory name")
    if not values['topics']:
        raise BagError('topics [] is empty; expected one or more topic names')
    return values


class RecorderNode(Node):
    def __init__(self, **kwargs):
        super().__init__('recorder', **kwargs)
        self.diag = Diagnostics(self, 'bag recorder')
        self.params = NodeParams(self, SPECS, check)
        self.lock = threading.Lock()
        self.writer = BagWriter(self.params.values['bag_path'], default_typestore()).open()
        self.wanted = list(self.params.values['topics'])
        self.subscribed = {}
        self.count = 0
        self._discover()
        self.create_timer(0.1, self._discover)
        self.diag.report(OK, f"recording {', '.join(self.wanted)} to {self.writer.path}")

    def _discover(self):
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

    def _write(self, topic: str, data: bytes):
        with self.lock:
            if self.writer is not None:
                self.writer.write(topic, self.get_clock().now().nanoseconds, data)
                self.count += 1

    def close(self):
        with self.lock:
            if self.writer is not None:
                path = self.writer.close()
                self.writer = None
                print(f'recorder: bag closed: {path} ({self.count} messages)', file=sys.stderr)


main = main_for(RecorderNode)
