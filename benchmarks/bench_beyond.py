"""Benchmark of the search beyond the catalog (docs/discovery.md): how often `discover` finds a departure
outside the catalog as the right term, and its cost.

    ./ft bench beyond [--trials N] [--clean M] [--seed S] [--kinds K1,K2,...] [--generator own|independent|both]

For every departure of the generator outside the catalog (generator.BEYOND, or those --kinds names: the eight the
search was built on, quadratic cell, air drag, zero drift of the moving cell, the stationary cell and the
accelerometer, carriage-excited vibration, viscous friction, cable drag; and the six it was not tuned on,
generator.UNTUNED: cubic cell, rail friction along the track, quadratic zero drift, stationary-cell pickup off the
mains, rate-dependent cell, the accelerometer misreading the speed; and, since issue 39, generator.SENSOR_OWN: the
stationary cell's and the accelerometer's own quadratic non-linearity), N campaigns (3 sets x 4 pulls) with it hidden
at a random strength, every other one through the model-form nuisances. Counted: the right term first on the right
channel of beyond_catalog; its coefficient within 30 % of the truth; no catalog cause named (the truth is outside
the catalog); whether its ci95 (statistical and systematic parts, core/beyond/) holds the true coefficient; and, when
another term is first, whether the right one is listed beside it as near-tied (beyond.near_tied: the data cannot
tell them apart). Beside them, each campaign's gain through the simulator on the truth's channel (report.json
simulation: the held-out pulls re-simulated with the model of record and with the extension; '-' when the check did
not run). A miss's line gives what was named, what was significant but within the band, and any catalog name.
Then M campaigns with nothing to act on (clean and nuisance in turn): a false alarm is any entry in
beyond_catalog. The cost: the wall time of the search's passes (Clock)
against the whole discovery's, side by side in one run. The code under test sees only the data and the nominal rig.
With --generator independent (or both, side by side): tests/independent's departures outside the catalog
(benchmarks/independent_cases.py), each hidden alone on a rig drawn per seed, `discover` given its datasheet; the
right term is the first grammar term the truth states; a departure whose physics has no term in the grammar is
counted on its own line (what was named for it); the false alarms on its campaigns with no departure.
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

from force_discovery.core.pipeline import discover
from force_tester_sim.core.extra_terms import CHANNEL_COLUMNS
from force_tester_sim.core.params import load_rig


class Clock:
    """progress(stage, done, total): the search's wall time, from the last report of the stage before it (the
    statistics pass; the decision between them is quick) to the search's last report."""

    def __init__(self):
        self.before = self.last = None

    def __call__(self, stage, done, total):
        now = time.perf_counter()
        if stage == 'beyond':
            self.last = now
        elif self.last is None:
            self.before = now

    def seconds(self) -> float:
        return 0.0 if self.last is None or self.before is None else self.last - self.before


def run(camp, rig, out):
    clock = Clock()
    t0 = time.perf_counter()
    report = discover(camp, rig, out, scheduler='inline', progress=clock)
    total = time.perf_counter() - t0
    return report, total, clock.seconds()


KEYS = ('right_term', 'coefficient_30pct', 'no_catalog', 'covered', 'near_tied')


def one(gen: str, kind: str, seed: int, k: int, rig, out):
    """(report, truth term or None, discovery s, search s) of one campaign with ``kind`` hidden."""
    if gen == 'own':
        camp, truth = G.beyond_campaign(kind, seed, nuisance=k % 2 == 1)
    else:
        c = IG.case(seed, [{'name': kind}])
        camp, rig, truth = c.campaign, c.rig, IG.beyond_term(c.truth)
    return (*run(camp, rig, out), truth)


def departures(gen: str, a, rig, tmp, clock) -> dict:
    tot = {**{key: 0 for key in KEYS}, 'n': 0, 'outside': 0, 'outside_named': 0}
    for kind in (a.kinds if gen == 'own' else a.independent_kinds):
        row = {key: 0 for key in KEYS}
        misses, gains, n = [], [], 0
        for k in range(a.trials):
            seed = a.seed + k
            report, t, ts, truth = one(gen, kind, seed, k, rig, tmp / f'{gen}_{kind}_{k}')
            clock[0], clock[1] = clock[0] + t, clock[1] + ts
            if truth is None:   # its physics has no term in the grammar: what was named for it
                named = [(b['channel'], b['term']) for b in report['beyond_catalog']] + \
                    [c['name'] for c in report['causes'] if c['name'] != 'unexplained']
                tot['outside'] += 1
                tot['outside_named'] += bool(named)
                print(f'{gen:<12} {kind:<20} seed {seed}: no grammar term for this physics; named {named}', flush=True)
                continue
            n += 1
            got = G.check_beyond(report, truth)
            sim = (report.get('simulation') or {}).get(CHANNEL_COLUMNS[truth['channel']])
            gains.append('-' if sim is None or sim['gain'] is None else f'{sim["gain"]:.3g}')
            for key, hit in (('right_term', got['right_term']), ('coefficient_30pct', got['coefficient_30pct']),
                             ('no_catalog', not got['catalog_named']), ('covered', got['ci95_holds']),
                             ('near_tied', got['near_tied'])):
                row[key] += bool(hit)
            if not (got['right_term'] and got['coefficient_30pct'] and not got['catalog_named']):
                band = report.get('beyond_search', {}).get('within_tolerance', [])
                within = [(b['channel'], b['term']) for b in band]
                misses.append(f'seed {seed}: truth {truth["channel"]} {truth["term"]}={truth["coefficient"]:.4g}, '
                              f'found {got["found"]}, within the band {within}, catalog {got["catalog_named"]}')
        for key in row:
            tot[key] += row[key]
        tot['n'] += n
        if n:
            counts = ' '.join(f'{row[key]:>{w}}/{n:<2}' for key, w in zip(KEYS, (7, 6, 7, 7, 6)))
            print(f'{gen:<12} {kind:<20} {counts}  {"/".join(gains):<20}  {"; ".join(misses)}', flush=True)
    return tot


