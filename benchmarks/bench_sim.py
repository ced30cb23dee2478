"""Benchmark: simulator speed (python benchmarks/bench_sim.py). Prints figures, asserts nothing.

- one 2 s pull at 50 kHz (nominal rig, set 3), prescribed motion (run_pull) and drive-coupled
  (run_coupled_pull, exact drive integrator; and once with the LSODA reference drive, method='lsoda'):
  wall time and real-time factor (record length / wall), target >= 10x;
- the 100-pull reference campaign: generate_campaign(load_rig(truth_reference.yaml), pulls=20,
  seed=2013, mapper=map_pulls): wall time on the embedded Dask cluster, target < 60 s.

The simulator's long-array arithmetic is written column by column (no tall-thin matrix products), so
the figures do not depend on the BLAS thread setting.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from force_tester_common.engine import map_pulls
from force_tester_sim.core import load_rig, nominal_pull_spec, run_pull
from force_tester_sim.core.campaign import generate_campaign
from force_tester_sim.core.coupled import run_coupled_pull

ROOT = Path(__file__).resolve().parents[1]

TRUTH = ROOT / 'src' / 'force_tester_sim' / 'force_tester_sim' / 'config' / 'truth_reference.yaml'
RT_TARGET = 10.0
CAMPAIGN_TARGET_S = 60.0


def best_of(fn, n=3):
    best, out = float('inf'), None
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main() -> int:
    argparse.ArgumentParser(prog='./ft bench sim', description=__doc__.split('\n\n')[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter,
                            epilog=__doc__.split('\n\n', 1)[1]).parse_args()
    rig = load_rig()
    spec = nominal_pull_spec(rig, 3, seed=1)
    rec = rig.daq.record_length_s
    print(f'one pull: nominal rig, set 3, {rec:g} s at {rig.daq.sample_rate_hz:g} Hz (best of 3; '
          f'OPENBLAS_NUM_THREADS={os.environ.get("OPENBLAS_NUM_THREADS")})')
    for name, fn, n in (('prescribed', lambda: run_pull(rig, spec), 3),
                        ('coupled', lambda: run_coupled_pull(rig, spec), 3),
                        ('coupled, LSODA drive (reference, best of 1)',
                         lambda: run_coupled_pull(rig, spec, method='lsoda'), 1)):
        wall, res = best_of(fn, n)
        extra = f', {res.iterations} passes' if hasattr(res, 'iterations') else ''
        rt = rec / wall
        print(f'  {name:10s} wall {wall:7.3f} s   real-time factor {rt:6.1f}x   '
              f'vs target {RT_TARGET:g}x: {rt / RT_TARGET:5.2f}{extra}')
    truth = load_rig(TRUTH)
    t0 = time.perf_counter()
    out = generate_campaign(truth, pulls=20, seed=2013, mapper=map_pulls)
    wall = time.perf_counter() - t0
    print(f'campaign: truth_reference.yaml, {len(out)} pulls on the embedded Dask cluster (prescribed motion)')
    print(f'  wall {wall:7.2f} s   {wall / len(out):.3f} s/pull   vs target {CAMPAIGN_TARGET_S:g} s: '
          f'{wall / CAMPAIGN_TARGET_S:5.2f} of the budget')
    return 0


if __name__ == '__main__':
    sys.exit(main())
