"""Benchmark of `discover` without a reference (docs/discovery.md, "Without a reference"): identification and
false-alarm rates on the test generator's drop impactor (tests/force_discovery/impactor.py: no stationary cell, no
encoder, compression impacts, 100 kHz, 4 records of 80 ms), and the time per campaign.

    ./ft bench impactor [--trials N] [--false-trials M] [--records K] [--rate HZ]

Identification: N campaigns with hidden effects drawn at random (mount 800-3000 Hz, accelerometer delay 10-80 us,
m2 0.27-0.40 kg against the rig YAML's 0.30, gain 0.95-1.05, hum 2-10 N at 50 or 60 Hz); identified = the mount
named with its mode within 1 % of the structure's, the delay named within 3 us, g m2's interval holding g x m2.
False alarms: M campaigns with nothing to act on in the force channel (m2 = 0.30 kg, gain 1, no delay, hum 0.2 N);
a false alarm is gain_mass_product, accel_delay or mains_hum named. The code sees only the data and the rig YAML.
--rate samples the records at another rate (the mount drawn below 0.4 x the rate); the summary gives g m2's error
(pooled estimate against g x m2), median and worst, at any rate.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'force_discovery'), str(ROOT / 'tests')]   # the test generator and its DAQ helpers

import numpy as np  # noqa: E402
from impactor import Impactor, memory_campaign, rig_yaml, tip_mode_hz  # noqa: E402

from force_discovery.core.pipeline import discover  # noqa: E402
from force_tester_sim.core.params import load_rig  # noqa: E402


def draw(seed: int, rate: float) -> Impactor:
    r = np.random.default_rng([seed, 2626])
    return Impactor(mount_hz=r.uniform(800, min(3000, 0.4 * rate)), accel_delay_s=r.uniform(10e-6, 80e-6),
                    m2_kg=r.uniform(0.27, 0.40), gain=r.uniform(0.95, 1.05), hum_hz=float(r.choice([50.0, 60.0])),
                    hum_n=r.uniform(2, 10), rate_hz=rate)


def identified(rep: dict, imp: Impactor) -> list:
    bad = []
    named = {c['name'] for c in rep['causes']}
    c = rep['candidates']
    if 'mount_resonance' not in named or abs(c['mount_resonance']['parameters']['frequency_hz'] / tip_mode_hz(imp)
                                             - 1) > 0.01:
        bad.append('mount')
    if 'accel_delay' not in named or abs(c['accel_delay']['parameters']['delay_s'] - imp.accel_delay_s) > 3e-6:
        bad.append('delay')
    lo, hi = c['gain_mass_product']['parameters_ci95']['gain_mass_kg']
    if not lo <= imp.gain * imp.m2_kg <= hi:
        bad.append(f'g m2 [{lo:.5g}, {hi:.5g}] vs {imp.gain * imp.m2_kg:.5g}')
    return bad


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench impactor', description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=10)
    ap.add_argument('--false-trials', type=int, default=6)
    ap.add_argument('--records', type=int, default=4)
    ap.add_argument('--rate', type=float, default=100_000.0, help='sample rate of the records, Hz (default 100000)')
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix='bench_impactor_'))
    rig = load_rig(rig_yaml(tmp / 'rig.yaml', a.rate, 0.08))
    ok, times, errs = 0, [], []
    for k in range(a.trials):
        imp = draw(k, a.rate)
        camp = memory_campaign(imp, a.records, seed0=100 * k)
        t = time.perf_counter()
        rep = discover(camp, rig, tmp / f'id{k}', scheduler='inline', plots=False)
        times.append(time.perf_counter() - t)
        bad = identified(rep, imp)
        ok += not bad
        errs.append(rep['candidates']['gain_mass_product']['parameters']['gain_mass_kg'] / (imp.gain * imp.m2_kg) - 1)
        print(f'trial {k}: mount {imp.mount_hz:.0f} Hz, delay {1e6 * imp.accel_delay_s:.1f} us, g m2 '
              f'{imp.gain * imp.m2_kg:.4f} kg: {"identified" if not bad else "MISSED " + ", ".join(bad)}', flush=True)
    fa = 0
    for k in range(a.false_trials):
        imp = Impactor(m2_kg=0.30, gain=1.0, accel_delay_s=0.0, hum_n=0.2, mount_hz=float(1000 + 300 * k),
                       rate_hz=a.rate)
        rep = discover(memory_campaign(imp, a.records, seed0=1000 + 100 * k), rig, tmp / f'fa{k}',
                       scheduler='inline', plots=False)
        named = {c['name'] for c in rep['causes']} & {'gain_mass_product', 'accel_delay', 'mains_hum'}
        fa += bool(named)
        print(f'null {k}: named {sorted(named) or "nothing"} in the force channel', flush=True)
    print(f'identified {ok}/{a.trials} ({100 * ok / max(a.trials, 1):.0f} %); false alarms {fa}/{a.false_trials} '
          f'({100 * fa / max(a.false_trials, 1):.0f} %); discover {np.median(times):.2f} s a campaign (median, '
          f'{a.records} records of {round(0.08 * a.rate)} samples at {a.rate:g} Hz, inline)')
    if errs:
        e = 100 * np.abs(errs)
        print(f'g m2 error: median {np.median(e):.3f} %, worst {np.max(e):.3f} % ({len(errs)} campaigns)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
