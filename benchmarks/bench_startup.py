"""Benchmark: the set-up from nothing, and `./ft bag correct` as a whole process with the share of it that is
start-up (./ft bench startup [--pulls 30] [--reps 5] [--baseline REV] [--setup N]).

A bag of --pulls sim pulls (2 s at 50 kHz each, made once and kept under runs/bench_startup/) is
corrected by `./ft bag correct BAG OUT` in a new process, --reps times. Printed: the median wall
time and how many times faster than real time; `./ft env` (the script's up-to-date checks and an
interpreter, nothing imported); the same correction in this process after a first call (the
arithmetic and the I/O alone); and the start-up share, 1 - in process / whole process.
Target: >= 150x real time as a whole process. Each run's CPU (user + system of ./ft and what it ran) is printed
too: on a shared machine it moves less with the load than the wall time.

--baseline REV also checks REV out into a git worktree under /tmp (sharing .venv, with its own colcon build)
and runs its `./ft bag correct` alternately with this one's, so both are measured side by side in one run on the
same machine state, and prints the ratios.

--stages: where a whole `./ft bag correct` goes, this tree only, each step --reps times, alternately: the whole
command; the same without bash's `./ft` (`python -m ft_cli`); its imports alone; numpy alone; the interpreter alone
(`-c pass`, with the ROS wheels' .pth hook); `./ft env`. Wall and CPU, min and median.

--setup N: the set-up from nothing, N times for each tree (this one's HEAD and REV, alternately), each in a new git
worktree under /tmp with no .venv, install/ or .ft/: the venv step (`python -m ft_cli.bootstrap venv`, what ./ft
runs first: making .venv and installing the lock) and the build step (`./ft` up to its first command: colcon).
The package caches (pip's, uv's) are whatever the machine has: the first of the N runs warms them; the table
gives every run. Target: <= 90 s in all.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import re
import resource
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
    """REV checked out under /tmp, sharing this workspace's .venv; built once by its own ./ft."""
    sha = subprocess.run(['git', 'rev-parse', '--short', rev], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout.strip()
    tree = Path(tempfile.gettempdir()) / f'ft_baseline_{sha}'
    if not (tree / 'ft').is_file():
        subprocess.run(['git', 'worktree', 'add', '--detach', '--force', str(tree), sha], cwd=ROOT, check=True,
                       capture_output=True)
        (tree / '.venv').symlink_to((ROOT / '.venv').resolve())
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


def setup_once(rev: str, into: Path) -> tuple:
    """(venv s, build s) of REV set up from nothing in a new git worktree INTO (removed afterwards)."""
    subprocess.run(['git', 'worktree', 'add', '--detach', '--force', str(into), rev], cwd=ROOT, check=True,
                   capture_output=True)
    try:
        (into / '.ft').mkdir(exist_ok=True)
        env = {k: v for k, v in os.environ.items()
               if k not in ('PYTHONPATH', 'VIRTUAL_ENV', 'AMENT_PREFIX_PATH', 'CMAKE_PREFIX_PATH', 'LD_LIBRARY_PATH',
                            'COLCON_PREFIX_PATH', '_ROS_WHEELS_BOOTSTRAP_COMPLETE')}
        env['PATH'] = os.pathsep.join(d for d in env['PATH'].split(os.pathsep) if '.venv' not in d)
        python = shutil.which('python3', path=env['PATH'])
        t0 = time.perf_counter()
        subprocess.run([python, '-m', 'ft_cli.bootstrap', 'venv', '--venv', str(into / '.venv'), '--lock',
                        str(into / 'requirements.lock'), '--log', str(into / '.ft' / 'venv.log'), '--mend',
                        str(into / 'tools' / 'fix_ros_wheels.py')], cwd=into, check=True,
                       env=dict(env, PYTHONPATH=str(into / 'tools')))
        t_venv = time.perf_counter() - t0
        (into / '.ft' / 'venv.stamp').touch()       # what ./ft does after the step
        t0 = time.perf_counter()
        subprocess.run([str(into / 'ft'), 'bag', 'info', str(into / 'no-such-bag')], cwd=into, env=env,
                       capture_output=True)           # set up, then a one-line error: the set-up is what is timed
        t_build = time.perf_counter() - t0
        keep = CACHE / 'setup_logs' / f'{rev}_{time.strftime("%H%M%S")}'   # the logs outlive the tree: the profile
        keep.mkdir(parents=True, exist_ok=True)
        for log in (into / '.ft').glob('*.log'):
            shutil.copy2(log, keep / log.name)
        if not (into / 'install' / 'setup.bash').is_file():
            raise SystemExit(f'{rev}: the build failed (log: {keep / "build.log"})')
        steps = re.findall(r'^Finished <<< (\S+) \[([\d.]+)s\]', (keep / 'build.log').read_text(), re.M)
        print(f'  {rev}: venv {t_venv:.1f} s, build {t_build:.1f} s (colcon: '
              f'{", ".join(f"{name} {s}" for name, s in steps)}; logs: {keep})', file=sys.stderr)
        return t_venv, t_build
    finally:
        subprocess.run(['git', 'worktree', 'remove', '--force', str(into)], cwd=ROOT, capture_output=True)
        shutil.rmtree(into, ignore_errors=True)


def bench_setup(revs: dict, runs: int) -> None:
    """The set-up from nothing of each tree, alternately, RUNS times; the ratios of the last runs' medians."""
    got = {name: [] for name in revs}
    for k in range(runs):
        for name, rev in revs.items():
            print(f'set-up {k + 1} of {runs}: {name} ({rev})', file=sys.stderr)
            got[name].append(setup_once(rev, Path(tempfile.gettempdir()) / f'ft_setup_{rev}'))
    print(f'set-up from nothing (empty venv, no install/), {runs} run(s) each, alternately; the first warms the '
          'package caches (target <= 90 s):')
    for name, rows in got.items():
        cells = '   '.join(f'venv {v:5.1f} s + build {b:5.1f} s = {v + b:5.1f} s' for v, b in rows)
        print(f'  {name:<12} {cells}')
    if len(got) == 2 and runs > 1:
        (a, ra), (b, rb) = got.items()
        def ratio(pick):
            return statistics.median(pick(r) for r in rb[1:]) / statistics.median(pick(r) for r in ra[1:])
        print(f'  {b} / {a}, warm runs, median: venv {ratio(lambda r: r[0]):.1f}x, build '
              f'{ratio(lambda r: r[1]):.1f}x, all {ratio(sum):.1f}x')


def whole(ft: Path, bag: Path, out: Path) -> tuple:
    """(wall, CPU: user + system of ./ft and everything it ran) of one `./ft bag correct`, s."""
    shutil.rmtree(out, ignore_errors=True)
    return run_once([str(ft), 'bag', 'correct', str(bag), str(out)])


def run_once(cmd: list) -> tuple:
    """(wall, CPU of it and its children) of one command, s."""
    r0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, cwd=ROOT)
    wall, r1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime


