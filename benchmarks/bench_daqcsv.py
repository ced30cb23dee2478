"""Benchmark: reading and writing one campaign pull CSV, before and now (./ft bench daqcsv [--reps N]).

One pull of the truth rig (set 3, 2 s at 50 kHz: 100,000 samples, 10 columns, 20 MB of CSV), written and read
back alternately by the earlier code (Python repr for every value, joined in Python; numpy.loadtxt)
and the code now (bag_tools.core.daq.write_csv / read_csv: pyarrow formats and parses in C++). Checks that
both write the same bytes and read the same doubles, and prints the median per pull (wall and CPU time of
this process, one thread) and the ratio. Target: >= 3x on both. Asserts nothing about speed.
"""
from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _pkg in ('bag_tools', 'force_tester_common', 'force_tester_sim'):
    if str(ROOT / 'src' / _pkg) not in sys.path:
        sys.path.insert(0, str(ROOT / 'src' / _pkg))

from bag_tools.core.daq import read_csv, write_csv  # noqa: E402
from force_tester_sim.core.campaign import generate_campaign  # noqa: E402
from force_tester_sim.core.params import RigParams  # noqa: E402

TARGET = 3.0


def write_before(path, channels) -> None:
    """write_csv as it was (commit d39cbe8)."""
    names = list(channels)
    cols = [list(map(repr, np.asarray(channels[c], dtype=np.float64).tolist())) for c in names]
    with open(path, 'w', encoding='utf-8', newline='') as fh:
        fh.write(','.join(names) + '\n')
        fh.write('\n'.join(map(','.join, zip(*cols))))
        fh.write('\n')


def read_before(path) -> dict:
    """read_csv's well-formed path as it was: numpy.loadtxt over the body."""
    with open(path, encoding='utf-8', newline='') as fh:
        header = fh.readline()
        body = fh.read()
    names = [h.strip() for h in header.strip().split(',')]
    data = np.loadtxt(io.StringIO(body), delimiter=',', dtype=np.float64, ndmin=2)
    return {name: np.ascontiguousarray(data[:, i]) for i, name in enumerate(names)}


def timed(fn, *args):
    w, c = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--reps', type=int, default=5, help='alternating rounds (default 5)')
    args = ap.parse_args()
    (_meta, ch), = generate_campaign(RigParams(), sets=(3,), pulls=1, seed=2013)
    ch = {k: np.asarray(v, dtype=np.float64) for k, v in ch.items()}
    n = len(ch['time_s'])
    times = {k: ([], []) for k in ('write before', 'write now', 'read before', 'read now')}
    with tempfile.TemporaryDirectory() as tmp:
        old, new = os.path.join(tmp, 'old.csv'), os.path.join(tmp, 'new.csv')
        for _ in range(args.reps):
            for key, fn, path in (('write before', write_before, old), ('write now', write_csv, new)):
                _o, w, c = timed(fn, path, ch)
                times[key][0].append(w)
                times[key][1].append(c)
            a, w, c = timed(read_before, old)
            times['read before'][0].append(w)
            times['read before'][1].append(c)
            b, w, c = timed(read_csv, Path(old))
            times['read now'][0].append(w)
            times['read now'][1].append(c)
        same_bytes = Path(old).read_bytes() == Path(new).read_bytes()
        size = Path(old).stat().st_size
    same_values = all(a[k].tobytes() == b[k].tobytes() == ch[k].tobytes() for k in ch)
    print(f'one pull: {n} samples x {len(ch)} columns, {size / 1e6:.1f} MB of CSV; {args.reps} alternating rounds')
    print(f'same bytes written: {same_bytes}; same doubles read (and equal to the pull): {same_values}')
    print(f'{"per pull":<14} {"wall median":>12} {"cpu median":>11}')
    med = {k: (statistics.median(v[0]), statistics.median(v[1])) for k, v in times.items()}
    for k, (w, c) in med.items():
        print(f'{k:<14} {w:>10.3f} s {c:>9.3f} s')
    for what in ('write', 'read'):
        bw, bc = med[f'{what} before']
        nw, nc = med[f'{what} now']
        print(f'{what}: {bw / nw:.1f}x wall, {bc / nc:.1f}x cpu (target >= {TARGET:g}x)')
    return 0 if same_bytes and same_values else 1


if __name__ == '__main__':
    sys.exit(main())
