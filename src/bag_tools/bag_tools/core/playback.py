"""Pure playback scheduling: bag stamps -> wall-clock offsets. No clock access. Also the
player's command-line options, shared by the `player` executable and `./ft bag play`."""

from __future__ import annotations

import argparse
import math
import operator
import os
from bisect import bisect_left, bisect_right
from collections.abc import Sequence
from typing import NamedTuple

from force_tester_common.core.clock import NS_PER_S, seconds_to_ns

from .errors import BagError
from .metadata import METADATA_FILE


class Schedule(NamedTuple):
    """Messages stamps[start_index:stop_index] are played, message start_index + k at
    wall offset offsets_ns[k] after the first played one (offsets_ns[0] == 0)."""

    start_index: int
    stop_index: int
    offsets_ns: list[int]


def _seconds(name: str, value: float, allow_none: bool = False) -> float | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value) or value < 0:
        raise BagError(f'{name} {value!r} is invalid; expected a finite number of seconds >= 0')
    return float(value)


def schedule(stamps_ns: Sequence[int], rate: float = 1.0, start_offset_s: float = 0,
             stop_offset_s: float | None = None) -> Schedule:
    """Wall offsets for replaying messages with bag stamps stamps_ns (ints, non-decreasing).

    rate > 0 scales time (2.0 = twice as fast). start_offset_s / stop_offset_s select the
    messages with first + start <= stamp <= first + stop (relative to the first stamp
    of the bag); stop None = to the end.
    """
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) \
            or not math.isfinite(rate) or rate <= 0:
        raise BagError(f'playback rate {rate!r} is invalid; expected a finite number > 0')
    start_s = _seconds('start offset', start_offset_s)
    stop_s = _seconds('stop offset', stop_offset_s, allow_none=True)
    if stop_s is not None and stop_s < start_s:
        raise BagError(f'stop offset {stop_offset_s!r} s is before start offset '
                       f'{start_offset_s!r} s')
    stamps = list(stamps_ns)
    if not stamps:
        return Schedule(0, 0, [])
    for i, s in enumerate(stamps):
        if isinstance(s, bool) or not isinstance(s, int):
            try:
                stamps[i] = s = operator.index(s)  # numpy integers
            except TypeError:
                raise BagError(f'stamp #{i} {s!r} is not an integer nanosecond count') from None
        if i and s < stamps[i - 1]:
            raise BagError(f'stamp #{i} {s} ns is before the previous one {stamps[i - 1]} ns; '
                           'expected stamps in time order')
    first = stamps[0]
    lo = bisect_left(stamps, first + seconds_to_ns(start_s))
    hi = len(stamps) if stop_s is None else bisect_right(stamps, first + seconds_to_ns(stop_s))
    if lo >= len(stamps):
        raise BagError(f'start offset {start_offset_s!r} s is beyond the end of the bag '
                       f'({(stamps[-1] - first) / NS_PER_S:.3f} s)')
    base = stamps[lo]
    if rate == 1:
        offsets = [s - base for s in stamps[lo:hi]]
    else:
        offsets = [round((s - base) / rate) for s in stamps[lo:hi]]
    return Schedule(lo, hi, offsets)


PLAY_DESCRIPTION = ('Republish a rosbag2 bag (MCAP or sqlite3) with its original timing. Topics '
                    'whose message type is not installed are skipped with a warning; the rest '
                    'play. Options may come before or after the bag; ROS arguments go last, '
                    'after --ros-args.')


def add_play_arguments(p: argparse.ArgumentParser) -> None:
    """The player's options (ROS-free, so `./ft bag --help` needs no rclpy)."""
    p.add_argument('bag', nargs='?', default=None, help='bag directory (with metadata.yaml)')
    p.add_argument('--rate', type=float, default=1.0,
                   help='time scale: 2.0 plays twice as fast (default 1.0)')
    p.add_argument('--topics', nargs='+', metavar='TOPIC',
                   help='play only these topics (default: all)')
    p.add_argument('--loop', action='store_true',
                   help='play again from the start when done (Ctrl-C ends)')
    p.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                   help='skip the first S seconds of the bag')
    p.add_argument('--stop-offset', type=float, default=None, metavar='S',
                   help='stop S seconds after the start of the bag')
    p.add_argument('--remap', nargs='+', default=[], metavar='FROM:=TO',
                   help='publish topic FROM as TO')
    p.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                   help='before playing, wait until every played topic has N subscribers')
    p.add_argument('--wait-timeout', type=float, default=30.0, metavar='S',
                   help='give up waiting for subscribers after S seconds (default 30)')


def take_bag_argument(args: argparse.Namespace) -> argparse.Namespace:
    """`--topics /a /b BAG` puts BAG among the topics (nargs='+'): a last item that is a
    directory with a metadata.yaml, or not an absolute name as topics are, is the bag.
    BagError if there is none."""
    if args.bag is None and args.topics and len(args.topics) > 1:
        last = args.topics[-1]
        if not last.startswith('/') or os.path.isfile(os.path.join(last, METADATA_FILE)):
            args.bag = args.topics.pop()
    if args.bag is None:
        raise BagError('no bag given; expected play [options] BAG (see --help)')
    return args
