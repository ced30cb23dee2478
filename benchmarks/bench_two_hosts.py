"""Benchmark: the live graph across two hosts, on a clean link and on a lossy, slow one (needs root).

    ./ft bench two_hosts [--loss 2] [--delay 5] [--sets 1] [--pulls 1] [--rate 1.0] [--json FILE]

Host A (a network namespace) runs the sim; host B runs correction, validator and recorder; a
veth pair joins them, and the link drops multicast, so discovery must use the configured unicast
peers. The clean run configures them with ROS_STATIC_PEERS, the lossy run with a Fast DDS XML
profile (--discovery picks one for both); both use UDPv4 only. Prints, per run, the messages the
sim published and those host B's recorder wrote per topic, the pulls scored, and what crossed the
link: bytes and packets each way, packets lost on the link and datagrams dropped by a receiver's
full UDP socket buffer, the user data host A sent once and again (the retransmission cost, read
from the RTPS messages in its outgoing frames by netlab/rtps_sniff.py), and the bytes A put on the
link per byte of payload (each reader in B gets its own copy). Exits 1 if a run did not deliver
everything.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from force_tester_common.core.scores import PULL_STATUS_NAMES
from ft_cli.paths import RUNS
from netlab.netns import Impairment, probe
from netlab.two_hosts import DISCOVERY, LINK_TOPICS, run_two_hosts

MB = 1e6


def report(run) -> str:
    a, b = run.counters['a'], run.counters['b']
    sa, sb = run.sniffed.get('a', {}), run.sniffed.get('b', {})
    statuses = [PULL_STATUS_NAMES.get(s['status'], str(s['status'])) for s in run.scores]
    lines = [f'{run.link}, discovery {run.discovery}; {run.seconds:.1f} s'
             + (f'\n  impairment: {run.method}' if run.method != 'none' else ''),
             f"  {'topic':12s} {'sent (A)':>9s} {'recorded (B)':>13s} {'seq gaps':>9s} {'readers in B':>13s} "
             f"{'payload MB':>11s}"]
    for t in LINK_TOPICS:
        lines.append(f"  {t:12s} {run.sent.get(t, '-'):>9} {run.received.get(t, '-'):>13} "
                     f"{run.seq_gaps.get(t, '-'):>9} {run.readers.get(t, '-'):>13} "
                     f"{run.cdr_bytes.get(t, 0) * int(run.readers.get(t, 0)) / MB:>11.3f}")
    control_mb = (sa.get('control_bytes', 0) + sb.get('control_bytes', 0)) / MB
    lines += [f"  pulls scored: {len(run.scores)} ({', '.join(statuses) or 'none'})",
              f"  A->B: {a['tx_bytes'] / MB:.3f} MB in {a['tx_packets']} packets; lost on the link {b['lost']}, "
              f"dropped by full UDP socket buffers in B {b['udp_rcvbuf_errors']}",
              f"  B->A: {b['tx_bytes'] / MB:.3f} MB in {b['tx_packets']} packets; lost on the link {a['lost']}, "
              f"dropped by full UDP socket buffers in A {a['udp_rcvbuf_errors']}",
              f"  A's user data: {sa.get('data_first', 0)} submessages ({sa.get('data_first_bytes', 0) / MB:.3f} MB) "
              f"sent once, {sa.get('data_again', 0)} ({sa.get('data_again_bytes', 0) / MB:.3f} MB) sent again "
              f"(+{run.retransmitted * 100:.2f} %); reliability control: {sa.get('control', 0)} A->B + "
              f"{sb.get('control', 0)} B->A submessages ({control_mb:.3f} MB)",
              f"  bytes A put on the link per payload byte: {run.wire_ratio:.4f} "
              f"(payload {run.payload_bytes / MB:.3f} MB); multicast blocked on the link: "
              f"{a['multicast_blocked']} + {b['multicast_blocked']} packets"
              + (f"; delay line overflowed: {a['delay_line_dropped'] + b['delay_line_dropped']}"
                 if a['delay_line_dropped'] + b['delay_line_dropped'] else '')
              + (f"; the packet counters missed {sa.get('missed_by_sniffer')} + {sb.get('missed_by_sniffer')} frames"
                 if sa.get('missed_by_sniffer') or sb.get('missed_by_sniffer') else '')]
    if run.problem:
        lines.append(f'  PROBLEM: {run.problem}')
    return '\n'.join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench two_hosts', description=__doc__.splitlines()[0])
    ap.add_argument('--loss', type=float, default=2.0, help='lossy run: packet loss in %% each way (default 2)')
    ap.add_argument('--delay', type=float, default=5.0, help='lossy run: one-way delay in ms (default 5)')
    ap.add_argument('--sets', nargs='+', type=int, default=[1], help='test sets (default 1)')
    ap.add_argument('--pulls', type=int, default=1, help='pulls per set (default 1)')
    ap.add_argument('--rate', type=float, default=1.0, help='sim pace, real-time factor (default 1.0)')
    ap.add_argument('--discovery', choices=DISCOVERY, default=None,
                    help='both runs with this discovery (default: clean static_peers, lossy xml)')
    ap.add_argument('--timeout', type=float, default=240.0, help='give up on a run after this many seconds')
    ap.add_argument('--out', default=str(RUNS / 'two_hosts'), help='logs and bags (default runs/two_hosts)')
    ap.add_argument('--json', help='also write the runs to this JSON file')
    args = ap.parse_args()
    support = probe()
    if not support.netns:
        print(f'bench two_hosts: cannot run: {support.reason}', file=sys.stderr)
        return 2
    print(f'this machine: network namespaces and veth yes; sch_netem {"yes" if support.netem else "no"}; '
          f'cls_bpf {"yes" if support.bpf else "no"}; tap delay line {"yes" if support.delay_line else "no"}')
    runs = []
    for name, imp, disc in (('clean', Impairment(), args.discovery or 'static_peers'),
                            ('lossy', Impairment(args.loss, args.delay), args.discovery or 'xml')):
        run = run_two_hosts(Path(args.out) / name, imp, disc, sets=args.sets, pulls=args.pulls, rate=args.rate,
                            timeout=args.timeout, say=lambda m: print(m, file=sys.stderr, flush=True))
        runs.append(run)
        print(f'{name}: {report(run)}', flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps([r.as_dict() for r in runs], indent=1))
    ok = all(r.complete and r.sent == r.received and not r.left for r in runs)
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
