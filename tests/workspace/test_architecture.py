"""The architecture rules of ARCHITECTURE.md, enforced: the layering matrix, ROS-free cores, no
import cycles between modules, one home for shared facts, and ruff's rule set."""
from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / 'src'
TOOLS = ROOT / 'tools'

# package -> the workspace packages it may import (force_tester_msgs is a ROS message package)
LAYERS = {
    'force_tester_common': set(),
    'force_tester_sim': {'force_tester_common'},
    'bag_tools': {'force_tester_common'},
    'force_correction': {'force_tester_common', 'bag_tools'},
    'force_discovery': {'force_tester_common', 'force_tester_sim', 'force_correction', 'bag_tools'},
    'force_tester_monitor': {'force_tester_common', 'bag_tools'},
    'ft_cli': {'force_tester_common', 'force_tester_sim', 'bag_tools', 'force_correction',
               'force_discovery', 'force_tester_monitor'},
    'netlab': {'force_tester_common', 'bag_tools', 'ft_cli'},
}
# the network lab's hosts, links and sniffer: standard library only (a Dask cluster may use them as well)
NETLAB_STDLIB = ('netlab.netns', 'netlab.rtps_sniff')
ROS_MODULES = {'rclpy', 'rcl_interfaces', 'rosidl_runtime_py', 'force_tester_msgs', 'std_msgs',
               'diagnostic_msgs', 'builtin_interfaces'}
# ROS-free parts: what they may import from outside the workspace
PURE_THIRD_PARTY = {'numpy', 'scipy', 'yaml'}
BAG_THIRD_PARTY = PURE_THIRD_PARTY | {'rosbags', 'mcap', 'ruamel', 'nptdms', 'matplotlib',
                                      'lvm_read', 'asammdf', 'pyuff', 'pyarrow'}   # DAQ files (issue 26)
# the campaign engine: ROS-free, so the ROS-free parts may map their pulls with it; it alone imports Dask
ENGINE = 'force_tester_common.engine'
ENGINE_THIRD_PARTY = PURE_THIRD_PARTY | {'dask', 'distributed'}


def package_dirs() -> dict:
    out = {p.name: p / p.name for p in sorted(SRC.iterdir()) if (p / p.name / '__init__.py').is_file()}
    out['ft_cli'] = TOOLS / 'ft_cli'
    out['netlab'] = TOOLS / 'netlab'
    return out


def modules() -> dict:
    """module name -> source path, for every workspace module."""
    out = {}
    for d in package_dirs().values():
        for path in sorted(d.rglob('*.py')):
            rel = path.relative_to(d.parent).with_suffix('')
            parts = list(rel.parts)
            if parts[-1] == '__init__':
                parts.pop()
            out['.'.join(parts)] = path
    return out


MODULES = modules()


def imports_of(name: str, path: Path) -> list:
    """Absolute names of everything ``path`` imports, anywhere in the file (functions too)."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                mod = '.'.join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ''
            for a in node.names:  # `from pkg import submodule` imports the submodule
                sub = f'{mod}.{a.name}'
                out.append(sub if sub in MODULES else mod)
    return out


def is_pure(name: str) -> bool:
    """A ROS-free part: a package's core, and the offline tools and discovery built on cores."""
    parts = name.split('.')
    return 'core' in parts or parts[:2] == ['force_correction', 'offline'] or parts[0] == 'force_discovery' \
        or name == ENGINE


def test_every_package_is_known():
    assert set(package_dirs()) == set(LAYERS), 'add the new package to LAYERS and ARCHITECTURE.md'
    assert len(MODULES) > 40


@pytest.mark.parametrize('name', sorted(MODULES))
def test_layering(name):
    """A module imports only the workspace packages its package may import, and a ROS-free part
    imports no ROS and only the ROS-free parts of other packages."""
    pkg = name.split('.')[0]
    for mod in imports_of(name, MODULES[name]):
        top = mod.split('.')[0]
        if top in LAYERS and top != pkg:
            assert top in LAYERS[pkg], f'{name} imports {mod}: {pkg} may import {sorted(LAYERS[pkg])}'
        if not is_pure(name):
            continue
        assert top not in ROS_MODULES, f'{name} is ROS-free but imports {mod}'
        if top in LAYERS and top != pkg:
            assert is_pure(mod) or mod == 'bag_tools.cli', f'{name} imports {mod}, which is not ROS-free'
        if top not in LAYERS and top not in sys.stdlib_module_names:
            allowed = BAG_THIRD_PARTY if pkg in ('bag_tools', 'force_correction', 'force_discovery') \
                else ENGINE_THIRD_PARTY if name == ENGINE else PURE_THIRD_PARTY
            assert top in allowed, f'{name} imports {mod}; a ROS-free part may import {sorted(allowed)}'


