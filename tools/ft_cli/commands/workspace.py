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
)


class Test:
    NAME = 'test'
    HELP = 'run the test suite (pytest); extra arguments go to pytest'
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
    NAME = 'run'
    HELP = 'run a node like `ros2 run PACKAGE EXECUTABLE [--ros-args ...]`'
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
    NAME = 'env'
    HELP = 'print the environment as shell exports: eval "$(./ft env)"'

    @staticmethod
    def add_arguments(p):
        pass

    @staticmethod
    def run(args) -> int:
        for name in ENV_VARS:
            if name in os.environ:
                print(f'export {name}={shlex.quote(os.environ[name])}')
        return 0


class Bench:
    NAME = 'bench'
    HELP = 'run a benchmark script from benchmarks/ (e.g. ./ft bench correction)'
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
