"""./ft bag COMMAND: record, play and inspect rosbag2 (MCAP) bags."""
from __future__ import annotations

import argparse
import os
import sys

from .core.errors import BagError
from .core.info import bag_info, format_info


def cmd_info(args) -> int:
    print(format_info(bag_info(args.bag)))
    return 0


def cmd_play(args) -> int:
    from .player import main as play_main
    return play_main(args.player_args)


def cmd_record(args) -> int:
    """Run the recorder node in this process until Ctrl-C."""
    from .recorder_node import DEFAULT_TOPICS, RecorderNode
    from force_tester_common.ros import spin_nodes
    if os.path.exists(args.output):
        raise BagError(f'output {args.output!r} exists already; expected a new directory name')
    topics = args.topics or DEFAULT_TOPICS
    ros_args = ['--ros-args', '-p', f'bag_path:={args.output}', '-p', f'topics:={list(topics)!r}']
    print(f'recording {", ".join(topics)} to {args.output}; Ctrl-C stops', file=sys.stderr)
    return spin_nodes(RecorderNode, args=['recorder', *ros_args])


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='./ft bag', description='Record, play and inspect rosbag2 MCAP bags.')
    sub = p.add_subparsers(dest='command', required=True, metavar='COMMAND')
    i = sub.add_parser('info', help='topics, types, counts, duration, sample rate, dropped blocks, pulls')
    i.add_argument('bag')
    i.set_defaults(func=cmd_info)
    pl = sub.add_parser('play', help='republish a bag with its original timing (./ft bag play -h)',
                        add_help=False)
    pl.add_argument('player_args', nargs=argparse.REMAINDER)
    pl.set_defaults(func=cmd_play)
    r = sub.add_parser('record', help='record topics to a new MCAP bag until Ctrl-C')
    r.add_argument('-o', '--output', required=True, help='bag directory to create')
    r.add_argument('topics', nargs='*', help='topics (default: every force tester topic)')
    r.set_defaults(func=cmd_record)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BagError as exc:
        print(f'./ft bag {args.command}: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
