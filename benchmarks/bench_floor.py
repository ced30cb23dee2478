"""Benchmark: the message floor of a rig, with no physics and no arithmetic (./ft bench floor).

`./ft bench floor [--rigs 1,4,8,10] [--seconds S] [--block N] [--json FILE]`

A null rig has the messages of a real rig and nothing else, three processes under /rigK:
  - a null sim publishes /force, /accel, /encoder and /motor blocks of --block samples at 50 kHz
    (the arrays filled once; no simulation);
  - a relay takes /force and /accel and publishes /force_corrected (the correction's messages, no
    arithmetic);
  - a null validator subscribes to /force_corrected and /force and counts them.
That is 9 message operations per block (5 publishes, 4 receipts), as in a sim, correction and
validator. Every process spins rclpy's EventsExecutor, as the workspace's nodes do.

It prints, for each N: the CPU of the null rigs (all processes, as a share of one core) per rig and
in total, the CPU per message operation, the blocks lost (published by the null sims but not
received by the null validators, from the first one each received), and how far the slowest null
sim fell behind its 50 kHz clock (blocks due but not sent when it was stopped). A run is live if
nothing is lost and no sim is behind by more than a block or two. If N null rigs already need the
machine's cores, N real rigs cannot run on it with rclpy, whatever the workspace's own code costs;
if they fit, the rest of the machine is what the workspace's own work per rig may cost.
"""
from __future__ import annotations

import argparse
import atexit
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from force_tester_common.core.blocks import BLOCK_SAMPLES
from force_tester_common.core.clock import NS_PER_S
from ft_cli.graph import cpu_seconds

RATE_HZ = 50_000.0
OPS_PER_BLOCK = 9     # null sim: 4 publishes; relay: 2 receipts + 1 publish; null validator: 2 receipts
WARMUP_S = 2.0
START_TIMEOUT_S = 120.0
DRAIN_S = 0.5
ROLES = ('sim', 'relay', 'sink')
STARTED = []   # every null-rig process; those still running when the benchmark ends (a failed run) are killed
atexit.register(lambda: [p.kill() for p in STARTED if p.poll() is None])


