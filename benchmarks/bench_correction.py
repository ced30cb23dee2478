"""Benchmark: does the correction node keep up with 50 kHz live? (./ft bench correction [--seconds S])

Starts the correction node as its own process, publishes /force and /accel in 1 ms blocks
(50 samples) paced in real time from this process for S seconds (default 60), receives
/force_corrected here, and prints:
  - blocks sent / received / dropped (sequence gaps or missing blocks),
  - latency from block stamp (its first sample) to receipt of the corrected block, p50/p99/max,
    and the added latency after the block is complete (stamp + 1 ms),
  - the node's CPU share (from /proc), and
  - the same arithmetic by the core on one numpy array, as a ratio to the node's CPU time.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from force_tester_common.core.blocks import BLOCK_SAMPLES
from force_tester_common.core.clock import NS_PER_S
from ft_cli.graph import Graph, cpu_seconds

# the relay: bench_floor's, a node that publishes each /force block as /force_corrected, with no arithmetic
RELAY = [sys.executable, str(Path(__file__).with_name('bench_floor.py')), '--role', 'relay']


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench correction', description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=60.0, help='live run length (default 60)')
    ap.add_argument('--block', type=int, default=BLOCK_SAMPLES,
                    help=f'samples per block (default {BLOCK_SAMPLES}, the workspace default)')
    ap.add_argument('--relay', action='store_true',
                    help='run a relay node instead of the correction: it takes /force and /accel and publishes '
                         'each force block as /force_corrected, no arithmetic (the floor of rclpy and DDS)')
    args = ap.parse_args()

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from force_correction.core.params import CorrectionParams
    from force_correction.core.streaming import correct_signal
    from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, fill_block, stamp_to_ns
    from force_tester_common.ros import BLOCK_QOS
    from force_tester_sim.core.params import load_rig
    from force_tester_sim.core.pull import make_pull_specs
    from force_tester_sim.core.simulate import simulate_pull

    rig = load_rig()
    pull = simulate_pull(rig, make_pull_specs(rig, 3, 1, seed=0)[0])
    rate = rig.daq.sample_rate_hz
    n_blocks = int(args.seconds * rate) // args.block
    reps = -(-n_blocks * args.block // len(pull['time_s']))
    force = np.tile(pull['force_moving_n'], reps)[: n_blocks * args.block]
    accel = np.tile(pull['accel_axial_m_s2'], reps)[: n_blocks * args.block]

    out = Path('runs/bench_correction')
    graph = Graph(out / 'logs')
    rclpy.init()
    node = rclpy.create_node('bench_correction')
    topics = {t.topic: t for t in BLOCK_TOPICS}
    pub_f = node.create_publisher(topics['/force'].msg_type, '/force', BLOCK_QOS)
    pub_a = node.create_publisher(topics['/accel'].msg_type, '/accel', BLOCK_QOS)
    received = {}  # seq -> (stamp_ns, receive_ns)

    def on_corrected(msg):
        received[msg.seq] = (stamp_to_ns(msg.header.stamp), time.time_ns())

    node.create_subscription(CORRECTED_TOPIC.msg_type, CORRECTED_TOPIC.topic, on_corrected, BLOCK_QOS)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    if args.relay:
        proc = subprocess.Popen(RELAY, stdout=open(out / 'logs' / 'relay.log', 'a'),
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        graph.procs['relay'] = proc
    else:
        proc = graph.start('force_correction', 'correction_node')
    try:
        deadline = time.monotonic() + 30
        while (pub_f.get_subscription_count() < 1 or pub_a.get_subscription_count() < 1
               or node.count_publishers('/force_corrected') < 1) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.5)
        cpu0 = cpu_seconds(proc.pid)
        period_ns = int(args.block * NS_PER_S / rate)
        done = threading.Event()

        def publish():
            t0 = time.time_ns()
            for k in range(n_blocks):
                stamp = t0 + k * period_ns
                wait = (stamp + period_ns - time.time_ns()) / NS_PER_S  # block complete -> publish
                if wait > 0:
                    time.sleep(wait)
                s = slice(k * args.block, (k + 1) * args.block)
                tf = topics['/force'].msg_type()
                pub_f.publish(fill_block(tf, stamp, rate, k, {'moving_n': force[s], 'stationary_n': force[s]}))
                ta = topics['/accel'].msg_type()
                pub_a.publish(fill_block(ta, stamp, rate, k, {'axial_m_s2': accel[s]}))
                if k % 5000 == 0:
                    print(f'  {k * args.block / rate:5.1f} s of {args.seconds:.0f} s published', file=sys.stderr)
            done.set()

        sender = threading.Thread(target=publish, daemon=True)
        wall0 = time.monotonic()
        sender.start()
        while not done.is_set() or (len(received) < n_blocks and time.monotonic() - wall0 < args.seconds + 10):
            executor.spin_once(timeout_sec=0.05)
            if done.is_set() and len(received) >= n_blocks:
                break
        wall = time.monotonic() - wall0
        cpu = cpu_seconds(proc.pid) - cpu0
    finally:
        graph.stop()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()

    seqs = sorted(received)
    dropped = n_blocks - len(received)
    lat = np.array([r - s for s, r in received.values()]) / 1e6
    added = lat - period_ns / 1e6
    t = time.perf_counter()
    for _ in range(5):
        correct_signal(force, accel, CorrectionParams())
    batch = (time.perf_counter() - t) / 5
    print(f'correction node, {args.seconds:.0f} s of 50 kHz in {args.block}-sample blocks '
          f'({n_blocks} force + {n_blocks} accel blocks):')
    print(f'  received {len(received)} corrected blocks, dropped {dropped}, '
          f'seq range {seqs[0] if seqs else "-"}..{seqs[-1] if seqs else "-"}')
    if len(lat):
        print(f'  latency stamp -> corrected received: p50 {np.percentile(lat, 50):.2f} ms, '
              f'p99 {np.percentile(lat, 99):.2f} ms, max {lat.max():.2f} ms')
        print(f'  added latency after the block is complete: p50 {np.percentile(added, 50):.2f} ms, '
              f'p99 {np.percentile(added, 99):.2f} ms')
    print(f'  node CPU: {cpu:.2f} s over {wall:.1f} s wall = {100 * cpu / wall:.1f} % of one core')
    print(f'  core on one numpy array of the same {len(force)} samples: {1e3 * batch:.1f} ms; '
          f'node CPU / batch = {cpu / batch:.0f}x')
    return 0 if dropped == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
