"""Where the test suite's time goes: the slowest tests and the time by kind (the tables of docs/tests.md).

    ./ft bench tests [--run [PYTEST_ARGS]] [--file FILE] [--baseline FILE] [--top 25]

Reads the durations the last `./ft test` wrote (.ft/test-durations.json; tests/conftest.py records each test's
time, its kind and the seconds it spent making campaigns and in `discover`), or with --run runs `./ft test`
first (the whole suite, or PYTEST_ARGS). Prints the TOP slowest tests, the test time by kind (the seconds inside
the campaign makers and `discover`, measured; the rest of each test's time under its kind marker: ros, browser,
netns, or the rest) and the tiers: the time of the fast tier (the tests not marked slow) and any of its tests
over the limit. --baseline adds the same figures of an earlier file (a durations file, or pytest's --junitxml
report, whose tests have no kinds) side by side. The sums are test seconds: with several workers the wall time
is shorter (pytest prints it).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests'))
from kinds import FAST_S, KINDS, LABELS  # noqa: E402  (the tests' own definition of the kinds)

from ft_cli.commands.workspace import DURATIONS  # noqa: E402  (where ./ft test writes them; ./ft puts tools/ on the path)


def load(path: Path) -> list:
    """[{nodeid, seconds, kind, slow, campaign, discover, cpu}] from a durations file or a JUnit XML report."""
    if path.suffix == '.xml':
        out = []
        for case in ET.parse(path).getroot().iter('testcase'):
            parts = case.get('classname', '').split('.')
            cls = parts.pop() if parts and parts[-1][:1].isupper() else None
            nodeid = '::'.join(['/'.join(parts) + '.py', *([cls] if cls else []), case.get('name')])
            out.append({'nodeid': nodeid, 'seconds': float(case.get('time', 0.0)), 'kind': None, 'slow': None})
        return out
    return json.loads(path.read_text())


def by_kind(records: list) -> dict:
    """{kind: seconds}: campaign and discover as measured, each test's remainder under its own kind."""
    out = defaultdict(float)
    for r in records:
        measured = sum(r.get(k, 0.0) for k in ('campaign', 'discover'))
        for k in ('campaign', 'discover'):
            out[k] += r.get(k, 0.0)
        out[r['kind'] or 'unknown'] += max(r['seconds'] - measured, 0.0)
    return out


def with_kinds_of(baseline: list, records: list) -> list:
    """BASELINE's tests (a JUnit report has no kinds) with the kinds of the same tests in RECORDS, and their
    campaign and discover seconds at the share of the test's time that RECORDS measured: an estimate."""
    now = {r['nodeid']: r for r in records}
    out = []
    for b in baseline:
        r = now.get(b['nodeid'])
        if b['kind'] is None and r is not None:
            share = {k: r.get(k, 0.0) / r['seconds'] for k in ('campaign', 'discover') if r['seconds'] > 0}
            b = {**b, 'kind': r['kind'], **{k: v * b['seconds'] for k, v in share.items()}}
        out.append(b)
    return out


def kind_table(kinds: dict, total: float) -> list:
    return [f'| {LABELS.get(k, k)} | {kinds[k]:.0f} | {100 * kinds[k] / total:.0f} % |'
            for k in (*KINDS, 'unknown') if kinds.get(k)]


def worker_lines(records: list) -> list:
    """The run's span (first test's start to last test's end) and, per xdist worker, the seconds it spent in tests
    and when it ran out of tests: the tail is the time the last worker ran on alone at the end."""
    t0, t1 = min(r['start'] for r in records), max(r['end'] for r in records)
    ends = {}
    lines = [f'Workers: the tests ran from start to end in {t1 - t0:.0f} s ({(t1 - t0) / 60:.1f} min)', '',
             '| worker | tests | seconds in tests | its last test ended at |', '|---|---|---|---|']
    for w in sorted({r['worker'] for r in records}):
        mine = [r for r in records if r['worker'] == w]
        ends[w] = max(r['end'] for r in mine) - t0
        lines.append(f"| {w} | {len(mine)} | {sum(r['end'] - r['start'] for r in mine):.0f} | {ends[w]:.0f} s |")
    last = sorted(ends.values())
    if len(last) > 1:
        lines.append(f'\ntail (the last worker alone after the one before it ran out of tests): '
                     f'{last[-1] - last[-2]:.0f} s')
    return lines


