"""Benchmark of the simulation check (docs/discovery.md): time and per-channel gains of
re-simulating held-out pulls
with the model of record and with the model of record + extension.

    PYTHONPATH=src/force_tester_sim:src/force_discovery:src/force_tester_common:tests/force_discovery \
        python benchmarks/bench_resim.py [--pulls 20] [--nuisance SEED] [--single]

Default: a campaign of the truth reference rig (config/truth_reference.yaml, 5 sets x --pulls), prepared against the
nominal rig; the held-out half (odd list positions, as discover) re-simulated with the truth rig's departures as
the extension. --nuisance adds the test generator's model-form nuisances (damping, anti-alias filter, 1/f noise,
16-bit samples). --single: instead, one hidden departure at a time (3 sets x 2 pulls each), scored with the true one.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'force_discovery'), str(ROOT / 'tests')]   # the test generator, its timing

import generator as G  # the test generator

from force_discovery.core.prep import prepare
from force_discovery.core.resim import simulation_check
from force_tester_sim.core.departures import departures_from_data
from force_tester_sim.core.params import TRUTH_YAML, load_rig

SINGLE = {
    'effective_mass': {'mass_kg': 1.4},
    'mount_resonance': {'frequency_hz': 1200.0, 'damping_ratio': 0.02},
    'moving_cell_gain': {'gain': 1.05},
    'accel_delay': {'delay_s': 5e-5},
    'ac_coupling': {'time_constant_s': 0.5},
    'mains_hum': {'frequency_hz': 60.0, 'amplitude_n': 10.0},
    'coulomb_friction': {'force_n': 150.0},
}


def show(title: str, chk, n: int) -> None:
    print(f'== {title}: {n} pulls re-simulated in {chk.time_s:.2f} s ({chk.time_s / n:.3f} s/pull); '
          f'cell damping {chk.cell_damping}')
    for ch, v in chk.as_dict().items():
        print(f'   {ch:20s} baseline {v["baseline_rms"]:9.3f}  extended {v["extended_rms"]:9.3f}  '
              f'gain {v["gain"]:8.2f}')
    if chk.ring:
        print(f'   ring: measured {chk.ring["measured_hz"]} Hz, extended sim {chk.ring["extended_sim_hz"]} Hz, '
              f'rel. error {chk.ring["rel_error"]}')
    if chk.skipped:
        print(f'   skipped: {chk.skipped}')


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument('--pulls', type=int, default=20)
    ap.add_argument('--nuisance', type=int, default=None)
    ap.add_argument('--single', action='store_true')
    a = ap.parse_args()
    rig = load_rig()
    nz = G.draw_nuisance(a.nuisance) if a.nuisance is not None else None
    if a.single:
        for name, params in SINGLE.items():
            camp = G.make_campaign({name: params}, seed=3, sets=(2, 3, 4), pulls=2, nuisance=nz)
            pulls = [prepare(m, c, rig) for m, c in camp]
            show(f'{name} {params}', simulation_check(pulls, range(len(pulls)), rig,
                                                     departures_from_data({name: params})), len(pulls))
        return 0
    truth = load_rig(TRUTH_YAML)
    t0 = time.perf_counter()
    camp = G.make_campaign(truth.departures.as_dict(), seed=1, sets=(1, 2, 3, 4, 5), pulls=a.pulls, nuisance=nz)
    t1 = time.perf_counter()
    pulls = [prepare(m, c, rig) for m, c in camp]
    t2 = time.perf_counter()
    held = list(range(1, len(pulls), 2))
    print(f'campaign {len(pulls)} pulls: simulated {t1 - t0:.1f} s, prepared {t2 - t1:.1f} s')
    show(f'truth rig, extension = its departures ({truth.departures})',
         simulation_check(pulls, held, rig, truth.departures), len(held))
    return 0


if __name__ == '__main__':
    sys.exit(main())
