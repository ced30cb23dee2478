"""Soak: the live graph (sim, correction, validator, recorder) at full rate for a long run.

    ./ft bench soak [--seconds 600] [--rate 1.0] [--out runs/soak] [--json FILE]

Pulls of the five test sets back to back (each 2 s of 50 kHz data) for about --seconds, the
four nodes as separate processes over DDS, as `./ft demo` runs them. At the end it prints, per
topic, the messages published (from the publishers' own counters on /diagnostics: the sim's
blocks and pulls, the correction's pairs, the validator's scores and OK pulls) against the
messages in the bag (they must be equal), the RSS of every node process (and the sim's worker)
when the first pull is scored and at the end, the dropped blocks (the validator's per-pull
count and the seq gaps in the bag), and the bag's data rate with the loss bound of the
recorder's chunk policy at that rate. Exit 1 if any count differs or a block was dropped.

The 10-minute default needs a quiet machine (it keeps both cores of this one busy).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

from bag_tools.core.info import bag_info
from bag_tools.core.recording import CHUNK_BYTES, FLUSH_S
from force_tester_common.core.channels import (
    BLOCK_TYPES,
    CORRECTED_TYPE,
    PULL_EVENT_TOPIC,
    PULL_SCORE_TOPIC,
    SET_SUMMARY_TOPIC,
)
from force_tester_common.core.scores import PULL_OK
from ft_cli.commands.demo import rig_params
from ft_cli.graph import Graph, ScoreCollector
from ft_cli.paths import RUNS

PULL_S = 2.0          # seconds of data in one pull (100,000 samples at 50 kHz)
SETS = (1, 2, 3, 4, 5)
RECORD_OVERHEAD = 31  # MCAP message record bytes besides the data
NODES = ('sim_node', 'correction_node', 'validator_node', 'recorder_node')


class Counters(ScoreCollector):
    """ScoreCollector plus the latest heartbeat values of every node."""

    def __init__(self):
        self.latest = {}  # status name -> {key: value}
        super().__init__()

    def _on_diagnostics(self, msg):
        super()._on_diagnostics(msg)
        for status in msg.status:
            self.latest.setdefault(status.name, {}).update({kv.key: kv.value for kv in status.values})

    def value(self, node: str, key: str) -> int:
        vals = [int(float(v[key])) for name, v in self.latest.items()
                if name.startswith(f'{node}:') and key in v]
        return max(vals, default=0)

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)


def rss_kb(pid: int) -> int:
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def children(pid: int) -> list:
    try:
        return [int(c) for t in Path(f'/proc/{pid}/task').iterdir()
                for c in (t / 'children').read_text().split()]
    except OSError:
        return []


def rss_all(graph: Graph) -> dict:
    out = {name: rss_kb(graph.procs[name].pid) for name in NODES}
    workers = children(graph.procs['sim_node'].pid)
    out['sim worker'] = sum(rss_kb(p) for p in workers)
    return out


def published_counts(c: Counters) -> dict:
    """Messages published per topic, from the publishers' own counters."""
    out = {topic: c.value('sim', 'blocks_per_topic') for topic, _ in BLOCK_TYPES.values()}
    out[PULL_EVENT_TOPIC] = 2 * c.value('sim', 'pulls')
    out[CORRECTED_TYPE[1][0]] = c.value('correction', 'pairs')
    out[PULL_SCORE_TOPIC] = c.value('validator', 'scores')
    out[SET_SUMMARY_TOPIC] = sum(1 for s in c.scores if s['status'] == PULL_OK)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench soak', description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=600.0, help='length of the run, s of data (default 600)')
    ap.add_argument('--rate', type=float, default=1.0, help='sim pace, real-time factor (default 1.0)')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--out', default=str(RUNS / 'soak'), help='bag/ and logs/ go here (replaced)')
    ap.add_argument('--json', help='write the figures to this file too')
    ap.add_argument('--domain', type=int, default=1 + os.getpid() % 100,
                    help='ROS_DOMAIN_ID of the run (default: from the process id), discovery on '
                    'localhost only, so that other graphs on this machine do not mix in')
    args = ap.parse_args()
    os.environ['ROS_DOMAIN_ID'] = str(args.domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    pulls_per_set = max(1, math.ceil(args.seconds / PULL_S / len(SETS)))
    pulls = pulls_per_set * len(SETS)
    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    bag = out / 'bag'
    graph = Graph(out / 'logs')
    c = Counters()
    rss_start = rss_end = rss_max = None
    t0 = time.monotonic()
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(bag)})
        if not c.wait_for_graph({'/force_corrected': 2, '/force': 3, PULL_EVENT_TOPIC: 2}, timeout=60):
            raise SystemExit('soak: the graph did not come up within 60 s')
        graph.start('force_tester_sim', 'sim_node', {
            'test_sets': '[' + ','.join(map(str, SETS)) + ']', 'pulls_per_set': pulls_per_set,
            'seed': args.seed, 'rate': float(args.rate), 'wait_for_subscribers': 2, **rig_params('truth')})
        print(f'soak: {pulls} pulls ({pulls * PULL_S / args.rate:.0f} s at rate {args.rate:g}); logs in '
              f'{graph.log_dir}', file=sys.stderr, flush=True)
        if not c.wait(1, 120, alive=lambda: not graph.dead()):
            raise SystemExit(f'soak: no pull scored within 120 s:\n{graph.tail((graph.dead() or ["sim_node"])[0])}')
        rss_start = rss_all(graph)
        rss_max = dict(rss_start)
        deadline = time.monotonic() + pulls * PULL_S / args.rate * 1.5 + 120
        last_note = time.monotonic()
        while len(c.scores) < pulls and time.monotonic() < deadline and not graph.dead():
            c.wait(len(c.scores) + 1, 5)
            now = rss_all(graph)
            rss_max = {k: max(v, now[k]) for k, v in rss_max.items()}
            if time.monotonic() - last_note > 60:
                last_note = time.monotonic()
                print(f'soak: {len(c.scores)}/{pulls} pulls scored, RSS {now} kB', file=sys.stderr, flush=True)
        # the recorder has caught up when it has written every message published
        deadline = time.monotonic() + 120
        caught_up = False
        while time.monotonic() < deadline and not caught_up:
            c.spin(0.5)
            caught_up = (c.value('sim', 'pulls') == pulls
                         and c.value('recorder', 'messages') >= sum(published_counts(c).values()))
        c.spin(1.5)  # one more heartbeat of every node, with the final counters
        rss_end = rss_all(graph)
    finally:
        codes = graph.stop()
        c.close()
    took = time.monotonic() - t0
    info = bag_info(bag)
    topics = info['topics']
    ok_pulls = sum(1 for s in c.scores if s['status'] == PULL_OK)
    published = published_counts(c)
    rows, equal = [], True
    for topic, n in published.items():
        got = topics.get(topic, {}).get('count', 0)
        equal &= got == n
        rows.append((topic, n, got, topics.get(topic, {}).get('seq_gaps', '-')))
    dropped_scores = sum(s['dropped_blocks'] for s in c.scores)
    gaps = sum(t.get('seq_gaps', 0) or 0 for t in topics.values())
    size = sum(p.stat().st_size for p in bag.glob('*.mcap'))
    rate_bps = size / info['duration_s'] if info['duration_s'] else 0.0
    per_msg = size / info['message_count'] if info['message_count'] else 0.0
    print(f'\nsoak: {len(c.scores)}/{pulls} pulls scored ({ok_pulls} OK) in {took:.0f} s; '
          f'recorder caught up: {caught_up}; exit codes {codes}')
    print(f"{'topic':<18} {'published':>10} {'in bag':>10} {'seq gaps':>9}")
    for topic, n, got, g in rows:
        print(f'{topic:<18} {n:>10} {got:>10} {g!s:>9}{"" if n == got else "   DIFFERENT"}')
    print(f"\n{'node RSS, MB':<18} {'start':>8} {'end':>8} {'change':>8} {'max':>8}")
    for name in rss_start:
        a, b, m = rss_start[name] / 1024, rss_end[name] / 1024, rss_max[name] / 1024
        note = '  (its pulls done)' if name == 'sim worker' else ''
        print(f'{name:<18} {a:>8.1f} {b:>8.1f} {b - a:>+8.1f} {m:>8.1f}{note}')
    print(f'\ndropped blocks: {dropped_scores} (validator), {gaps} (seq gaps in the bag)')
    chunk_ms = CHUNK_BYTES / rate_bps * 1e3 if rate_bps else float('nan')
    print(f'bag: {size / 1e6:.0f} MB, {info["message_count"]} messages over {info["duration_s"]:.0f} s: '
          f'{rate_bps / 1e6:.2f} MB/s, {per_msg:.0f} bytes per message; a SIGKILL loses at most one '
          f'chunk: {CHUNK_BYTES // 1024} KiB = {CHUNK_BYTES / per_msg:.0f} messages = '
          f'{min(chunk_ms, FLUSH_S * 1e3):.0f} ms at this rate')
    result = {'seconds': args.seconds, 'pulls': pulls, 'scored': len(c.scores), 'ok': ok_pulls,
              'published': published, 'in_bag': {t: topics.get(t, {}).get('count', 0) for t in published},
              'rss_start_kb': rss_start, 'rss_end_kb': rss_end, 'rss_max_kb': rss_max,
              'dropped_blocks_validator': dropped_scores,
              'seq_gaps': gaps, 'bag_bytes': size, 'bag_messages': info['message_count'],
              'bytes_per_s': rate_bps, 'bytes_per_message': per_msg, 'wall_s': took}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0 if equal and not dropped_scores and not gaps and len(c.scores) == pulls else 1


if __name__ == '__main__':
    sys.exit(main())
