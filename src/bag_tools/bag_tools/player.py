"""player: republish a rosbag2 bag (MCAP or sqlite3) with its original timing.

    player BAG [--rate R] [--topics T ...] [--loop] [--start-offset S] [--stop-offset S]
               [--remap FROM:=TO ...] [--wait-for-subscribers N] [--ros-args ...]

Messages go out as recorded (serialized CDR, no re-encoding) at their recorded receive times,
scaled by --rate. Like `ros2 bag play`, a topic whose message type is not installed (no Python
package) is skipped with a warning and the rest play; old 'pkg/Type' names are accepted. An
empty bag has nothing to play (exit 0). A missing or corrupt bag ends with one line on stderr
and exit code 2; Ctrl-C stops cleanly with exit code 130.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from dataclasses import dataclass, field

from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from force_tester_common.conversions import message_class
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.ros import BLOCK_QOS, ros_init, startup_failure

from .core.errors import BagError, one_line
from .core.playback import PLAY_DESCRIPTION, add_play_arguments, schedule, take_bag_argument
from .core.reader import brief, open_bag
from .core.typestore import normalize_type

EXIT_INTERRUPTED = 130


def build_parser(prog: str = 'player') -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=PLAY_DESCRIPTION)
    add_play_arguments(p)
    return p


def parse_remaps(items: list) -> dict:
    remaps = {}
    for item in items:
        src, sep, dst = item.partition(':=')
        if not sep or not src.startswith('/') or not dst.startswith('/'):
            raise BagError(f'remap {item!r} is malformed; expected /from:=/to')
        remaps[src] = dst
    return remaps


def installed_class(type_name: str):
    """(class, None) for an installed 'pkg/msg/Type' (or old 'pkg/Type'), else (None, why)."""
    name = normalize_type(type_name)
    parts = name.split('/')
    if len(parts) != 3 or not all(parts):
        return None, f"type name {type_name!r} is malformed; expected 'pkg/msg/Type'"
    pkg, kind, cls = parts
    try:
        return message_class(name), None
    except ImportError:
        return None, f"type {name} is not installed (no Python package '{pkg}')"
    except AttributeError:
        return None, f'type {name} is not installed ({pkg}.{kind} has no {cls})'
    except Exception as exc:  # noqa: BLE001 - a broken package is skipped like a missing one
        return None, f'package {pkg} does not load: {brief(exc)}'


@dataclass
class Plan:
    """What load() found: messages to play with their offsets, publishers' classes, skipped
    topics with the reason, and notes (count differences) to show."""

    msgs: list = field(default_factory=list)
    offsets_ns: list = field(default_factory=list)
    classes: dict = field(default_factory=dict)
    remaps: dict = field(default_factory=dict)
    skipped: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    empty: bool = False


def load(args) -> Plan:
    """Read the selected playable messages and their playback offsets (all validation and
    every skip decision happens here, before ROS starts)."""
    take_bag_argument(args)
    plan = Plan(remaps=parse_remaps(args.remap))
    with open_bag(args.bag, allow_empty=True) as bag:
        topics = bag.topics()
        if args.topics:
            missing = [t for t in args.topics if t not in topics]
            if missing:
                raise BagError(f'topic {missing[0]!r} not in bag {args.bag!r}; expected one '
                               f'of {sorted(topics)[:8]!r}')
        selected = list(args.topics or topics)
        if bag.message_count == 0:
            plan.empty = True
            return plan
        for t in selected:
            cls, why = installed_class(topics[t].type_name)
            if cls is None:
                plan.skipped[t] = why
            else:
                plan.classes[t] = cls
        playable = [t for t in selected if t in plan.classes]
        msgs = list(bag.messages(playable)) if playable else []
        read = Counter(m.topic for m in msgs)
        meta = {d.topic: d.metadata_count for d in bag.count_differences()}
        for t in playable:
            if t in meta:
                said = 'does not list it' if meta[t] is None else f'says {meta[t]}'
                plan.notes.append(f'{t}: {read[t]} messages read, metadata.yaml {said}')
    if not msgs:
        if plan.skipped and not playable:
            raise BagError(f'bag {args.bag!r}: none of the selected topics can be played '
                           f'({len(plan.skipped)} skipped: {skipped_summary(plan.skipped)})')
        plan.empty = True
        return plan
    sched = schedule([m.stamp_ns for m in msgs], args.rate, args.start_offset, args.stop_offset)
    plan.msgs = msgs[sched.start_index:sched.stop_index]
    plan.offsets_ns = sched.offsets_ns
    return plan


def skipped_summary(skipped: dict) -> str:
    return '; '.join(f'{t}: {why}' for t, why in skipped.items())


class PlayerNode(Node):
    def __init__(self, classes: dict, remaps: dict):
        super().__init__('player')
        self.pubs = {t: self.create_publisher(cls, remaps.get(t, t), BLOCK_QOS)
                     for t, cls in classes.items()}
        self.published = 0   # messages published so far, every pass (what an interrupt reports)

    def wait_for_subscribers(self, n: int, timeout_s: float) -> dict:
        """Wait until every topic has N subscribers, at most TIMEOUT_S: {published topic: its subscribers} of
        the topics that fell short ({} when none did)."""
        deadline = time.monotonic() + timeout_s
        while True:
            short = {p.topic_name: p.get_subscription_count() for p in self.pubs.values()
                     if p.get_subscription_count() < n}
            if not short or time.monotonic() > deadline:
                return short
            time.sleep(0.05)

    def play(self, msgs, offsets_ns) -> None:
        """Publish one pass; ``published`` counts each message as it goes out."""
        t0 = time.monotonic_ns()
        for msg, offset in zip(msgs, offsets_ns):
            delay = (t0 + offset - time.monotonic_ns()) / NS_PER_S
            if delay > 0:
                time.sleep(delay)
            try:
                self.pubs[msg.topic].publish(msg.cdr)
            except Exception:
                # Ctrl-C: rclpy's signal handler shuts the context down before Python raises
                # KeyboardInterrupt, so publish fails first (RCLError). That is the interrupt.
                if not self.context.ok():
                    raise KeyboardInterrupt from None
                raise
            self.published += 1


def run(args, ros_args=(), prog: str = 'player') -> int:
    """Play as the parsed options say. BagError for bad input; 0 when done (or nothing to
    play), 2 when subscribers never came, 130 on Ctrl-C."""
    def say(kind: str, text: str) -> None:
        print(f'{prog}: {kind}{one_line(text)}', file=sys.stderr)

    try:
        plan = load(args)
    except KeyboardInterrupt:
        say('', 'interrupted while reading the bag; nothing played')
        return EXIT_INTERRUPTED
    for topic, why in plan.skipped.items():
        say('warning: ', f'skipping {topic}: {why}')
    for note in plan.notes:
        say('warning: ', f'message count differs: {note}')
    if plan.empty:
        say('', f'bag {args.bag} has no messages on the selected topics; nothing to play')
        return 0
    node, started = None, False
    try:
        with ros_init([prog, *ros_args]):
            node = PlayerNode(plan.classes, plan.remaps)
            started = True
            try:
                short = node.wait_for_subscribers(args.wait_for_subscribers, args.wait_timeout) \
                    if args.wait_for_subscribers else {}
                if short:
                    say('error: ', f'fewer than {args.wait_for_subscribers} subscriber(s) after '
                        f'{args.wait_timeout:g} s on ' + ', '.join(f'{t} ({n})' for t, n in short.items()))
                    return 2
                while True:
                    node.play(plan.msgs, plan.offsets_ns)
                    skipped = f'; skipped {len(plan.skipped)} topic(s): ' \
                        f'{", ".join(plan.skipped)}' if plan.skipped else ''
                    say('', f'played {len(plan.msgs)} messages on {len(plan.classes)} topic(s) '
                        f'from {args.bag}{skipped}')
                    if not args.loop:
                        break
                time.sleep(0.5)  # let reliable QoS deliver the tail before the node goes away
            finally:
                try:
                    node.destroy_node()
                except Exception:  # after Ctrl-C the context is gone already
                    if node.context.ok():
                        raise
    except (KeyboardInterrupt, ExternalShutdownException):
        say('', f'interrupted; stopped after {node.published if node is not None else 0} messages')
        return EXIT_INTERRUPTED
    except Exception as exc:  # noqa: BLE001 - while starting (rclpy refusing --ros-args): one line
        if started:
            raise
        code, line = startup_failure(exc)
        say('error: ', line)
        return code
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args_end = argv.index('--ros-args') if '--ros-args' in argv else len(argv)
    args = build_parser().parse_args(argv[:args_end])
    try:
        return run(args, argv[args_end:])
    except BagError as exc:
        print(f'player: error: {exc}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
