"""The ROS-free cores stay ROS-free; every package keeps the core / conversions / node split."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
CORE_PACKAGES = ['force_tester_sim', 'force_correction', 'bag_tools']
ROS_MODULES = ('rclpy', 'rosidl_runtime_py', 'force_tester_msgs', 'std_msgs', 'diagnostic_msgs',
               'builtin_interfaces')
ALLOWED = ('force_tester_common.channels',)  # pure data, no ROS import (checked below)


@pytest.mark.parametrize('package', CORE_PACKAGES)
def test_core_sources_import_no_ros(package):
    core = SRC / package / package / 'core'
    files = sorted(core.glob('*.py'))
    assert len(files) >= 2, f'{core} holds no modules'
    for path in files:
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or '']
            for name in names:
                assert name.split('.')[0] not in ROS_MODULES, f'{path.name} imports {name}'
                if name.startswith('force_tester_common'):
                    assert name in ALLOWED, f'{path.name} imports {name}'


def test_allowed_shared_modules_import_nothing():
    for mod in ALLOWED:
        path = SRC / mod.split('.')[0] / (mod.replace('.', '/') + '.py')
        tree = ast.parse(path.read_text(), str(path))
        assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], path


@pytest.mark.parametrize('package', CORE_PACKAGES)
def test_importing_core_loads_no_rclpy(package):
    code = (f'import importlib, pkgutil, sys\n'
            f'import {package}.core as core\n'
            f'mods = [m.name for m in pkgutil.iter_modules(core.__path__)]\n'
            f'for m in mods: importlib.import_module("{package}.core." + m)\n'
            f'bad = sorted(m for m in sys.modules if m.split(".")[0] in {ROS_MODULES!r})\n'
            f'print(len(mods), bad)\n'
            f'sys.exit(1 if bad else 0)\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         env={'PYTHONPATH': f"{SRC / package}:{SRC / 'force_tester_common'}:{SRC / 'force_correction'}",
                              'PATH': '/usr/bin:/bin',
                              '_ROS_WHEELS_BOOTSTRAP_COMPLETE': '1'})
    assert out.returncode == 0, out.stdout + out.stderr
    assert int(out.stdout.split()[0]) >= 2
