"""Benchmark: how many rigs one machine runs live (./ft bench rigs [--rigs N] [--seconds S] [--json FILE]).

Each rig is a sim, a correction and a validator under its own namespace (/rig1/force, ...), started
as separate processes over Fast DDS in a ROS domain of their own (or, with --layout composed, every
rig's correction and validator in one process and one executor). The sims pace 50 kHz in real time
in blocks of --block samples, back-to-back pulls of the five test sets, for S seconds of data (the
prescribed carriage motion unless --drive: a real rig's hardware makes the data). It prints:
  - per rig: blocks sent (the sim's count), corrected (the correction's), pulls scored and scored
    OK, and the blocks dropped (the larger of: sent but not corrected; missing from the scored pulls);
  - the CPU of every process (its children included) as a share of one core over the run;
  - for rig 1, the latency of /rig1/force_corrected after its block is complete (stamp + block
    length) and the latency the correction adds (arrival of the corrected block minus arrival of
    its /force block, both here), p50/p99;
  - the correction's CPU per rig, and its ratio to the same arithmetic done by the core on one
    numpy array (timed in the same run).

--max finds the largest N with zero dropped blocks, every pull scored and rig 1 keeping up (p99
latency after the block is complete under --live-ms, 100 ms): N = --rigs, doubled until a run
fails, then bisection. --block, --executor and --layout take comma-separated lists: every
combination runs, one after another, and a table puts them side by side. --json FILE writes
{"rigs", "dropped", "p99_added_ms", "correction_cpu_per_rig", ...} (for a list: every run's; for
--max: the largest clean run's figures, and every run's).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from force_tester_common.core.blocks import BLOCK_SAMPLES
from force_tester_common.core.channels import (
    DIAGNOSTICS_TOPIC,
    PULL_EVENT_TOPIC,
    PULL_SCORE_TOPIC,
)
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.health import status_node
from force_tester_common.core.scores import PULL_OK
from force_tester_common.ros import DEFAULT_EXECUTOR, EXECUTOR_ENV, EXECUTORS
from ft_cli.graph import Graph
from ft_cli.paths import RUNS

SETS = (1, 2, 3, 4, 5)
LAYOUTS = ('process', 'composed')
PULL_S = 2.0          # every test set's pull lasts 2 s of data (the sim's schedule)
START_TIMEOUT_S = 60.0


class NotStarted(Exception):
    """The rigs' sims did not all start publishing in time."""


def tree_cpu(proc) -> float:
    """CPU seconds (user + system) of a process and its live children."""
    import psutil
    total = 0.0
    try:
        p = psutil.Process(proc.pid)
        for q in [p, *p.children(recursive=True)]:
            try:
                t = q.cpu_times()
                total += t.user + t.system
            except psutil.NoSuchProcess:
                pass
    except psutil.NoSuchProcess:
        pass
    return total