def test_only_the_engine_imports_dask():
    for name, path in MODULES.items():
        if name != ENGINE:
            bad = [m for m in imports_of(name, path) if m.split('.')[0] in ('dask', 'distributed')]
            assert not bad, f'{name} imports {bad[0]}; campaign work goes through {ENGINE}'


def test_the_network_lab_imports_only_the_standard_library():
    for name in NETLAB_STDLIB:
        for mod in imports_of(name, MODULES[name]):
            assert mod.split('.')[0] in sys.stdlib_module_names or mod.startswith('netlab.'), f'{name} imports {mod}'


def test_shared_facts_import_only_numpy():
    for name, path in MODULES.items():
        if name.startswith('force_tester_common.core'):
            for mod in imports_of(name, path):
                top = mod.split('.')[0]
                assert top in sys.stdlib_module_names or top == 'numpy' or \
                    mod.startswith('force_tester_common.core'), f'{name} imports {mod}'


def test_no_import_cycles():
    graph = {name: {m for m in imports_of(name, path) if m in MODULES and m != name}
             for name, path in MODULES.items()}
    index, low, stack, on, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert cycles == []


def test_importing_cores_loads_no_rclpy():
    code = ('import importlib, sys\n'
            f'for m in {sorted(n for n in MODULES if is_pure(n))!r}: importlib.import_module(m)\n'
            f'bad = sorted(m for m in sys.modules if m.split(".")[0] in {sorted(ROS_MODULES)!r})\n'
            'print(bad)\nsys.exit(1 if bad else 0)\n')
    paths = [str(d.parent) for d in package_dirs().values()]
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         env={'PYTHONPATH': ':'.join(paths), 'PATH': '/usr/bin:/bin',
                              '_ROS_WHEELS_BOOTSTRAP_COMPLETE': '1'})
    assert out.returncode == 0, out.stdout + out.stderr


# ------------------------------------------------------------------ one home for shared facts
FACTS = ROOT / 'src' / 'force_tester_common' / 'force_tester_common' / 'core'
# numbers that are facts with a home in force_tester_common.core; a literal copy elsewhere is a defect
FACT_NUMBERS = {1.152: 'MASS_KG', 4.4482216152605: 'LBF_N', 0.3048: 'FT_M', 9.80665: 'G_M_S2',
                1e9: 'NS_PER_S', 0.5e9: 'NS_PER_S'}
FACT_PATTERNS = {r'\bwindow\b\W{1,4}140\b': 'WINDOW', r'\bmax_pending\b\W{1,4}500\b': 'MAX_PENDING',
                 r"\bPULL_(START|END)\s*=": 'PULL_START/PULL_END'}


def _code_files():
    for base in (ROOT / 'src', ROOT / 'tools', ROOT / 'benchmarks'):
        for path in sorted(base.rglob('*.py')):
            if FACTS not in path.parents and 'install' not in path.parts:
                yield path


def test_no_literal_copies_of_shared_facts():
    found = []
    for path in _code_files():
        with tokenize.open(path) as f:
            for tok in tokenize.generate_tokens(f.readline):
                if tok.type == tokenize.NUMBER:
                    value = ast.literal_eval(tok.string)
                    if isinstance(value, (int, float)) and value in FACT_NUMBERS:
                        found.append(f'{path.relative_to(ROOT)}:{tok.start[0]}: {tok.string} '
                                     f'(import {FACT_NUMBERS[value]})')
        text = path.read_text()
        for pattern, fact in FACT_PATTERNS.items():
            for m in re.finditer(pattern, text):
                found.append(f'{path.relative_to(ROOT)}:{text.count(chr(10), 0, m.start()) + 1}: '
                             f'{m.group(0)!r} (import {fact})')
    assert not found, '\n'.join(found)


def test_pull_event_codes_match_the_message_definition():
    from force_tester_common.core import channels
    text = (SRC / 'force_tester_msgs' / 'msg' / 'PullEvent.msg').read_text()
    codes = dict(re.findall(r'^uint8 (START|END)=(\d+)', text, re.M))
    assert {'START': channels.PULL_START, 'END': channels.PULL_END} == \
        {k: int(v) for k, v in codes.items()}


def test_pull_score_status_codes_match_the_message_definition():
    from force_tester_common.core import scores
    text = (SRC / 'force_tester_msgs' / 'msg' / 'PullScore.msg').read_text()
    codes = {k: int(v) for k, v in re.findall(r'^uint8 ([A-Z]+)=(\d+)', text, re.M)}
    assert codes == {name: code for code, name in scores.PULL_STATUS_NAMES.items()}


