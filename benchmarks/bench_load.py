"""Load test: the DDS graph and node tests, N times in a row, next to CPU hogs.

    ./ft bench load [--runs 3] [--hogs 2] [-- PYTEST_ARGS]

Each run is a fresh pytest process over tests/workspace/test_graph.py, test_live_runs.py and
tests/force_correction/test_nodes.py (or the tests given after --), while --hogs processes spin a
core each. Prints per run the outcome, the time and the failing tests; exits 1 if any run failed.
Tests that pass here wait on conditions, not on timers.
"""
from __future__ import annotations

import argparse
import multiprocessing
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_TESTS = ['tests/workspace/test_graph.py', 'tests/workspace/test_live_runs.py',
                 'tests/force_correction/test_nodes.py']


def hog(stop) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench load', description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=3, help='pytest runs in a row (default 3)')
    ap.add_argument('--hogs', type=int, default=2, help='busy processes next to the tests (default 2)')
    ap.add_argument('pytest_args', nargs=argparse.REMAINDER, help='tests and pytest options (after --)')
    args = ap.parse_args()
    tests = [a for a in args.pytest_args if a != '--'] or DEFAULT_TESTS
    stop = multiprocessing.Event()
    hogs = [multiprocessing.Process(target=hog, args=(stop,), daemon=True) for _ in range(args.hogs)]
    for h in hogs:
        h.start()
    failed_runs = 0
    try:
        for run in range(1, args.runs + 1):
            t0 = time.monotonic()
            res = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider', *tests],
                                 cwd=ROOT, capture_output=True, text=True)
            took = time.monotonic() - t0
            summary = (res.stdout.strip().splitlines() or ['(no output)'])[-1]
            failures = re.findall(r'^(?:FAILED|ERROR) (\S+)', res.stdout, re.M)
            failed_runs += bool(res.returncode)
            print(f'run {run}/{args.runs} with {args.hogs} CPU hog(s): {"ok" if not res.returncode else "FAILED"} '
                  f'in {took:.0f} s: {summary}', flush=True)
            for f in failures:
                print(f'    {f}', flush=True)
    finally:
        stop.set()
        for h in hogs:
            h.join(timeout=5)
    print(f'{args.runs - failed_runs} of {args.runs} run(s) passed')
    return 1 if failed_runs else 0


if __name__ == '__main__':
    sys.exit(main())
