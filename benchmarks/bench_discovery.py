"""Benchmark of `discover` (docs/discovery.md): identification and false-alarm rates,
and the time of a 100-pull
analysis with its split (the stages, and the re-simulation of the held-out pulls).

    ./ft bench discovery [--trials N] [--false-trials M] [--skip-timing] [--generator own|independent|both]

Identification: for every catalog entry, N campaigns (3 sets x 4 pulls) with ONE hidden effect drawn from the
documented plausible ranges (generator.PLAUSIBLE), every other one through the model-form nuisances (cells and
lanyard 2-4x damped, a common anti-alias filter, 1/f noise, 16-bit samples); identified = right primary name +
parameters within generator.TOLERANCE + gain > 1.
False alarms: M campaigns with nothing to act on, in turn clean, with the nuisances (and departures well inside
the tolerances), and clean with real-world data defects (DAQ under-runs, 200-500 N spikes); a false alarm is any
named cause (for the defect campaigns: any catalog name). Out-of-catalog campaigns naming a catalog entry are
counted on their own line. The code under test sees only the data and the nominal rig.
With --generator independent (or both, side by side): the same counts on tests/independent's campaigns, physics
written apart from the search (benchmarks/independent_cases.py): each catalog entry it has hidden alone on a rig
it draws per seed, `discover` given that rig's datasheet; the false alarms on its campaigns with no departure.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'force_discovery'), str(ROOT / 'tests')]   # the test generator, its timing

import generator as G  # the generator
import independent_cases as IG  # beside this script: --generator
from bench_beyond import Clock  # beside this script

from force_discovery.core.pipeline import discover
from force_tester_sim.core.params import load_rig

FALSE_KINDS = ('clean', 'nuisance', 'defects')


def false_campaign(kind: str, seed: int):
    if kind == 'clean':
        return G.make_campaign(None, seed)
    if kind == 'nuisance':
        return G.make_campaign(None, seed, nuisance=G.draw_nuisance(seed))
    from defects import real_world_defects
    return real_world_defects(G.make_campaign(None, seed), seed)[0]


def check_identified(report: dict, name: str, truths: dict) -> list:
    """The own generator's rule on an independent campaign: the right primary cause, its parameters within
    generator.TOLERANCE of the truth (the mount: the mode the accelerometer sees), the gain above 1."""
    if report['cause'] != name:
        return [f'cause {report["cause"]!r} != {name!r} ({[c["name"] for c in report["causes"]]})']
    got = report['causes'][0]['parameters']
    bad = [f'{k} = {got.get(k)}, truth {v:.6g}' for (cause, k), v in truths.items()
           if cause == name and k in G.TOLERANCE and (got.get(k) is None or not G.within(got[k], v, k))]
    if not (report['gain'] and report['gain'] > 1.0):
        bad.append(f'gain {report["gain"]}')
    return bad


def identification(gen: str, a, tmp) -> tuple:
    """(identified, campaigns, simulation s, analysis s), one line per catalog entry."""
    n_id = n_ok = 0
    t_sim = t_an = 0.0
    rig = load_rig()
    for name in sorted(G.PLAUSIBLE if gen == 'own' else IG.CATALOG):
        ok, fails = 0, []
        for k in range(a.trials):
            seed = 1000 + k
            t0 = time.perf_counter()
            if gen == 'own':
                truth = G.draw(name, seed)
                nuisance = G.draw_nuisance(seed, within_tolerance=False) if k % 2 else None
                camp, rig_k = G.make_campaign({name: truth}, seed, nuisance=nuisance), rig
            else:
                c = IG.case(seed + 100 * sorted(IG.CATALOG).index(name), [{'name': name}])
                camp, rig_k, truth, nuisance = c.campaign, c.rig, IG.catalog_truths(c.truth), None
            t1 = time.perf_counter()
            rep = discover(camp, rig_k, tmp / f'{gen}_{name}_{k}', plots=False)
            t_an += time.perf_counter() - t1
            t_sim += t1 - t0
            bad = G.check_identified(rep, name, truth) if gen == 'own' else check_identified(rep, name, truth)
            ok += not bad
            if bad:
                shown = truth if gen == 'own' else {p: round(v, 6) for (cn, p), v in truth.items() if cn == name}
                fails.append(f'{shown}{" +nuisance" if nuisance else ""}: {bad}')
        n_id += a.trials
        n_ok += ok
        print(f'{gen:<12} {name:<18} {ok:>4}/{a.trials:<5}  ' + ' | '.join(fails), flush=True)
    return n_ok, n_id, t_sim, t_an


def false_alarms(gen: str, a, tmp) -> int:
    rig = load_rig()
    fa, got = 0, {}
    for k in range(a.false_trials):
        if gen == 'own':
            kind, seed = FALSE_KINDS[k % len(FALSE_KINDS)], 2000 + k
            camp, rig_k = false_campaign(kind, seed), rig
        else:
            c = IG.case(2000 + k, [])
            kind, camp, rig_k = 'clean', c.campaign, c.rig
        rep = discover(camp, rig_k, tmp / f'{gen}_false_{k}', plots=False)
        wrong = rep['cause'] not in (('none', 'unexplained') if kind == 'defects' else ('none',))
        fa += wrong
        got.setdefault(kind, []).append(rep['cause'])
    for kind, causes in got.items():
        print(f'{gen:<12} {kind:<18} causes: {causes}', flush=True)
    return fa


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=4, help='campaigns per catalog entry (default 4)')
    ap.add_argument('--false-trials', type=int, default=21, help='campaigns with nothing to act on (default 21)')
    ap.add_argument('--skip-timing', action='store_true', help='skip the 100-pull timing')
    IG.add_option(ap)
    a = ap.parse_args()
    rig = load_rig()
    tmp = Path(tempfile.mkdtemp(prefix='bench_discovery_'))
    print(f'{"generator":<12} {"entry":<18} {"identified":>10}  failures', flush=True)
    figures = {}
    for gen in IG.chosen(a.generator):
        n_ok, n_id, t_sim, t_an = identification(gen, a, tmp)
        fa = false_alarms(gen, a, tmp) if a.false_trials else 0
        if gen == 'own':
            for kind in G.OUT_OF_CATALOG:
                causes = [discover(G.out_of_catalog(kind, 3000 + k), rig, tmp / f'{kind}_{k}', plots=False)['cause']
                          for k in range(max(1, a.trials // 2))]
                print(f'{gen:<12} {kind:<18} catalog names given: '
                      f'{sum(c not in ("none", "unexplained") for c in causes)}/{len(causes)}  causes: {causes}',
                      flush=True)
        figures[gen] = (n_ok, n_id, fa, t_sim, t_an)
    for gen, (n_ok, n_id, fa, t_sim, t_an) in figures.items():
        print(f'{gen} generator: identification {n_ok}/{n_id} = {100 * n_ok / max(n_id, 1):.0f} % (target >= 95 %); '
              f'false alarms {fa}/{a.false_trials} = {100 * fa / max(a.false_trials, 1):.0f} % (target <= 5 %); '
              f'time: simulation {t_sim:.1f} s, analysis {t_an:.1f} s (catalog trials)')
    if not a.skip_timing:
        from force_tester_common.engine import map_pulls
        from force_tester_sim.core.campaign import generate_campaign
        rig_t = G.rig_with({'effective_mass': {'mass_kg': 1.3}})
        t0 = time.perf_counter()
        camp = generate_campaign(rig_t, pulls=20, seed=7, mapper=map_pulls)
        t1 = time.perf_counter()
        clock = Clock()
        rep = discover(camp, rig, tmp / 'timing', progress=clock)
        t2 = time.perf_counter()
        resim = rep['simulation_check']['time_s']
        print(f'100-pull campaign: made in {t1 - t0:.1f} s; discover {t2 - t1:.1f} s (target < 180 s) = stages and '
              f'report {t2 - t1 - resim:.1f} s + re-simulation of {len(rep["held_out_pulls"])} held-out pulls '
              f'{resim:.1f} s (workers\' CPU); the search beyond the catalog {clock.seconds():.1f} s of it (wall, '
              f'bench_beyond.Clock)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
