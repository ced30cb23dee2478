"""Benchmark: offline bag tools on sim data (./ft bench bag [--pulls N] [--correct-pulls K]).

1. `correct` on a bag of K pulls (2 s at 50 kHz each, 1 ms blocks) vs. the same arithmetic on
   in-memory arrays (correct_signal per run, score_pull per pull, SetStatistics), the two run
   alternately --reps times in one process: median and best of each, times faster than real
   time, and the ratios bag / in memory. Also the first call in the process (one-time set-up
   of the message types) and `./ft bag correct` end to end in a new process (imports too).
   Targets: >= 100x real time, within 3x of in memory.
2. import (campaign folder -> bag) and export (bag -> campaign folder) of an N-pull campaign.
   Target: < 60 s each for 100 pulls.

The pulls come from the sim core (force_tester_sim.core.pull.simulate_pull, with noise): one
pull per test set is simulated and repeated to N pulls (generation is not timed).
"""
from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bag_tools.core.convert import bag_to_campaign, campaign_to_bag
from bag_tools.core.daq import read_campaign, write_campaign
from force_correction.core import CorrectionParams, SetStatistics, correct_signal, score_pull
from force_correction.offline import correct
from force_tester_common.core.clock import NS_PER_S
from force_tester_sim.core.params import load_rig
from force_tester_sim.core.pull import make_pull_specs
from force_tester_sim.core.simulate import simulate_pull

ROOT = Path(__file__).resolve().parents[1]


def sim_pulls(n: int, contiguous: bool = True) -> list:
    rig = load_rig(None)
    base = []
    for s in (1, 2, 3, 4, 5):
        spec = make_pull_specs(rig, s, 1, seed=s)[0]
        ts = rig.test_set(s)
        base.append(({'set': s, 'coupon_lbf': ts.coupon_lbf, 'velocity_fps': ts.velocity_fps,
                      'decel_g': ts.decel_g}, simulate_pull(rig, spec)))
    out = []
    start = 1_700_000_000 * NS_PER_S
    for i in range(n):
        m, ch = base[i % len(base)]
        m = dict(m, pull_id=i + 1)
        if contiguous:  # back to back, like the sim node publishes
            m['start_ns'] = start
            start += len(ch['time_s']) * NS_PER_S // 50000
        out.append((m, ch))
    return out


def in_memory(pulls: list, params: CorrectionParams) -> dict:
    """The arithmetic of `correct` on arrays: one run over contiguous pulls, then scores."""
    f = np.concatenate([c['force_moving_n'] for _, c in pulls])
    a = np.concatenate([c['accel_axial_m_s2'] for _, c in pulls])
    out = correct_signal(f, a, params)
    stats = SetStatistics()
    pos = 0
    for m, c in pulls:
        n = len(c['time_s'])
        sl = slice(pos, pos + n)
        pos += n
        stats.add(m['set'], score_pull(c['force_stationary_n'], out.raw_n[sl],
                                       out.corrected_n[sl], out.filtered_n[sl]))
    return {s: stats.summary(s) for s in stats.sets()}