def clean(gen: str, a, rig, tmp, clock) -> int:
    false = 0
    for k in range(a.clean):
        seed = a.seed + 500 + k
        if gen == 'own':
            nuis = G.draw_nuisance(seed) if k % 2 else None
            camp, what = G.make_campaign(None, seed, nuisance=nuis), 'nuisance' if nuis else 'clean'
        else:
            c = IG.case(seed, [])
            camp, rig, what = c.campaign, c.rig, 'clean'
        report, t, ts = run(camp, rig, tmp / f'{gen}_clean_{k}')
        clock[0], clock[1] = clock[0] + t, clock[1] + ts
        if report['beyond_catalog']:
            false += 1
            print(f'{gen:<12} false alarm (seed {seed}, {what}): '
                  f'{[(b["channel"], b["term"]) for b in report["beyond_catalog"]]}', flush=True)
    return false


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=4, help='campaigns per departure (default 4)')
    ap.add_argument('--clean', type=int, default=6, help='campaigns with nothing to act on (default 6)')
    ap.add_argument('--seed', type=int, default=2700, help='first seed (default 2700)')
    ap.add_argument('--kinds', default=None,
                    help='the departures to hide, comma-separated (default every one of the generator\'s: '
                         f'own {",".join(sorted(G.BEYOND))}; independent {",".join(IG.BEYOND)})')
    IG.add_option(ap)
    a = ap.parse_args()
    if a.trials < 0 or a.clean < 0:
        print(f'bench_beyond: error: --trials {a.trials} / --clean {a.clean}; expected >= 0', file=sys.stderr)
        return 2
    kinds = [k for k in (a.kinds or '').split(',') if k]
    unknown = [k for k in kinds if k not in G.BEYOND and k not in IG.BEYOND]
    if unknown:
        print(f'bench_beyond: error: --kinds {",".join(unknown)}; expected some of {",".join(sorted(G.BEYOND))} '
              f'(own) or {",".join(IG.BEYOND)} (independent)', file=sys.stderr)
        return 2
    a.kinds = [k for k in kinds if k in G.BEYOND] if kinds else sorted(G.BEYOND)
    a.independent_kinds = [k for k in kinds if k in IG.BEYOND] if kinds else list(IG.BEYOND)
    rig = load_rig()
    tmp = Path(tempfile.mkdtemp(prefix='bench_beyond_'))
    print(f'{"generator":<12} {"departure":<20} {"right term":>10} {"coef 30%":>9} {"no catalog":>10} '
          f'{"ci95 holds":>10} {"near-tied":>9}  {"sim gain":<20}  misses', flush=True)
    results = {}
    for gen in IG.chosen(a.generator):
        clock = [0.0, 0.0]   # the discoveries' and the searches' wall time
        tot = departures(gen, a, rig, tmp, clock)
        false = clean(gen, a, rig, tmp, clock)
        results[gen] = (tot, false, clock)
    print()
    for gen, (tot, false, (t_all, t_search)) in results.items():
        n = tot['n']
        runs = n + tot['outside'] + a.clean
        print(f'{gen} generator:')
        if n:
            for key, what in (('right_term', 'right term on the right channel'),
                              ('coefficient_30pct', 'coefficient within 30 %'),
                              ('no_catalog', 'no catalog name (truth outside)'),
                              ('covered', 'ci95 holds the true coefficient (the right term found, else not held)'),
                              ('near_tied', 'right term near-tied (not first)')):
                print(f'  {what + ":":<40} {tot[key]}/{n} ({100 * tot[key] / n:.0f} %)')
        if tot['outside']:
            print(f'  {"physics with no grammar term, named:":<40} {tot["outside_named"]}/{tot["outside"]}')
        if a.clean:
            print(f'  {"false alarms:":<40} {false}/{a.clean} ({100 * false / a.clean:.0f} %)')
        if runs:
            print(f'  cost: the search {t_search / runs:.2f} s of {t_all / runs:.1f} s a discovery '
                  f'({100 * t_search / max(t_all, 1e-9):.0f} %), {runs} campaigns, inline')
    return 0


if __name__ == '__main__':
    sys.exit(main())