def bench_stages(bag: Path, reps: int) -> None:
    """The steps of a whole `./ft bag correct` (see --stages), each reps times, alternately."""
    py = sys.executable   # the venv's, run under ./ft
    imports = 'import ft_cli.main, force_correction.offline.cli, force_correction.offline.pipeline, ' \
              'force_correction.offline.bag, bag_tools.core.sources'
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / 'out'
        steps = {'./ft bag correct': [str(ROOT / 'ft'), 'bag', 'correct', str(bag), str(out)],
                 'python -m ft_cli bag correct': [py, '-m', 'ft_cli', 'bag', 'correct', str(bag), str(out)],
                 'its imports alone': [py, '-c', imports],
                 'numpy alone': [py, '-c', 'import numpy'],
                 'the interpreter (-c pass)': [py, '-c', 'pass'],
                 './ft env': [str(ROOT / 'ft'), 'env']}
        got = {k: [] for k in steps}
        for rep in range(reps):
            print(f'stages: run {rep + 1} of {reps}', file=sys.stderr)
            for name, cmd in steps.items():
                shutil.rmtree(out, ignore_errors=True)
                got[name].append(run_once(cmd))
    print(f'the steps of `./ft bag correct` ({reps} runs each, alternately): wall min / median, CPU min / median, s')
    for name, runs in got.items():
        w, c = [r[0] for r in runs], [r[1] for r in runs]
        print(f'  {name:<30} {min(w):.3f} / {statistics.median(w):.3f}   {min(c):.3f} / {statistics.median(c):.3f}')


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench startup', description=__doc__.split('\n\n')[0])
    ap.add_argument('--pulls', type=int, default=30, help='pulls in the bag (2 s of data each; default 30)')
    ap.add_argument('--reps', type=int, default=5, help='whole-process runs of each (default 5)')
    ap.add_argument('--baseline', metavar='REV', help='also run REV (a commit) side by side, alternately')
    ap.add_argument('--setup', type=int, default=0, metavar='N',
                    help='also time the set-up from nothing N times each (this HEAD and --baseline REV)')
    ap.add_argument('--stages', action='store_true',
                    help="also time the steps of a whole `./ft bag correct`: bash's ./ft, imports, numpy, Python")
    args = ap.parse_args()
    if args.setup:
        head = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, check=True, capture_output=True,
                              text=True).stdout.strip()
        bench_setup({'this HEAD': head, **({args.baseline: args.baseline} if args.baseline else {})}, args.setup)
    bag, seconds = make_bag(args.pulls)
    if args.stages:
        bench_stages(bag, args.reps)
    trees = {'this tree': ROOT}
    if args.baseline:
        trees[args.baseline] = baseline_tree(args.baseline)
    times = {name: [] for name in trees}
    cpu = {name: [] for name in trees}
    env_times = {name: [] for name in trees}
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.reps):
            print(f'run {rep + 1} of {args.reps}', file=sys.stderr)
            for name, tree in trees.items():   # alternately: both see the same machine state
                wall, used = whole(tree / 'ft', bag, Path(tmp) / 'out')
                times[name].append(wall)
                cpu[name].append(used)
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
        print(f'  {"":<12} CPU (user + system, the whole process) median {statistics.median(cpu[name]):.3f} s, '
              f'min {min(cpu[name]):.3f} s')
    print(f'  in this process, after a first call: {t_in:.2f} s, {seconds / t_in:.0f}x real time '
          '(the arithmetic and the I/O alone)')
    if args.baseline:
        ratio = statistics.median(times[args.baseline]) / statistics.median(times['this tree'])
        print(f'  {args.baseline} / this tree: {ratio:.2f}x wall, '
              f'{statistics.median(cpu[args.baseline]) / statistics.median(cpu["this tree"]):.2f}x CPU (medians)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
