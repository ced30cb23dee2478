"""./ft test, run, env and bench: the workspace's own tools."""
from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
from pathlib import Path

from ..paths import ROOT, executable

ENV_VARS = (
    'VIRTUAL_ENV', 'PATH', 'LD_LIBRARY_PATH', 'PYTHONPATH', 'AMENT_PREFIX_PATH',
    'CMAKE_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'RMW_IMPLEMENTATION', '_ROS_WHEELS_BOOTSTRAP_COMPLETE',
    'OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS',
)


class Test:
    PASSTHROUGH = 'pytest_args'

    @staticmethod
    def add_arguments(p):
        p.add_argument('pytest_args', nargs=argparse.REMAINDER)

    @staticmethod
    def run(args) -> int:
        chosen = any(Path(a.split('::')[0]).exists() for a in args.pytest_args if not a.startswith('-'))
        cmd = [sys.executable, '-m', 'pytest', *([] if chosen else [str(ROOT / 'tests')]), *args.pytest_args]
        rc = subprocess.call(cmd, cwd=ROOT)
        if rc == 5:
            print('ft: error: pytest collected no tests', file=sys.stderr)
            return 1
        return rc


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
