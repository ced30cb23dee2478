"""The monitor's cost on the live 50 kHz graph: `./ft bench monitor [--pulls N] [--set S]`.

Runs the live graph (sim, correction, validator as processes) three times on the same pulls: without
the monitor; with monitor_node and one Foxglove client (tools/foxglove_client, decoding nothing it
does not print) on the topics the shipped layout reads, as the Foxglove app with that layout open;
and with the monitor and one client on every topic it serves (so /motor and /encoder too, which
the monitor subscribes to only while a client watches them). Prints

- the monitor process's CPU (user + system, from /proc) while data flows and over the run, as a
  share of one core;
- the correction path's latency in both runs: a /force_corrected block's arrival at this
  benchmark's own rclpy node minus its header stamp (the block's first sample), p50 and p99;
- how many blocks the monitor received of those published (it may lose, never delay).

Short by default (one 2 s pull of set 3): the machine is shared.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests' / 'force_tester_monitor'))   # the Foxglove client's helpers (fox_client)

from fox_client import LAYOUT, client_command, layout_topics, monitor_port

from force_tester_common.core.blocks import BLOCK_SAMPLES
from force_tester_common.core.clock import stamp_to_ns
from ft_cli.graph import Graph, ScoreCollector, cpu_seconds


def run(pulls: int, test_set: int, topics: list | None, logs: Path) -> dict:
    """topics: the Foxglove client's; None runs no monitor."""
    from force_tester_msgs.msg import CorrectedForceBlock, MonitorHealth, PullEvent

    from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
    graph = Graph(logs)
    collector = ScoreCollector()
    latency_ns, health = [], []

    def on_corrected(msg):
        latency_ns.append(time.time_ns() - stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec))
    collector.node.create_subscription(CorrectedForceBlock, '/force_corrected', on_corrected, BLOCK_QOS)
    collector.node.create_subscription(MonitorHealth, '/monitor/health', health.append, EVENT_QOS)
    client = None
    monitor = topics is not None
    out = {}
    flowing = {'cpu_s': 0.0, 'wall_s': 0.0, 'start': None}   # the monitor's CPU from each pull's START to its END

    def on_event(msg):
        now = (time.monotonic(), cpu_seconds(mon.pid))
        if msg.event == PullEvent.START:
            flowing['start'] = now
        elif flowing['start'] is not None:
            flowing['wall_s'] += now[0] - flowing['start'][0]
            flowing['cpu_s'] += now[1] - flowing['start'][1]
            flowing['start'] = None
    if monitor:
        collector.node.create_subscription(PullEvent, '/pull_event', on_event, EVENT_QOS)
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        subs = {'/force': 2, '/pull_event': 1}
        if monitor:
            mon = graph.start('force_tester_monitor', 'monitor_node', {'port': 0})
            port = monitor_port(logs / 'monitor_node.log', mon)
            client = subprocess.Popen(client_command(port, '--topics', ','.join(topics),
                                                     '--keep', ','.join(f'{t}=0' for t in topics),
                                                     '--timeout', '600'),
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            subs = {'/force': 3, '/pull_event': 3}
        assert collector.wait_for_graph(subs, timeout=60)
        time.sleep(1.0)
        cpu0, t0 = (cpu_seconds(mon.pid) if monitor else 0.0), time.monotonic()
        graph.start('force_tester_sim', 'sim_node', {'test_sets': f'[{test_set}]', 'pulls_per_set': pulls,
                                                     'wait_for_subscribers': subs['/pull_event'],
                                                     'exit_when_done': True})
        assert collector.wait(pulls, 60 + 10 * pulls, alive=lambda: not graph.dead()), graph.tail('sim_node')
        if monitor:  # until the monitor has worked through every corrected block (it may lag)
            def last():
                return {t.topic: t for t in health[-1].topics} if health else {}
            collector.spin_until(lambda: last().get('/force_corrected') is not None
                                 and last()['/force_corrected'].received >= len(latency_ns), 30, poll_s=0.1)
            out['cpu_s'] = cpu_seconds(mon.pid) - cpu0
            out['wall_s'] = time.monotonic() - t0
            out['flowing'] = flowing
            out['monitor_received'] = {k: t.received for k, t in last().items() if k in ('/force', '/force_corrected')}
    finally:
        if client is not None:
            client.kill()
            client.wait()
        graph.stop()
        collector.close()
    lat = np.array(latency_ns) / 1e6
    out.update(blocks=lat.size, p50_ms=float(np.percentile(lat, 50)), p99_ms=float(np.percentile(lat, 99)),
               dropped=sum(s['dropped_blocks'] for s in collector.scores))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--pulls', type=int, default=1)
    ap.add_argument('--set', type=int, default=3)
    args = ap.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    from force_tester_monitor.monitor_node import DERIVED, FORWARDED
    served = sorted({*FORWARDED, *DERIVED})
    clients = {'layout': layout_topics(json.loads(LAYOUT.read_text()), served), 'every topic': served}
    with tempfile.TemporaryDirectory() as tmp:
        runs = {'without monitor': run(args.pulls, args.set, None, Path(tmp) / 'without')}
        for name, topics in clients.items():
            runs[f'monitor + client on {name}'] = run(args.pulls, args.set, topics, Path(tmp) / name.replace(' ', '_'))
    print(f'{args.pulls} pull(s) of set {args.set}, 50 kHz, {BLOCK_SAMPLES}-sample blocks (the sim default)')
    for name, topics in clients.items():
        r = runs[f'monitor + client on {name}']
        f = r['flowing']
        print(f"monitor CPU, one Foxglove client on {name} ({', '.join(topics)}): "
              f"{100 * f['cpu_s'] / f['wall_s']:.1f} % of one core while data flows ({f['cpu_s']:.2f} CPU-s in "
              f"{f['wall_s']:.1f} s from each pull's START to its END; target < 15 %); "
              f"{100 * r['cpu_s'] / r['wall_s']:.1f} % over the {r['wall_s']:.1f} s run; it received (of "
              f"{r['blocks']} corrected blocks) {r['monitor_received']}")
    for name, r in runs.items():
        print(f"correction path latency {name}: p50 {r['p50_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms "
              f"over {r['blocks']} blocks, dropped {r['dropped']}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