# ------------------------------------------------------------------ the three roles (child processes)
def role_main(role: str, block: int, started: Path) -> None:
    import array

    import rclpy

    from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, ns_to_stamp
    from force_tester_common.ros import BLOCK_QOS, in_namespace, make_executor, release, spin
    rclpy.init()
    node = rclpy.create_node(f'null_{role}')
    topics = {t.topic: t for t in BLOCK_TOPICS}
    counts = {}
    if role == 'sim':
        zeros = array.array('d', bytes(8 * block))
        msgs = []
        for topic in topics.values():
            msg = topic.msg_type(sample_rate_hz=RATE_HZ)
            for field in topic.fields:
                setattr(msg, field, zeros)
            msgs.append((node.create_publisher(topic.msg_type, in_namespace(topic.topic), BLOCK_QOS), msg))
        period_ns = int(block / RATE_HZ * NS_PER_S)
        t0 = []
        counts['sent'] = 0
        force_pub = msgs[list(topics).index('/force')][0]

        def tick():
            if not t0:  # start once the relay and the null validator both hear /force
                if force_pub.get_subscription_count() < 2:
                    return
                t0.append(time.monotonic_ns())
                (started / str(os.getpid())).touch()
            due = (time.monotonic_ns() - t0[0]) // period_ns + 1
            while counts['sent'] < due:
                stamp = ns_to_stamp(time.time_ns())
                for pub, msg in msgs:
                    msg.header.stamp = stamp
                    msg.seq = counts['sent']
                    pub.publish(msg)
                counts['sent'] += 1
        node.create_timer(period_ns / NS_PER_S, tick)
    elif role == 'relay':
        pub = node.create_publisher(CORRECTED_TOPIC.msg_type, in_namespace(CORRECTED_TOPIC.topic), BLOCK_QOS)
        counts.update(force=0, accel=0)

        def on_force(m):
            counts['force'] += 1
            out = CORRECTED_TOPIC.msg_type(header=m.header, sample_rate_hz=m.sample_rate_hz, seq=m.seq)
            out.raw_n = out.inertial_n = out.corrected_n = out.filtered_n = m.moving_n
            pub.publish(out)

        def on_accel(_m):
            counts['accel'] += 1
        node.create_subscription(topics['/force'].msg_type, in_namespace('/force'), on_force, BLOCK_QOS)
        node.create_subscription(topics['/accel'].msg_type, in_namespace('/accel'), on_accel, BLOCK_QOS)
    else:
        counts.update(force=0, corrected=0, first=-1)

        def on_corrected(m):
            if counts['first'] < 0:
                counts['first'] = m.seq
            counts['corrected'] += 1

        def on_force(_m):
            counts['force'] += 1
        node.create_subscription(topics['/force'].msg_type, in_namespace('/force'), on_force, BLOCK_QOS)
        node.create_subscription(CORRECTED_TOPIC.msg_type, in_namespace(CORRECTED_TOPIC.topic), on_corrected,
                                 BLOCK_QOS)
    ex = make_executor()
    ex.add_node(node)
    try:
        spin(ex)
    except Exception:  # noqa: BLE001, S110 - shutting down
        pass
    if role == 'sim':  # blocks due by the 50 kHz clock but not sent: the sim fell behind real time
        counts['behind'] = int((time.monotonic_ns() - t0[0]) // period_ns + 1 - counts['sent']) if t0 else -1
    print(json.dumps(counts), flush=True)
    release(ex, [node])


# ------------------------------------------------------------------ the benchmark
def run(rigs: int, seconds: float, block: int, started: Path) -> dict:
    procs = {}
    for marker in started.iterdir():
        marker.unlink()
    for k in range(1, rigs + 1):
        for role in reversed(ROLES):  # receivers first
            procs[(k, role)] = subprocess.Popen(
                [sys.executable, __file__, '--role', role, '--block', str(block), '--started', str(started),
                 '--ros-args', '-r', f'__ns:=/rig{k}'], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            STARTED.append(procs[(k, role)])
    deadline = time.monotonic() + START_TIMEOUT_S
    while len(list(started.iterdir())) < rigs:  # every null sim has found its two readers
        if time.monotonic() > deadline:
            for p in procs.values():
                p.kill()
            raise SystemExit(f'bench floor: {rigs} null rigs did not all start within {START_TIMEOUT_S:g} s')
        time.sleep(0.1)
    time.sleep(WARMUP_S)  # start-up, left out of the CPU window
    cpu0, t0 = {key: cpu_seconds(p.pid) for key, p in procs.items()}, time.monotonic()
    time.sleep(seconds)
    cpu = {key: cpu_seconds(p.pid) - cpu0[key] for key, p in procs.items()}
    wall = time.monotonic() - t0
    counts = {}
    for stage in ROLES:  # stop the sims first, then what they feed, each after the one before has ended
        time.sleep(DRAIN_S)  # what is in flight arrives
        for (_k, role), p in procs.items():
            if role == stage:
                p.send_signal(signal.SIGINT)
        for (k, role), p in procs.items():
            if role == stage:
                out, _ = p.communicate(timeout=60)
                counts[(k, role)] = json.loads(out.strip().splitlines()[-1])
    sent = sum(counts[(k, 'sim')]['sent'] for k in range(1, rigs + 1))
    behind = max(counts[(k, 'sim')]['behind'] for k in range(1, rigs + 1))
    got = sum(counts[(k, 'sink')]['corrected'] for k in range(1, rigs + 1))
    # lost: from the first block a null validator received on (the ones before it went out while
    # the relay's publisher and the validator were still discovering each other)
    lost = sum(counts[(k, 'sim')]['sent'] - max(counts[(k, 'sink')]['first'], 0) - counts[(k, 'sink')]['corrected']
               for k in range(1, rigs + 1))
    total = sum(cpu.values()) / wall
    ops_per_s = rigs * OPS_PER_BLOCK * RATE_HZ / block
    return {'rigs': rigs, 'block': block, 'seconds': wall, 'cpu_total': total, 'cpu_per_rig': total / rigs,
            'cpu_by_role': {r: sum(v for (k, role), v in cpu.items() if role == r) / wall / rigs for r in ROLES},
            'us_per_op': 1e6 * total / ops_per_s, 'sent': sent, 'received': got, 'lost': lost,
            'behind': behind}


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench floor', description=__doc__.splitlines()[0])
    ap.add_argument('--rigs', default='1,4,8,10', help='comma-separated numbers of null rigs (default 1,4,8,10)')
    ap.add_argument('--seconds', type=float, default=20.0, help='measured span per run (default 20)')
    ap.add_argument('--block', type=int, default=BLOCK_SAMPLES, help=f'samples per block (default {BLOCK_SAMPLES})')
    ap.add_argument('--json', type=Path, help='write every run as JSON to this file')
    ap.add_argument('--role', choices=ROLES, help=argparse.SUPPRESS)
    ap.add_argument('--started', type=Path, help=argparse.SUPPRESS)
    args, _ros = ap.parse_known_args()
    if args.role:
        role_main(args.role, args.block, args.started)
        return 0
    try:
        counts = [int(n) for n in args.rigs.split(',')]
    except ValueError:
        print(f'bench floor: error: --rigs {args.rigs!r} is invalid; expected comma-separated integers',
              file=sys.stderr)
        return 2
    os.environ.setdefault('ROS_DOMAIN_ID', str(1 + os.getpid() % 100))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    cores = os.cpu_count()
    print(f'null rigs: {block_text(args.block)}, {OPS_PER_BLOCK} message operations per block, '
          f'{args.seconds:g} s each, {cores} cores')
    print(f"{'rigs':>4} {'CPU total':>10} {'per rig':>8} {'sim':>6} {'relay':>6} {'sink':>6} {'us/op':>6} "
          f"{'sent':>7} {'lost':>6} {'behind':>7}")
    results = []
    with tempfile.TemporaryDirectory() as started:
        for n in counts:
            r = run(n, args.seconds, args.block, Path(started))
            results.append(r)
            by = r['cpu_by_role']
            print(f"{n:>4} {100 * r['cpu_total']:9.1f}% {100 * r['cpu_per_rig']:7.1f}% {100 * by['sim']:5.1f}% "
                  f"{100 * by['relay']:5.1f}% {100 * by['sink']:5.1f}% {r['us_per_op']:6.0f} {r['sent']:>7} "
                  f"{r['lost']:>6} {r['behind']:>7}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


def block_text(block: int) -> str:
    return f'{block}-sample blocks ({1000 * block / RATE_HZ:g} ms)'


if __name__ == '__main__':
    sys.exit(main())
