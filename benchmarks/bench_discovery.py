"""Benchmark of `discover` (issue 5): identification and false-alarm rates, and the time of a 100-pull analysis.

    PYTHONPATH=src/force_tester_sim:src/force_correction:src/bag_tools:tools:tests \
        python benchmarks/bench_discovery.py [--trials N] [--skip-timing]

For every catalog entry, N campaigns (3 sets x 4 pulls) with ONE hidden effect drawn from the documented plausible
ranges (tests/test_discovery.py PLAUSIBLE); identified = right primary name + parameters within TOLERANCE + gain > 1.
False alarms: no-effect campaigns naming anything; out-of-catalog campaigns naming a catalog entry.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for sub in ('src/force_tester_sim', 'src/force_correction', 'src/force_discovery', 'src/force_tester_common',
            'src/bag_tools', 'tools', 'tests', 'tests/force_discovery'):
    sys.path.insert(0, str(ROOT / sub))

import generator as G  # noqa: E402  (the generator)

from force_discovery.core.pipeline import discover  # noqa: E402
from force_tester_sim.core.params import load_rig  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument('--trials', type=int, default=5)
    ap.add_argument('--skip-timing', action='store_true')
    a = ap.parse_args()
    rig = load_rig()
    tmp = Path(tempfile.mkdtemp(prefix='bench_discovery_'))
    t_sim = t_an = 0.0
    print(f'{"entry":<18} {"identified":>10}  failures')
    for name in sorted(G.PLAUSIBLE):
        ok, fails = 0, []
        for k in range(a.trials):
            seed = 1000 + k
            truth = G.draw(name, seed)
            t0 = time.perf_counter()
            camp = G.make_campaign({name: truth}, seed)
            t1 = time.perf_counter()
            rep = discover(camp, rig, tmp / f'{name}_{k}')
            t_an += time.perf_counter() - t1
            t_sim += t1 - t0
            bad = G.check_identified(rep, name, truth)
            ok += not bad
            if bad:
                fails.append(f'{truth}: {bad}')
        print(f'{name:<18} {ok:>4}/{a.trials:<5}  ' + ' | '.join(fails))
    for kind in ('none',) + G.OUT_OF_CATALOG:
        fa, got = 0, []
        for k in range(a.trials):
            seed = 2000 + k
            camp = G.make_campaign(None, seed) if kind == 'none' else G.out_of_catalog(kind, seed)
            rep = discover(camp, rig, tmp / f'{kind}_{k}')
            wrong = rep['cause'] not in ('none',) if kind == 'none' else rep['cause'] not in ('none', 'unexplained')
            fa += wrong
            got.append(rep['cause'])
        print(f'{kind:<18} false alarms {fa}/{a.trials}  causes: {got}')
    print(f'time: simulation {t_sim:.1f} s, analysis {t_an:.1f} s (catalog trials)')
    if not a.skip_timing:
        from force_tester_sim.core.campaign import generate_campaign
        rig_t = G.rig_with({'effective_mass': {'mass_kg': 1.3}})
        t0 = time.perf_counter()
        camp = generate_campaign(rig_t, pulls=20, seed=7, workers=2)
        t1 = time.perf_counter()
        discover(camp, rig, tmp / 'timing')
        t2 = time.perf_counter()
        tot = t2 - t0
        print(f'100-pull run: simulation {t1 - t0:.1f} s + analysis {t2 - t1:.1f} s = {tot:.1f} s '
              f'(simulation share {100 * (t1 - t0) / tot:.0f} %)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
