"""./ft test, run, env and bench: the workspace's own tools."""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
from pathlib import Path

from ..paths import ROOT, executable

DURATIONS = ROOT / '.ft' / 'test-durations.json'   # each test's time in the last ./ft test (tests/conftest.py)

ENV_VARS = (
    'VIRTUAL_ENV', 'PATH', 'LD_LIBRARY_PATH', 'PYTHONPATH', 'AMENT_PREFIX_PATH',
    'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'RMW_IMPLEMENTATION', '_ROS_WHEELS_BOOTSTRAP_COMPLETE',
    'OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_',
)


class Test:
    """./ft test: the whole suite on every core (pytest-xdist); --fast: the inner loop (docs/tests.md)."""
    PASSTHROUGH = 'pytest_args'

    @staticmethod
    def add_arguments(p):
        p.description = ("Run the test suite with pytest on pytest-xdist's workers (one per core and one more; "
                         'FT_TEST_WORKERS sets another number, -n 0 runs in this process). Each test\'s time is '
                         f'written to {DURATIONS.relative_to(ROOT)} (./ft bench tests prints the table). Other '
                         'arguments go to pytest.')
        p.add_argument('--fast', action='store_true',
                       help='only the tests not marked slow (each under a few seconds): the inner loop, <= 3 min')
        p.add_argument('pytest_args', nargs=argparse.REMAINDER)

    @staticmethod
    def run(args) -> int:
        rc = subprocess.call(pytest_command(args.pytest_args, args.fast), cwd=ROOT)
        if rc == 5:
            print('ft: error: pytest collected no tests', file=sys.stderr)
            return 1
        return rc


def _has_option(args: list, *names: str) -> bool:
    """Whether ARGS give one of the options NAMES ('-n 2', '-n2', '--dist=load', ...)."""
    return any(a == n or a.startswith(n + '=') or (len(n) == 2 and a.startswith(n)) for a in args for n in names)


def default_workers(fast: bool = False) -> int:
    """One pytest-xdist worker per core, and for the whole suite two more: its ROS graphs, network labs, browser and
    Dask clusters wait on real time and on other processes, and the spare workers keep the cores busy meanwhile
    (docs/tests.md, on 2 cores, the same tree back to back on an idle machine: 12 min 38 s with 3 workers, 11 min 31 s
    with 4; the fast tier, which waits on nothing, 1.9 min with 2, 2.0 with 3)."""
    return len(os.sched_getaffinity(0)) + (0 if fast else 2)


def pytest_command(args: list, fast: bool = False) -> list:
    """The pytest command line of ./ft test ARGS: the tests folder unless ARGS name tests, the workers and their
    distribution unless ARGS set them, the fast tier's marker expression (joined to one of ARGS), and the durations
    file."""
    args = list(args)
    chosen = any(Path(a.split('::')[0]).exists() for a in args if not a.startswith('-'))
    if fast:
        if '-m' in args:
            i = args.index('-m') + 1
            args[i] = f'not slow and ({args[i]})'
        else:
            args += ['-m', 'not slow']
    if 'no:xdist' not in args and not _has_option(args, '-n', '--numprocesses'):
        args += ['-n', os.environ.get('FT_TEST_WORKERS', str(default_workers(fast)))]
    if 'no:xdist' not in args and not _has_option(args, '--dist'):
        args += ['--dist', 'loadgroup']
    if not _has_option(args, '--record-durations'):
        args += ['--record-durations', str(DURATIONS)]
    return [sys.executable, '-m', 'pytest', *([] if chosen else [str(ROOT / 'tests')]), *args]


class Run:
    PASSTHROUGH = 'args'

    @staticmethod
    def add_arguments(p):
        p.add_argument('package')
        p.add_argument('executable')
        p.add_argument('args', nargs=argparse.REMAINDER)

    @staticmethod
    def run(args) -> int:
        exe = executable(args.package, args.executable)
        os.execv(str(exe), [str(exe), *args.args])
        return 0  # not reached


class Env:

    @staticmethod
    def add_arguments(p):
        pass

    @staticmethod
    def run(args) -> int:
        for name in ENV_VARS:
            if name in os.environ:
                print(f'export {name}={shlex.quote(os.environ[name])}')
        if not (ROOT / 'install' / 'setup.bash').is_file() or not (ROOT / '.venv' / 'bin' / 'python').exists():
            print('ft: .venv or install/ is not set up yet (the first ./ft demo or ./ft test does it): '
                  'these exports will work once it is', file=sys.stderr)
        return 0


class Wheels:
    """./ft wheels DIR: what an air-gapped machine needs, carried in one folder."""

    @staticmethod
    def add_arguments(p):
        p.description = ('Download every package requirements.lock pins, with its hashes checked, the tools that '
                         "build the lock's few source packages, and the npm packages of the Foxglove client and "
                         'the viewer, into DIR. '
                         'Carry DIR and the workspace to the machine with no network and run FT_WHEELS=DIR ./ft demo '
                         '(or ./ft test) there: it installs from DIR alone.')
        p.add_argument('dir', type=Path, help='the folder to fill (made if missing)')

    @staticmethod
    def run(args) -> int:
        from ..bootstrap import SetupError, download
        try:
            n_files = download(ROOT / 'requirements.lock', args.dir, ROOT / '.ft' / 'wheels.log',
                               (ROOT / 'tools' / 'foxglove_client', ROOT / 'tools' / 'viewer'))
        except SetupError as e:
            print(f'ft: error: {e}', file=sys.stderr)
            return 1
        print(f'ft: {n_files} files in {args.dir}; on the machine with no network: FT_WHEELS={args.dir} ./ft demo')
        return 0


class Bench:
    PASSTHROUGH = 'bench_args'

    @staticmethod
    def add_arguments(p):
        p.add_argument('name')
        p.add_argument('bench_args', nargs=argparse.REMAINDER)

    @staticmethod
    def run(args) -> int:
        script = ROOT / 'benchmarks' / f'bench_{args.name}.py'
        if not script.is_file():
            have = sorted(p.stem.removeprefix('bench_') for p in (ROOT / 'benchmarks').glob('bench_*.py'))
            raise SystemExit(f"ft: error: no benchmark {args.name!r}; expected one of {', '.join(have)}")
        return subprocess.call([sys.executable, str(script), *args.bench_args], cwd=ROOT)
