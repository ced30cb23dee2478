"""Benchmark of the search beyond the catalog (docs/discovery.md): how often `discover` finds a departure
outside the catalog as the right term, and its cost.

    ./ft bench beyond [--trials N] [--clean M] [--seed S] [--kinds K1,K2,...]

For every departure of the generator outside the catalog (generator.BEYOND, or those --kinds names: the eight the
search was built on, quadratic cell, air drag, zero drift of the moving cell, the stationary cell and the
accelerometer, carriage-excited vibration, viscous friction, cable drag; and the six it was not tuned on,
generator.UNTUNED: cubic cell, rail friction along the track, quadratic zero drift, stationary-cell pickup off the
mains, rate-dependent cell, the accelerometer misreading the speed), N campaigns (3 sets x 4 pulls) with it hidden
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=4, help='campaigns per departure (default 4)')
    ap.add_argument('--clean', type=int, default=6, help='campaigns with nothing to act on (default 6)')
    ap.add_argument('--seed', type=int, default=2700, help='first seed (default 2700)')
    ap.add_argument('--kinds', default=','.join(sorted(G.BEYOND)),
                    help='the departures to hide, comma-separated (default every one of generator.BEYOND)')
    a = ap.parse_args()
    if a.trials < 0 or a.clean < 0:
        print(f'bench_beyond: error: --trials {a.trials} / --clean {a.clean}; expected >= 0', file=sys.stderr)
        return 2
    kinds = [k for k in a.kinds.split(',') if k]
    unknown = [k for k in kinds if k not in G.BEYOND]
    if unknown:
        print(f'bench_beyond: error: --kinds {",".join(unknown)}; expected some of {",".join(sorted(G.BEYOND))}',
              file=sys.stderr)
        return 2
    rig = load_rig()
    tmp = Path(tempfile.mkdtemp(prefix='bench_beyond_'))
    tot = {'right_term': 0, 'coefficient_30pct': 0, 'no_catalog': 0, 'covered': 0, 'near_tied': 0, 'n': 0}
    t_all = t_search = 0.0
    print(f'{"departure":<20} {"right term":>10} {"coef 30%":>9} {"no catalog":>10} {"ci95 holds":>10} '
          f'{"near-tied":>9}  {"sim gain":<20}  misses', flush=True)
    for kind in kinds:
        row = {'right_term': 0, 'coefficient_30pct': 0, 'no_catalog': 0, 'covered': 0, 'near_tied': 0}
        misses, gains = [], []
        for k in range(a.trials):
            seed = a.seed + k
            camp, truth = G.beyond_campaign(kind, seed, nuisance=k % 2 == 1)
            report, t, ts = run(camp, rig, tmp / f'{kind}_{k}')
            t_all, t_search = t_all + t, t_search + ts
            got = G.check_beyond(report, truth)
            sim = (report.get('simulation') or {}).get(CHANNEL_COLUMNS[truth['channel']])
            gains.append('-' if sim is None or sim['gain'] is None else f'{sim["gain"]:.3g}')
            row['right_term'] += got['right_term']
            row['coefficient_30pct'] += got['coefficient_30pct']
            row['no_catalog'] += not got['catalog_named']
            row['covered'] += got['ci95_holds']
            row['near_tied'] += got['near_tied']
            if not (got['right_term'] and got['coefficient_30pct'] and not got['catalog_named']):
                band = report.get('beyond_search', {}).get('within_tolerance', [])
                within = [(t['channel'], t['term']) for t in band]
                misses.append(f'seed {seed}: truth {truth["term"]}={truth["coefficient"]:.4g}, found {got["found"]}, '
                              f'within the band {within}, catalog {got["catalog_named"]}')
        for key in row:
            tot[key] += row[key]
        tot['n'] += a.trials
        print(f'{kind:<20} {row["right_term"]:>7}/{a.trials:<2} {row["coefficient_30pct"]:>6}/{a.trials:<2} '
              f'{row["no_catalog"]:>7}/{a.trials:<2} {row["covered"]:>7}/{a.trials:<2} '
              f'{row["near_tied"]:>6}/{a.trials:<2}  {"/".join(gains):<20}  {"; ".join(misses)}',
              flush=True)
    false = 0
    for k in range(a.clean):
        seed = a.seed + 500 + k
        nuis = G.draw_nuisance(seed) if k % 2 else None
        report, t, ts = run(G.make_campaign(None, seed, nuisance=nuis), rig, tmp / f'clean_{k}')
        t_all, t_search = t_all + t, t_search + ts
        if report['beyond_catalog']:
            false += 1
            print(f'false alarm (seed {seed}, {"nuisance" if nuis else "clean"}): '
                  f'{[(b["channel"], b["term"]) for b in report["beyond_catalog"]]}', flush=True)
    n = tot['n']
    runs = n + a.clean
    print()
    if n:
        print(f'right term on the right channel: {tot["right_term"]}/{n} ({100 * tot["right_term"] / n:.0f} %)')
        print(f'coefficient within 30 %:        {tot["coefficient_30pct"]}/{n} '
              f'({100 * tot["coefficient_30pct"] / n:.0f} %)')
        print(f'no catalog name (truth outside): {tot["no_catalog"]}/{n} ({100 * tot["no_catalog"] / n:.0f} %)')
        print(f'ci95 holds the true coefficient: {tot["covered"]}/{n} ({100 * tot["covered"] / n:.0f} %; the right '
              'term found, else counted as not holding)')
        print(f'right term near-tied (not first): {tot["near_tied"]}/{n}')
    if a.clean:
        print(f'false alarms:                   {false}/{a.clean} ({100 * false / a.clean:.0f} %)')
    if runs:
        print(f'cost: the search {t_search / runs:.2f} s of {t_all / runs:.1f} s a 12-pull discovery '
              f'({100 * t_search / max(t_all, 1e-9):.0f} %), {runs} campaigns, inline')
    return 0


if __name__ == '__main__':
    sys.exit(main())