class Probe:
    """This process's node: pull events and scores of every rig, diagnostics counters, and rig 1's
    /force and /force_corrected arrival times."""

    def __init__(self, rigs: int, domain: int):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from force_tester_msgs.msg import ForceBlock, PullEvent, PullScore

        from force_tester_common.conversions import CORRECTED_TOPIC, stamp_to_ns
        from force_tester_common.ros import BLOCK_QOS, EVENT_QOS, SCORE_QOS, make_executor
        self.context = rclpy.Context()
        rclpy.init(args=['bench_rigs'], context=self.context, domain_id=domain)
        self.node = rclpy.create_node('bench_rigs', context=self.context)
        self.scores = {k: [] for k in range(1, rigs + 1)}
        self.events = {k: [] for k in self.scores}
        self.counters = {}             # (node fqn) -> latest heartbeat key/values
        self.force_arrival = {}        # rig 1: stamp ns -> (arrival ns, samples, rate)
        self.corrected_arrival = {}    # rig 1: stamp ns -> arrival ns
        for k in self.scores:
            self.node.create_subscription(PullScore, f'/rig{k}{PULL_SCORE_TOPIC}',
                                          lambda m, k=k: self.scores[k].append(m), SCORE_QOS)
            self.node.create_subscription(PullEvent, f'/rig{k}{PULL_EVENT_TOPIC}',
                                          lambda m, k=k: self.events[k].append(m.event), EVENT_QOS)

        def on_force(m):
            self.force_arrival[stamp_to_ns(m.header.stamp)] = (time.time_ns(), len(m.moving_n), m.sample_rate_hz)

        def on_corrected(m):
            self.corrected_arrival[stamp_to_ns(m.header.stamp)] = time.time_ns()
        self.node.create_subscription(ForceBlock, '/rig1/force', on_force, BLOCK_QOS)
        self.node.create_subscription(CORRECTED_TOPIC.msg_type, f'/rig1{CORRECTED_TOPIC.topic}', on_corrected,
                                      BLOCK_QOS)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, EVENT_QOS)
        self.executor = make_executor(context=self.context)
        self.executor.add_node(self.node)

    def _on_diagnostics(self, msg):
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if values:
                self.counters[status_node(status.name, status.hardware_id)] = values

    def counter(self, fqn: str, key: str) -> int:
        return int(self.counters.get(fqn, {}).get(key, 0))

    def spin_until(self, done, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if done():
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return done()

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()


def write_params(path: Path, namespace: str, nodes: dict) -> Path:
    """A ROS parameter file for one rig: {node name: {parameter: value}} under ``namespace``."""
    import yaml
    path.write_text(yaml.safe_dump({f'{namespace}/{node}': {'ros__parameters': params}
                                    for node, params in nodes.items()}, sort_keys=False))
    return path


def batch_seconds(seconds: float) -> float:
    """The core's m*a + moving average on one numpy array of ``seconds`` of one rig's data (median of 3)."""
    from force_correction.core.params import CorrectionParams
    from force_correction.core.streaming import correct_signal
    rng = np.random.default_rng(0)
    n = int(seconds * 50_000)
    force, accel = rng.normal(size=n), rng.normal(size=n)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        correct_signal(force, accel, CorrectionParams())
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def run(rigs: int, seconds: float, block: int, executor: str, compose: bool, domain: int, drive: bool = False,
        log=print, peak_u: bool = True) -> dict:
    """Start ``rigs`` rigs, let them publish ``seconds`` of data, and measure (see the module doc)."""
    pulls_per_set = max(1, math.ceil(seconds / (PULL_S * len(SETS))))
    n_pulls = pulls_per_set * len(SETS)
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ[EXECUTOR_ENV] = executor
    graph = Graph(RUNS / 'bench_rigs' / f'logs_{rigs}')
    probe = Probe(rigs, domain)
    procs = {}
    try:
        sim_params = {'test_sets': list(SETS), 'pulls_per_set': pulls_per_set, 'block_size': block,
                      'wait_for_subscribers': 2, 'drive': drive}
        namespaces = [f'/rig{k}' for k in range(1, rigs + 1)]
        # the documented way (docs/nodes.md, "Several rigs on one machine"): a namespace and a parameter file per rig
        files = [write_params(graph.log_dir / f'rig{k}.yaml', ns, {'sim': dict(sim_params, seed=k),
                                                                   'validator': {'peak_uncertainty': peak_u}})
                 for k, ns in enumerate(namespaces, 1)]
        if compose:
            procs['correction_graph'] = graph.start(
                'force_correction', 'correction_graph', extra=[
                    *(a for ns in namespaces for a in ('--namespace', ns)),
                    '--ros-args', *(a for f in files for a in ('--params-file', str(f)))])
        for k, ns in enumerate(namespaces, 1):
            remap = ['--ros-args', '-r', f'__ns:={ns}', '--params-file', str(files[k - 1])]
            if not compose:
                procs[f'rig{k}/correction'] = graph.start('force_correction', 'correction_node', extra=remap,
                                                          key=f'rig{k}_correction')
                procs[f'rig{k}/validator'] = graph.start('force_correction', 'validator_node', extra=remap,
                                                         key=f'rig{k}_validator')
        # the sims last: they wait for their correction and validator, then start at once
        for k, ns in enumerate(namespaces, 1):
            procs[f'rig{k}/sim'] = graph.start('force_tester_sim', 'sim_node', extra=[
                '--ros-args', '-r', f'__ns:={ns}', '--params-file', str(files[k - 1])], key=f'rig{k}_sim')

        def started():
            return all(probe.events.values())
        if not probe.spin_until(lambda: started() or graph.dead(), START_TIMEOUT_S + 5 * rigs) or graph.dead():
            raise NotStarted(f'bench rigs: {rigs} rig(s) did not start within {START_TIMEOUT_S + 5 * rigs:.0f} s '
                             f'(dead: {graph.dead()}); logs in {graph.log_dir}')
        cpu0 = {name: tree_cpu(p) for name, p in procs.items()}
        wall0 = time.monotonic()
        log(f'  {rigs} rig(s) publishing {n_pulls} pulls each ({n_pulls * PULL_S:.0f} s of data)', file=sys.stderr)

        def scored():
            return all(len(s) >= n_pulls for s in probe.scores.values())
        last = [time.monotonic()]

        def done():
            if time.monotonic() - last[0] > 10:
                last[0] = time.monotonic()
                log(f'  {time.monotonic() - wall0:5.0f} s: scored {[len(s) for s in probe.scores.values()]} '
                    f'of {n_pulls}', file=sys.stderr)
            return scored() or bool(graph.dead())
        probe.spin_until(done, n_pulls * PULL_S * 3 + 60)
        wall = time.monotonic() - wall0
        cpu = {name: tree_cpu(p) - cpu0[name] for name, p in procs.items()}
        probe.spin_until(lambda: False, 1.5)   # the last heartbeats with the final counters
    finally:
        graph.stop()
        probe.close()

    per_rig = []
    for k, ns in enumerate(namespaces, 1):
        sent = probe.counter(f'{ns}/sim', 'blocks_per_topic')
        corrected = probe.counter(f'{ns}/correction', 'pairs')
        scores = probe.scores[k]
        missing = sum(int(s.dropped_blocks) for s in scores)
        per_rig.append({'rig': k, 'sent': sent, 'corrected': corrected, 'pulls': n_pulls,
                        'scored': len(scores), 'scored_ok': sum(s.status == PULL_OK for s in scores),
                        'dropped': max(sent - corrected, missing)})
    lat, added = [], []
    for stamp, (arrival, samples, rate) in probe.force_arrival.items():
        if stamp in probe.corrected_arrival:
            complete = stamp + samples * NS_PER_S / rate
            lat.append((probe.corrected_arrival[stamp] - complete) / 1e6)
            added.append((probe.corrected_arrival[stamp] - arrival) / 1e6)
    corr_names = ['correction_graph'] if compose else [f'rig{k}/correction' for k in range(1, rigs + 1)]
    corr_cpu = sum(cpu[n] for n in corr_names) / wall   # composed: the correction and the validator
    live_cpu = sum(c for n, c in cpu.items() if not n.endswith('/sim')) / wall   # all but the sims
    batch = batch_seconds(n_pulls * PULL_S)
    return {'rigs': rigs, 'drive': drive, 'dropped': sum(r['dropped'] for r in per_rig),
            'unscored': sum(r['pulls'] - r['scored'] for r in per_rig), 'block': block, 'executor': executor,
            'compose': compose, 'peak_u': peak_u, 'live_cpu_per_rig': live_cpu / rigs,
            'seconds_of_data': n_pulls * PULL_S, 'wall_s': wall,
            'p50_latency_ms': float(np.percentile(lat, 50)) if lat else None,
            'p99_latency_ms': float(np.percentile(lat, 99)) if lat else None,
            'p50_added_ms': float(np.percentile(added, 50)) if added else None,
            'p99_added_ms': float(np.percentile(added, 99)) if added else None,
            'correction_cpu_per_rig': corr_cpu / rigs,
            'correction_cpu_over_batch': corr_cpu * wall / rigs / batch,
            'batch_s': batch,
            'cpu': {n: c / wall for n, c in cpu.items()}, 'per_rig': per_rig}


def report(r: dict) -> None:
    print(f"{r['rigs']} rig(s), {r['seconds_of_data']:.0f} s of 50 kHz data each in {r['block']}-sample blocks, "
          f"executor {r['executor']}{', correction+validator composed in one process' if r['compose'] else ''}; "
          f"{r['wall_s']:.0f} s wall")
    print(f"{'rig':>4} {'sent':>7} {'corrected':>9} {'pulls':>5} {'scored':>6} {'OK':>4} {'dropped':>7}")
    for p in r['per_rig']:
        print(f"{p['rig']:>4} {p['sent']:>7} {p['corrected']:>9} {p['pulls']:>5} {p['scored']:>6} "
              f"{p['scored_ok']:>4} {p['dropped']:>7}")
    print('CPU, share of one core over the run:')
    for name, c in sorted(r['cpu'].items()):
        print(f'  {name:24s} {100 * c:5.1f} %')
    if r['p99_latency_ms'] is not None:
        print(f"rig 1 latency after the block is complete: p50 {r['p50_latency_ms']:.2f} ms, "
              f"p99 {r['p99_latency_ms']:.2f} ms; added by the correction (corrected minus /force arrival): "
              f"p50 {r['p50_added_ms']:.2f} ms, p99 {r['p99_added_ms']:.2f} ms")
    what = 'correction + validator (composed)' if r['compose'] else 'correction'
    print(f"{what} CPU per rig: {100 * r['correction_cpu_per_rig']:.1f} % of one core = "
          f"{r['correction_cpu_over_batch']:.0f}x the core on one numpy array ({1e3 * r['batch_s']:.0f} ms for "
          f"{r['seconds_of_data']:.0f} s of data)")
    print(f"dropped blocks, all rigs: {r['dropped']}; pulls not scored: {r['unscored']}")


def clean(r: dict, live_ms: float = math.inf) -> bool:
    """Every block corrected and every pull scored (and, for --max, rig 1 kept up: its p99 latency
    after the block is complete under live_ms; a graph that falls behind drops nothing until its
    queues overflow, BLOCK_QOS's 10,000 blocks, 100 s of 10 ms blocks)."""
    return (r.get('started', True) and r['dropped'] == 0 and r['unscored'] == 0
            and (r['p99_latency_ms'] or math.inf) < live_ms)


def summary(results: list) -> None:
    """One line per run: the trade-offs side by side."""
    print('side by side (one run each, in this order):')
    print(f"{'rigs':>4} {'block':>5} {'executor':>8} {'layout':>8} {'peak U':>6} {'dropped':>7} {'corr CPU/rig':>12} "
          f"{'live CPU/rig':>12} {'x batch':>7} {'p50 after':>9} {'p99 after':>9} {'p50 added':>9} {'p99 added':>9}"
          "  (ms)")
    for r in results:
        if not r.get('started', True):
            print(f"{r['rigs']:>4} {r['block']:>5} {r['executor']:>8} {'composed' if r['compose'] else 'process':>8} "
                  'did not start')
            continue

        def ms(key, r=r):
            return f'{r[key]:9.2f}' if r[key] is not None else f"{'-':>9}"
        print(f"{r['rigs']:>4} {r['block']:>5} {r['executor']:>8} {'composed' if r['compose'] else 'process':>8} "
              f"{'on' if r['peak_u'] else 'off':>6} {r['dropped'] + r['unscored']:>7} "
              f"{100 * r['correction_cpu_per_rig']:11.1f}% {100 * r['live_cpu_per_rig']:11.1f}% "
              f"{r['correction_cpu_over_batch']:7.0f} {ms('p50_latency_ms')} {ms('p99_latency_ms')} "
              f"{ms('p50_added_ms')} {ms('p99_added_ms')}")


def listed(kind, choices=None):
    def parse(text):
        items = [kind(x) for x in text.split(',') if x]
        if not items or (choices and any(x not in choices for x in items)):
            raise argparse.ArgumentTypeError(f'{text!r}: expected a comma-separated list'
                                             + (f" of {', '.join(choices)}" if choices else ''))
        return items
    return parse


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench rigs', description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog='\n'.join(__doc__.splitlines()[2:]))
    ap.add_argument('--rigs', type=int, default=1, help='rigs to run (default 1)')
    ap.add_argument('--seconds', type=float, default=60.0, help='seconds of data per rig (default 60)')
    ap.add_argument('--block', type=listed(int), default=[BLOCK_SAMPLES], metavar='N[,N...]',
                    help=f'samples per block (default {BLOCK_SAMPLES}, the workspace default); a list runs each')
    ap.add_argument('--executor', type=listed(str, EXECUTORS), metavar='E[,E...]',
                    default=[os.environ.get(EXECUTOR_ENV, DEFAULT_EXECUTOR)],
                    help=f"the nodes' executor: {', '.join(EXECUTORS)} (default ${EXECUTOR_ENV} or "
                         f"{DEFAULT_EXECUTOR}); a list runs each")
    ap.add_argument('--layout', type=listed(str, LAYOUTS), default=['process'], metavar='L[,L...]',
                    help="process: one process per node (default); composed: every rig's correction and "
                         "validator in one process, one executor; a list runs each")
    ap.add_argument('--peak-u', type=listed(str, ('on', 'off')), default=['on'], metavar='on,off',
                    help="the validator's expanded uncertainty of each corrected peak (default on); "
                         "'on,off' runs both, side by side")
    ap.add_argument('--drive', action='store_true',
                    help="the sims simulate the carriage's motor drive too (0.25 s of CPU per 2 s pull; "
                         "default: the prescribed motion, since a real rig's hardware makes the data)")
    ap.add_argument('--max', action='store_true',
                    help='find the largest number of rigs with zero drops, doubling from --rigs, then bisecting '
                         '(first --block, --executor, --layout)')
    ap.add_argument('--live-ms', type=float, default=100.0,
                    help='--max: a run keeps up when rig 1\'s p99 latency after the block is complete is under '
                         'this (default 100 ms), besides dropping nothing')
    ap.add_argument('--json', type=Path, metavar='FILE', help='write the figures as JSON')
    ap.add_argument('--domain', type=int, default=60, help='first ROS domain id to use (default 60)')
    args = ap.parse_args()
    if args.rigs < 1 or args.seconds <= 0 or min(args.block) < 1:
        ap.error('--rigs, --seconds and --block must be positive')

    domain = [args.domain]
    results = []

    def trial(n, block, executor, layout, peak_u='on'):
        try:
            r = run(n, args.seconds, block, executor, layout == 'composed', domain[0], args.drive,
                    peak_u=peak_u == 'on')
        except NotStarted as exc:   # too many rigs to even start: a failed run, not the end of --max
            print(exc)
            r = {'rigs': n, 'block': block, 'executor': executor, 'compose': layout == 'composed',
                 'dropped': None, 'unscored': None, 'started': False, 'peak_u': peak_u == 'on'}
            results.append(r)
            return r
        finally:
            domain[0] += 1
        report(r)
        print(flush=True)
        results.append(r)
        return r
    if not args.max:
        for block in args.block:
            for executor in args.executor:
                for layout in args.layout:
                    for peak_u in args.peak_u:
                        trial(args.rigs, block, executor, layout, peak_u)
        if len(results) > 1:
            summary(results)
        out = results[0] if len(results) == 1 else {'runs': results}
        ok = all(clean(r) for r in results)
    else:
        setup = (args.block[0], args.executor[0], args.layout[0])
        good, bad, n = 0, None, args.rigs
        while bad is None:
            if clean(trial(n, *setup), args.live_ms):
                good, n = n, n * 2
            else:
                bad = n
        while bad - good > 1:
            n = (good + bad) // 2
            good, bad = (n, bad) if clean(trial(n, *setup), args.live_ms) else (good, n)
        summary(results)
        print(f'largest number of rigs with zero dropped blocks, every pull scored and rig 1 within '
              f'{args.live_ms:g} ms at p99: {good}')
        best = next((r for r in results if r['rigs'] == good), None)
        out = dict(best or {'rigs': 0, 'dropped': None}, max_rigs=good, runs=results)
        ok = good > 0
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + '\n')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