def print_tables(records: list, top: int, baseline: list | None = None) -> None:
    total = sum(r['seconds'] for r in records)
    base = {r['nodeid']: r['seconds'] for r in baseline or []}
    print(f'{len(records)} tests, {total:.0f} s of test time ({total / 60:.1f} min)'
          + (f'; baseline {len(base)} tests, {sum(base.values()):.0f} s' if baseline else ''))
    cpu = [r for r in records if r.get('cpu') is not None]
    if cpu:   # what a run on fewer cores than workers waits for: the CPU, not the seconds a test waited
        print(f"{sum(r['cpu'] for r in cpu):.0f} CPU seconds (each test's process, the children it waited for and "
              'its descendants still running)')
        print(f'\nThe {top} tests that cost the most CPU\n')
        print('| # | CPU s | seconds | kind | test |')
        print('|---|---|---|---|---|')
        for i, r in enumerate(sorted(cpu, key=lambda r: -r['cpu'])[:top], 1):
            print(f"| {i} | {r['cpu']:.1f} | {r['seconds']:.1f} | {r['kind'] or '-'} | `{r['nodeid']}` |")
    print(f'\nThe {top} slowest tests (seconds: setup + call + teardown)\n')
    print('| # | seconds |' + (' baseline |' if baseline else '') + ' kind | test |')
    print('|---|---|' + ('---|' if baseline else '') + '---|---|')
    for i, r in enumerate(sorted(records, key=lambda r: -r['seconds'])[:top], 1):
        was = f" {base[r['nodeid']]:.1f} |" if r['nodeid'] in base else (' - |' if baseline else '')
        print(f"| {i} | {r['seconds']:.1f} |{was} {r['kind'] or '-'} | `{r['nodeid']}` |")
    print('\nTest time by kind (campaigns and discover measured inside the tests; the rest of a test under its '
          'marker)\n')
    print('| kind | seconds | share |')
    print('|---|---|---|')
    print('\n'.join(kind_table(by_kind(records), total)))
    if baseline:
        was = with_kinds_of(baseline, records)
        print('\nThe baseline by kind (its tests\' kinds from this run, their campaign and discover seconds at the '
              'shares this run measured: an estimate where the baseline recorded none)\n')
        print('| kind | seconds | share |')
        print('|---|---|---|')
        print('\n'.join(kind_table(by_kind(was), sum(r['seconds'] for r in was))))
    timed = [r for r in records if r.get('start') is not None]
    if timed:
        print('\n' + '\n'.join(worker_lines(timed)))
    fast = [r for r in records if r['slow'] is False]
    if fast:
        over = [r for r in fast if r['seconds'] > FAST_S]
        print(f'\nfast tier (not slow): {len(fast)} tests, {sum(r["seconds"] for r in fast):.0f} s of test time; '
              f'slow: {len(records) - len(fast)} tests; fast-tier tests over {FAST_S:g} s: {len(over)}')
        for r in sorted(over, key=lambda r: -r['seconds']):
            print(f"  {r['seconds']:.1f} s  {r['nodeid']}")


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench tests', description=__doc__.splitlines()[0])
    ap.add_argument('--run', action='store_true', help='run ./ft test first (with the arguments after --run)')
    ap.add_argument('--file', type=Path, default=DURATIONS, help=f'the durations file (default {DURATIONS})')
    ap.add_argument('--baseline', type=Path, help='an earlier durations file or JUnit XML report, side by side')
    ap.add_argument('--top', type=int, default=25, help='how many of the slowest tests to list (default 25)')
    args, pytest_args = ap.parse_known_args()
    if args.run:
        rc = subprocess.call([str(ROOT / 'ft'), 'test', '--record-durations', str(args.file), *pytest_args])
        print(f'./ft test exited {rc}')
    elif pytest_args:
        ap.error(f"unrecognized arguments: {' '.join(pytest_args)} (pytest's arguments go after --run)")
    if not args.file.is_file():
        raise SystemExit(f'./ft bench tests: error: no durations file {args.file}; run ./ft test first (or --run)')
    print_tables(load(args.file), args.top, load(args.baseline) if args.baseline else None)
    return 0


if __name__ == '__main__':
    sys.exit(main())