def test_ruff():
    ruff = shutil.which('ruff') or str(Path(sys.executable).with_name('ruff'))
    if not Path(ruff).exists():
        pytest.fail('ruff is not installed (requirements.txt lists it)')
    out = subprocess.run([ruff, 'check', '--no-cache', '--output-format', 'concise', str(ROOT)],
                         capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr


# ------------------------------------------------------------------ one exception type per package (rule 5)
PACKAGE_ERRORS = {'force_tester_sim': {'SimError'}, 'bag_tools': {'BagError'}, 'force_correction': {'CorrectionError'},
                  'force_discovery': {'DiscoveryError'}, 'force_tester_monitor': {'MonitorError'},
                  'force_tester_common': {'ParameterError', 'EngineError'}}
# exceptions that never leave their package's code paths: signals caught by the caller that takes another way
INTERNAL_SIGNALS = {'FastPathError': 'bag_tools.core.fastcdr: the fast path does not apply; the generic path runs',
                    '_TornChunk': 'bag_tools.core.reindex: a torn chunk ends the scan'}


def test_one_exception_type_per_package():
    found = {}
    for name, path in MODULES.items():
        pkg = name.split('.')[0]
        if pkg not in PACKAGE_ERRORS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef) and any(
                    ast.unparse(b).split('.')[-1].endswith(('Error', 'Exception')) for b in node.bases):
                found.setdefault(pkg, set()).add(node.name)
    for pkg, names in found.items():
        assert names - set(INTERNAL_SIGNALS) == PACKAGE_ERRORS[pkg], \
            f'{pkg} defines {sorted(names)}; expected {sorted(PACKAGE_ERRORS[pkg])} (ARCHITECTURE.md rule 5)'


# ------------------------------------------------------------------ tests mirror the packages (rule 6)
def test_tests_mirror_the_packages():
    src_packages = {p for p in package_dirs() if (SRC / p).is_dir()}
    test_dirs = {p.name for p in (ROOT / 'tests').iterdir() if p.is_dir() and p.name != '__pycache__'}
    assert src_packages - {'force_tester_msgs'} <= test_dirs, 'each package has its tests/<package>/'
    assert test_dirs - src_packages == {'workspace', 'independent'}, \
        'a tests/ folder is a package, workspace/, or independent/ (the generator written apart, tests/independent)'


def _private_imports(path: Path) -> list:
    """``from <workspace module> import _name`` in ``path``: a private used outside its module."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split('.')[0] in LAYERS:
            out += [f'{path.relative_to(ROOT)}:{node.lineno}: {a.name} from {node.module}'
                    for a in node.names if a.name.startswith('_') and not a.name.startswith('__')]
    return out


# packages being split by their own change, whose private imports and dead code are left to it (none now)
SPLITTING: tuple = ()


def test_privates_stay_in_their_module():
    """Rule 6's public seams, and one home for code: a name another module or a test imports is public."""
    paths = [p for n, p in MODULES.items() if n.split('.')[0] not in SPLITTING]
    paths += [p for p in sorted((ROOT / 'tests').rglob('*.py')) if not set(SPLITTING) & set(p.parts)]
    paths += sorted((ROOT / 'benchmarks').glob('*.py'))
    found = [line for p in paths for line in _private_imports(p)]
    assert not found, '\n'.join(found)


# ------------------------------------------------------------------ no dead code
def _words(paths) -> dict:
    """How often each identifier occurs in ``paths`` (``__all__`` lists left out: exporting is not using)."""
    counts: dict = {}
    for p in paths:
        text = re.sub(r'__all__\s*=\s*\[[^\]]*\]', '', p.read_text(), flags=re.S)
        for w in re.findall(r'[A-Za-z_]\w*', text):
            counts[w] = counts.get(w, 0) + 1
    return counts


@pytest.mark.slow
def test_every_definition_is_used():
    """A top-level function or class, or a method, whose name occurs nowhere but in its own definition
    (anywhere in src/, tools/, tests/, benchmarks/ or a setup.py) is dead. Callbacks a library calls by
    name (``on_*``) and dunders are not counted."""
    everywhere = [p for base in ('src', 'tools', 'tests', 'benchmarks') for p in sorted((ROOT / base).rglob('*.py'))
                  if 'node_modules' not in p.parts]
    words = _words(everywhere)
    dead = []
    for name, path in MODULES.items():
        if name.split('.')[0] in SPLITTING:
            continue
        tree = ast.parse(path.read_text())
        for node in tree.body:
            defs = [node] if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) else []
            if isinstance(node, ast.ClassDef):
                defs += [n for n in node.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
            for d in defs:
                if d.name.startswith(('__', 'on_')):
                    continue
                own = len(re.findall(rf'\b{d.name}\b', ast.get_source_segment(path.read_text(), d) or ''))
                if words.get(d.name, 0) - own <= 0:
                    dead.append(f'{path.relative_to(ROOT)}:{d.lineno}: {d.name}')
    assert not dead, 'never used:\n' + '\n'.join(dead)