def timed(fn, *args, **kw):
    t0 = time.perf_counter()
    res = fn(*args, **kw)
    return time.perf_counter() - t0, res


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench bag', description=__doc__.splitlines()[0])
    ap.add_argument('--pulls', type=int, default=100, help='campaign size for import/export')
    ap.add_argument('--correct-pulls', type=int, default=10, help='pulls in the corrected bag')
    ap.add_argument('--reps', type=int, default=9, help='alternating repetitions of correct')
    ap.add_argument('--keep', action='store_true', help='keep the temporary folder')
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix='bench_bag-'))
    try:
        params = CorrectionParams()
        k = args.correct_pulls
        pulls = sim_pulls(max(args.pulls, k))
        real_s = sum(len(c['time_s']) for _, c in pulls[:k]) / 50000.0
        write_campaign(tmp / 'small', pulls[:k])
        campaign_to_bag(tmp / 'small', tmp / 'small_bag')
        os.sync()  # the set-up's dirty pages would otherwise be written back during the timing
        t_first, res = timed(correct, tmp / 'small_bag', tmp / 'first')
        t_bags, t_mems = [], []
        for r in range(args.reps):  # alternately, so both see the same machine state
            t_bags.append(timed(correct, tmp / 'small_bag', tmp / f'rep{r}')[0])
            t_mems.append(timed(in_memory, pulls[:k], params)[0])
            shutil.rmtree(tmp / f'rep{r}')
        t_bag, t_mem = statistics.median(t_bags), statistics.median(t_mems)
        cli = [sys.executable, '-c', 'import sys; from force_correction.offline.cli import main; '
               'sys.exit(main(sys.argv[1:]))', 'correct', str(tmp / 'small_bag'),
               str(tmp / 'cli_out')]
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(
            [str(ROOT / 'src' / p) for p in ('bag_tools', 'force_tester_common',
                                            'force_correction', 'force_tester_sim')]
            + [os.environ.get('PYTHONPATH', '')]))
        t_cli, _ = timed(subprocess.run, cli, env=env, check=True, capture_output=True)
        mem = in_memory(pulls[:k], params)
        worst = max(abs(s.filtered_mean_pct - mem[s.set_id].filtered_mean_pct) for s in res.sets)
        t_camp, _ = timed(correct, tmp / 'small', tmp / 'small_corrected_campaign')

        n = args.pulls
        write_campaign(tmp / 'big', pulls[:n])
        t_read, camp = timed(read_campaign, tmp / 'big')
        t_tobag, _ = timed(campaign_to_bag, camp, tmp / 'big_bag')
        t_export, _ = timed(bag_to_campaign, tmp / 'big_bag', tmp / 'big_back')
        t_export_j, _ = timed(bag_to_campaign, tmp / 'big_bag', tmp / 'big_back_j',
                              workers=os.cpu_count() or 1)
        size_mb = sum(p.stat().st_size for p in (tmp / 'big_bag').iterdir()) / 1e6
        csv_mb = sum(p.stat().st_size for p in (tmp / 'big').iterdir()) / 1e6

        rows = [
            (f'correct, bag of {k} pulls ({real_s:.0f} s of data), median of {args.reps}',
             f'{t_bag * 1e3:.0f} ms', f'{real_s / t_bag:.0f}x real time (target >= 100x)'),
            ('same arithmetic in memory, median (alternating with the bag)',
             f'{t_mem * 1e3:.0f} ms', f'{real_s / t_mem:.0f}x real time'),
            ('bag / in memory, ratio of medians', f'{t_bag / t_mem:.1f}x', 'target <= 3x'),
            ('bag / in memory, ratio of the best runs', f'{min(t_bags) / min(t_mems):.1f}x',
             f'best {min(t_bags) * 1e3:.0f} ms vs {min(t_mems) * 1e3:.0f} ms'),
            ('correct, first call in the process (type set-up)', f'{t_first:.2f} s',
             f'{real_s / t_first:.0f}x real time'),
            ('./ft bag correct in a new process (imports too)', f'{t_cli:.2f} s',
             f'{real_s / t_cli:.0f}x real time'),
            (f'correct, campaign of {k} pulls (CSV in and out)', f'{t_camp:.2f} s',
             f'{real_s / t_camp:.0f}x real time'),
            ('max |bag - in-memory| set mean % (filtered)', f'{worst:.1e}', 'must be <= 1e-9'),
            (f'import {n} pulls: read CSV ({csv_mb:.0f} MB)', f'{t_read:.1f} s', ''),
            (f'import {n} pulls: write bag ({size_mb:.0f} MB)', f'{t_tobag:.1f} s',
             f'total {t_read + t_tobag:.1f} s (target < 60 s)'),
            (f'export {n} pulls: bag -> CSV, 1 process', f'{t_export:.1f} s', 'target < 60 s'),
            (f'export {n} pulls: bag -> CSV, {os.cpu_count()} processes (CLI default)',
             f'{t_export_j:.1f} s', 'target < 60 s'),
        ]
        w = max(len(r[0]) for r in rows)
        for r in rows:
            print(f'{r[0]:<{w}}  {r[1]:>9}  {r[2]}')
    finally:
        if args.keep:
            print(f'kept {tmp}')
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
