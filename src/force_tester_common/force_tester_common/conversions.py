"""Messages <-> arrays for the force tester's sample-block topics.

The channel names are the DAQ export's column names (SI units), so a pull is one
``dict[str, np.ndarray]`` whether it comes from the simulator, a bag or a CSV export.
"""
from __future__ import annotations

import array
import importlib
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time

from .core import clock
from .core.blocks import block_problem, stamp_problem
from .core.channels import BLOCK_TYPES, CORRECTED_TYPE


@dataclass(frozen=True)
class BlockTopic:
    """A sample-block topic: its default name, message type and field -> channel map."""
    topic: str
    msg_type: type
    fields: dict  # message field -> channel (DAQ column) name


def message_class(type_name: str):
    """The Python class of an installed 'pkg/msg/Type' (or 'pkg/srv/Type'): the one place a type name
    becomes a class. ValueError for a malformed name, ImportError when its package is not installed,
    AttributeError when the package has no such type."""
    parts = type_name.split('/')
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"type name {type_name!r} is malformed; expected 'pkg/msg/Type'")
    pkg, kind, name = parts
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


BLOCK_TOPICS = tuple(BlockTopic(topic, message_class(t), fields) for t, (topic, fields) in BLOCK_TYPES.items())
CORRECTED_TOPIC = BlockTopic(CORRECTED_TYPE[1][0], message_class(CORRECTED_TYPE[0]), CORRECTED_TYPE[1][1])


def stamp_to_ns(stamp: Time) -> int:
    return clock.stamp_to_ns(stamp.sec, stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    sec, nanosec = clock.ns_to_stamp(ns)
    return Time(sec=sec, nanosec=nanosec)


def to_array(values) -> np.ndarray:
    """A float64[] message field (array.array('d')) as a numpy view, without copying."""
    if isinstance(values, array.array):
        return np.frombuffer(values, dtype=np.float64) if len(values) else np.empty(0)
    return np.asarray(values, dtype=np.float64)


def to_field(values: np.ndarray) -> array.array:
    """A numpy array as a float64[] message field (array.array is the fast path of the setters)."""
    return array.array('d', np.ascontiguousarray(values, dtype=np.float64).tobytes())


def fill_block(msg, stamp_ns: int, sample_rate_hz: float, seq: int, arrays: dict, frame_id: str = ''):
    """Fill a block message's header, rate, seq and its array fields from ``arrays`` (field -> array)."""
    msg.header.stamp = ns_to_stamp(stamp_ns)
    msg.header.frame_id = frame_id
    msg.sample_rate_hz = float(sample_rate_hz)
    msg.seq = int(seq)
    for field, values in arrays.items():
        setattr(msg, field, to_field(values))
    return msg


def block_message(topic: BlockTopic, channels: dict, start: int, stop: int, stamp_ns: int,
                  sample_rate_hz: float, seq: int):
    """The message of ``topic`` carrying samples [start, stop) of the channels present in ``channels``.

    Channels missing from ``channels`` (optional DAQ columns) are left empty.
    """
    arrays = {f: channels[c][start:stop] for f, c in topic.fields.items() if c in channels}
    return fill_block(topic.msg_type(), stamp_ns, sample_rate_hz, seq, arrays)


def message_problem(msg, topic: BlockTopic, required) -> str | None:
    """Why a received block message cannot be used (stamp, rate, array lengths), or None.
    required: the message fields the caller reads."""
    stamp = msg.header.stamp
    return stamp_problem(stamp.sec, stamp.nanosec) or block_problem(
        msg.sample_rate_hz, {f: len(getattr(msg, f)) for f in topic.fields}, required)
