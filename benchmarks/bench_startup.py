"""Benchmark: `./ft bag correct` as a whole process, and the share of it that is start-up
(./ft bench startup [--pulls 30] [--reps 5] [--baseline REV]).

A bag of --pulls sim pulls (2 s at 50 kHz each, made once and kept under runs/bench_startup/) is
corrected by `./ft bag correct BAG OUT` in a new process, --reps times. Printed: the median wall
time and how many times faster than real time; `./ft env` (the script's up-to-date checks and an
interpreter, nothing imported); the same correction in this process after a first call (the
arithmetic and the I/O alone); and the start-up share, 1 - in process / whole process.
Target: >= 150x real time as a whole process.

--baseline REV also checks REV out into a git worktree beside this one (sharing .venv, with its
own colcon build) and runs its `./ft bag correct` alternately with this one's, so both are
measured side by side in one run on the same machine state.
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / 'runs' / 'bench_startup'


def make_bag(n_pulls: int) -> tuple:
    """The bag of N pulls (made once) and its seconds of data."""
    from bench_bag import sim_pulls

    from bag_tools.core.convert import campaign_to_bag
    from bag_tools.core.daq import write_campaign
    bag = CACHE / f'bag_{n_pulls}'
    if not (bag / 'metadata.yaml').is_file():
        print(f'making a bag of {n_pulls} pulls under {CACHE} (once)', file=sys.stderr)
        shutil.rmtree(bag, ignore_errors=True)
        CACHE.mkdir(parents=True, exist_ok=True)
        pulls = sim_pulls(n_pulls)
        with tempfile.TemporaryDirectory() as tmp:
            write_campaign(Path(tmp) / 'campaign', pulls)
            campaign_to_bag(Path(tmp) / 'campaign', bag)
    from bag_tools.core.info import bag_info
    return bag, bag_info(bag)['duration_s']


def baseline_tree(rev: str) -> Path:
    """REV checked out beside this workspace, sharing its .venv; built once by its own ./ft."""
    tree = CACHE / f'baseline_{rev}'
    if not (tree / 'ft').is_file():
        subprocess.run(['git', 'worktree', 'add', '--detach', '--force', str(tree), rev], cwd=ROOT, check=True,
                       capture_output=True)
        (tree / '.venv').symlink_to(ROOT / '.venv')
        state = tree / '.ft'
        state.mkdir(exist_ok=True)
        # the stamps the older ./ft may keep, so that it takes the shared venv as set up
        digest = hashlib.sha256((tree / 'requirements.lock').read_bytes()
                                + (tree / 'tools' / 'fix_ros_wheels.py').read_bytes()).hexdigest()
        (state / 'venv.hash').write_text(digest + '\n')
        (state / 'venv.stamp').touch()
    print(f'building {rev} in {tree} (once)', file=sys.stderr)
    subprocess.run([str(tree / 'ft'), 'bag', '--help'], cwd=tree, check=True, capture_output=True)
    subprocess.run([str(tree / 'ft'), 'bag', 'info', str(tree / 'ft')], cwd=tree, capture_output=True)
    return tree


def whole(ft: Path, bag: Path, out: Path) -> float:
    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    subprocess.run([str(ft), 'bag', 'correct', str(bag), str(out)], check=True, capture_output=True)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench startup', description=__doc__.split('\n\n')[0])
    ap.add_argument('--pulls', type=int, default=30, help='pulls in the bag (2 s of data each; default 30)')
    ap.add_argument('--reps', type=int, default=5, help='whole-process runs of each (default 5)')
    ap.add_argument('--baseline', metavar='REV', help='also run REV (a commit) side by side, alternately')
    args = ap.parse_args()
    bag, seconds = make_bag(args.pulls)
    trees = {'this tree': ROOT}
    if args.baseline:
        trees[args.baseline] = baseline_tree(args.baseline)
    times = {name: [] for name in trees}
    env_times = {name: [] for name in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.reps):
            print(f'run {rep + 1} of {args.reps}', file=sys.stderr)
            for name, tree in trees.items():   # alternately: both see the same machine state
                times[name].append(whole(tree / 'ft', bag, Path(tmp) / 'out'))
                t0 = time.perf_counter()
                subprocess.run([str(tree / 'ft'), 'env'], check=True, capture_output=True)
                env_times[name].append(time.perf_counter() - t0)
        from force_correction.offline import correct
        correct(bag, Path(tmp) / 'first')          # the first call sets up the message types
        inproc = []
        for rep in range(args.reps):
            out = Path(tmp) / f'in{rep}'
            t0 = time.perf_counter()
            correct(bag, out)
            inproc.append(time.perf_counter() - t0)
            shutil.rmtree(out)
    t_in = statistics.median(inproc)
    print(f'`./ft bag correct` on {args.pulls} pulls ({seconds:.0f} s of data), median of {args.reps} '
          'whole-process runs (target >= 150x real time):')
    for name in trees:
        t = statistics.median(times[name])
        t_env = statistics.median(env_times[name])
        print(f'  {name:<12} {t:6.2f} s  {seconds / t:5.0f}x real time   `./ft env` {t_env:.2f} s'
              f'   start-up share {1 - t_in / t:4.0%}   (runs: {", ".join(f"{x:.2f}" for x in times[name])})')
    print(f'  in this process, after a first call: {t_in:.2f} s, {seconds / t_in:.0f}x real time '
          '(the arithmetic and the I/O alone)')
    if args.baseline:
        ratio = statistics.median(times[args.baseline]) / statistics.median(times['this tree'])
        print(f'  {args.baseline} / this tree: {ratio:.2f}x')
    return 0


if __name__ == '__main__':
    sys.exit(main())
