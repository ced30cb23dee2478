"""player: republish a rosbag2 (MCAP) bag with its original timing.

    player BAG [--rate R] [--topics T ...] [--loop] [--start-offset S] [--stop-offset S]
               [--remap FROM:=TO ...] [--wait-for-subscribers N]

Messages go out as recorded (serialized CDR, no re-encoding) at their recorded receive times,
scaled by --rate. A missing, empty or corrupt bag ends with one line on stderr and exit code 2.
"""
from __future__ import annotations

import argparse
import sys
import time

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from force_tester_common.core.clock import NS_PER_S
from force_tester_common.ros import BLOCK_QOS, ros_init

from .core.errors import BagError
from .core.playback import schedule
from .core.reader import open_bag
from .recorder_node import message_class


def build_parser(prog: str = 'player') -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description='Republish a rosbag2 MCAP bag with its original timing.')
    p.add_argument('bag', help='bag directory (with metadata.yaml)')
    p.add_argument('--rate', type=float, default=1.0, help='time scale: 2.0 plays twice as fast (default 1.0)')
    p.add_argument('--topics', nargs='+', metavar='TOPIC', help='play only these topics (default: all)')
    p.add_argument('--loop', action='store_true', help='play again from the start when done (Ctrl-C ends)')
    p.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                   help='skip the first S seconds of the bag')
    p.add_argument('--stop-offset', type=float, default=None, metavar='S',
                   help='stop S seconds after the start of the bag')
    p.add_argument('--remap', nargs='+', default=[], metavar='FROM:=TO', help='publish topic FROM as TO')
    p.add_argument('--wait-for-subscribers', type=int, default=0, metavar='N',
                   help='before playing, wait until every played topic has N subscribers')
    p.add_argument('--wait-timeout', type=float, default=30.0, metavar='S',
                   help='give up waiting for subscribers after S seconds (default 30)')
    return p


def parse_remaps(items: list) -> dict:
    remaps = {}
    for item in items:
        src, sep, dst = item.partition(':=')
        if not sep or not src.startswith('/') or not dst.startswith('/'):
            raise BagError(f'remap {item!r} is malformed; expected /from:=/to')
        remaps[src] = dst
    return remaps


def load(args):
    """Read the selected messages and their playback offsets (all validation happens here)."""
    remaps = parse_remaps(args.remap)
    bag = open_bag(args.bag)
    try:
        msgs = list(bag.messages(args.topics))
        types = {m.topic: m.type_name for m in msgs}
    finally:
        bag.close()
    if not msgs:
        raise BagError(f'bag {args.bag!r} has no messages on the selected topics; nothing to play')
    plan = schedule([m.stamp_ns for m in msgs], args.rate, args.start_offset, args.stop_offset)
    return msgs[plan.start_index:plan.stop_index], plan.offsets_ns, types, remaps


class PlayerNode(Node):
    def __init__(self, types: dict, remaps: dict):
        super().__init__('player')
        self.pubs = {t: self.create_publisher(message_class(ty), remaps.get(t, t), BLOCK_QOS)
                     for t, ty in types.items()}

    def wait_for_subscribers(self, n: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while any(p.get_subscription_count() < n for p in self.pubs.values()):
            if time.monotonic() > deadline:
                return False
            time.sleep(0.05)
        return True

    def play(self, msgs, offsets_ns) -> int:
        t0 = time.monotonic_ns()
        for msg, offset in zip(msgs, offsets_ns):
            delay = (t0 + offset - time.monotonic_ns()) / NS_PER_S
            if delay > 0:
                time.sleep(delay)
            self.pubs[msg.topic].publish(msg.cdr)
        return len(msgs)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args_end = argv.index('--ros-args') if '--ros-args' in argv else len(argv)
    args = build_parser().parse_args(argv[:args_end])
    try:
        msgs, offsets, types, remaps = load(args)
    except BagError as exc:
        print(f'player: error: {exc}', file=sys.stderr)
        return 2
    try:
        with ros_init(['player', *argv[args_end:]]):
            node = PlayerNode(types, remaps)
            if args.wait_for_subscribers and not node.wait_for_subscribers(args.wait_for_subscribers,
                                                                           args.wait_timeout):
                print(f'player: error: fewer than {args.wait_for_subscribers} subscriber(s) after '
                      f'{args.wait_timeout} s', file=sys.stderr)
                return 2
            while True:
                n = node.play(msgs, offsets)
                print(f'player: played {n} messages from {args.bag}', file=sys.stderr)
                if not args.loop:
                    break
            time.sleep(0.5)  # let reliable QoS deliver the tail before the node goes away
            node.destroy_node()
    except (KeyboardInterrupt, ExternalShutdownException):
        return 130
    return 0


if __name__ == '__main__':
    sys.exit(main())
