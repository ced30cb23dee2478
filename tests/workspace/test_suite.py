"""The suite's own machinery (tests/conftest.py, ./ft test, ./ft bench tests): tiers, workers' ROS domains, the
durations record, and no silent skips under CI=true."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import conftest
import pytest

from ft_cli.commands.workspace import pytest_command

ROOT = Path(__file__).resolve().parents[2]

SAMPLE = '''
import pytest
from force_tester_sim.core.campaign import generate_campaign
from force_tester_sim.core.params import load_rig

def test_passes():
    assert True

def test_skips():
    pytest.skip('nothing to run here')

def test_talks_over_dds(ros_domain):
    import os
    assert os.environ['ROS_DOMAIN_ID'] == str(ros_domain)

def test_makes_a_campaign():
    assert len(generate_campaign(load_rig(), (3,), 1, 0)) == 1

@pytest.mark.slow
def test_marked_slow():
    assert True
'''


GROUPED = '''
import os
import pytest

@pytest.fixture(scope='module')
def shared():
    return object()

def _note(name):
    with open(os.path.join(os.environ['WORKERS_DIR'], name), 'a') as f:
        f.write(os.environ['PYTEST_XDIST_WORKER'] + '\\n')

@pytest.mark.parametrize('i', range(6))
def test_shares_the_module_fixture(shared, i):
    _note('grouped')

@pytest.mark.parametrize('i', range(6))
def test_on_its_own(i):
    _note('alone')
'''


CLUSTER = '''
import os
import pytest
from pathlib import Path

@pytest.fixture(scope='module')
def children():   # this process's spawned children: Dask's worker processes (not multiprocessing's resource tracker)
    me = os.getpid()
    kids = lambda: [c for t in Path(f'/proc/{me}/task').glob('*') for c in (t / 'children').read_text().split()]
    return lambda: [c for c in kids() if b'spawn_main' in Path(f'/proc/{c}/cmdline').read_bytes()]

def test_1_starts_the_embedded_cluster(children, monkeypatch):
    from force_tester_common.engine import SCHEDULER_ENV, map_pulls
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)
    assert map_pulls(abs, [-1, 2]).scheduler.startswith('embedded LocalCluster') and children()

def test_2_finds_no_process_left(children):
    assert children() == []
'''


def run_inner(folder: Path, *args: str, ci: bool) -> subprocess.CompletedProcess:
    """pytest in FOLDER (SAMPLE, GROUPED and CLUSTER written there) with this suite's conftest.py as a plugin."""
    (folder / 'test_sample.py').write_text(SAMPLE)
    (folder / 'test_grouped.py').write_text(GROUPED)
    (folder / 'test_cluster.py').write_text(CLUSTER)
    env = {**os.environ, 'PYTHONPATH': f"{ROOT / 'tests'}:{os.environ.get('PYTHONPATH', '')}",
           'WORKERS_DIR': str(folder), 'CI': 'true' if ci else 'false'}
    for k in ('PYTEST_XDIST_WORKER', 'PYTEST_XDIST_WORKER_COUNT'):
        env.pop(k, None)
    # hypothesis's plugin left out: no inner test uses it, and it costs each of the 4 inner processes 0.75 CPU-s
    return subprocess.run([sys.executable, '-m', 'pytest', '-p', 'conftest', '-p', 'no:cacheprovider',
                           '-p', 'no:hypothesispytest', '--rootdir', str(folder), *args], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope='module')
def inner_runs(tmp_path_factory):
    """Two inner runs, each paying pytest's and conftest's start-up once: SAMPLE and GROUPED as ./ft test runs
    them (`-n 2 --dist loadgroup`, CI unset, the durations recorded), and the fast tier of SAMPLE and CLUSTER
    under CI=true, in one process."""
    folder = tmp_path_factory.mktemp('inner')
    out = folder / 'durations.json'
    quiet = run_inner(folder, '-n', '2', '--dist', 'loadgroup', '--record-durations', str(out), 'test_sample.py',
                      'test_grouped.py', ci=False)
    ci_fast = run_inner(folder, '-m', 'not slow', 'test_sample.py', 'test_cluster.py', ci=True)
    return {'folder': folder, 'quiet': quiet, 'ci_fast': ci_fast, 'durations': out}


@pytest.mark.slow
def test_a_skip_fails_the_run_under_ci_unless_allowed(inner_runs):
    quiet, ci = inner_runs['quiet'], inner_runs['ci_fast']
    assert quiet.returncode == 0, quiet.stdout[-2000:]
    assert ci.returncode == 1, ci.stdout[-2000:]
    assert 'not in tests/skips_allowed.txt' in ci.stdout and 'test_skips: nothing to run here' in ci.stdout
    # the durations record: every test, its kind and tier, the seconds spent making its campaign
    rec = {r['nodeid'].split('::')[-1]: r for r in json.loads(inner_runs['durations'].read_text())
           if r['nodeid'].startswith('test_sample.py::')}
    assert set(rec) == {'test_passes', 'test_skips', 'test_talks_over_dds', 'test_makes_a_campaign',
                        'test_marked_slow'}
    assert rec['test_talks_over_dds']['kind'] == 'ros' and rec['test_talks_over_dds']['slow']
    assert rec['test_passes']['kind'] == 'rest' and not rec['test_passes']['slow']
    assert rec['test_marked_slow']['slow'] and rec['test_skips']['outcome'] == 'skipped'
    assert 0 < rec['test_makes_a_campaign']['campaign'] <= rec['test_makes_a_campaign']['seconds']
    assert rec['test_makes_a_campaign']['cpu'] > 0 and all(r['cpu'] >= 0 for r in rec.values())   # its CPU seconds
    # the fast tier leaves out the slow and the ros test
    assert '4 passed, 1 skipped, 2 deselected' in ci.stdout, ci.stdout   # SAMPLE's 2, CLUSTER's 2


@pytest.mark.slow
def test_a_module_fixture_keeps_its_tests_on_one_worker(inner_runs):
    """Under ./ft test's --dist loadgroup the tests that share a module's fixture run on one worker (it is made
    once), while both workers run tests (the grouped ones come first: spread, both workers would have some)."""
    assert inner_runs['quiet'].returncode == 0, inner_runs['quiet'].stdout[-2000:]
    grouped, alone = ((inner_runs['folder'] / n).read_text().split() for n in ('grouped', 'alone'))
    assert len(grouped) == 6 and len(set(grouped)) == 1, grouped
    assert len(alone) == 6 and set(grouped + alone) == {'gw0', 'gw1'}, (grouped, alone)   # both workers had work


@pytest.mark.slow
def test_the_embedded_cluster_a_test_started_is_closed_after_it(inner_runs):
    """A test that takes the default path (the embedded Dask cluster) leaves no process behind for the next
    test on its worker: conftest.py closes the cluster after each test (idle, it cost 7 CPU-s a minute)."""
    out = inner_runs['ci_fast'].stdout   # one process: CLUSTER's two tests in order
    assert re.search(r'^test_cluster\.py \.\.\s', out, re.M) and 'FAILED test_cluster' not in out, out[-3000:]


def test_the_allow_list_is_short_and_every_line_has_a_reason():
    allowed = conftest.allowed_skips()
    assert 0 < len(allowed) <= 6
    assert all(pattern.startswith('tests/') and len(reason) > 10 for pattern, reason in allowed), allowed
    skips = [('tests/workspace/test_two_hosts.py::test_x', 'no netns'), ('tests/a.py::test_b', 'why not')]
    assert conftest.unallowed_skips(skips, allowed) == [('tests/a.py::test_b', 'why not')]


def test_each_worker_has_its_own_ros_domains(monkeypatch):
    seen = []
    for k in range(3):
        monkeypatch.setenv('PYTEST_XDIST_WORKER', f'gw{k}')
        monkeypatch.setenv('PYTEST_XDIST_WORKER_COUNT', '3')
        seen.append(set(conftest._domain_range()))
        with pytest.MonkeyPatch.context() as mp:
            assert conftest.isolated_ros_env(mp) in seen[-1]
    assert not (seen[0] & seen[1] or seen[1] & seen[2] or seen[0] & seen[2])
    assert min(map(min, seen)) >= 1 and max(map(max, seen)) <= conftest.ROS_DOMAINS


def test_ft_test_command_line():
    def option(cmd, name):   # the value after NAME among pytest's own arguments
        args = cmd[3:]
        return args[args.index(name) + 1]
    cmd = pytest_command([])
    assert cmd[:4] == [sys.executable, '-m', 'pytest', str(ROOT / 'tests')]
    assert option(cmd, '-n') == os.environ.get('FT_TEST_WORKERS', str(len(os.sched_getaffinity(0)) + 2))
    assert option(cmd, '--dist') == 'loadgroup'
    assert '--record-durations' in cmd and '-m' not in cmd[3:]
    fast = pytest_command(['-m', 'ros', '-n', '3'], fast=True)
    assert option(fast, '-m') == 'not slow and (ros)' and fast.count('-n') == 1 and option(fast, '-n') == '3'
    fast_default = pytest_command([], fast=True)
    assert option(fast_default, '-m') == 'not slow'
    assert option(fast_default, '-n') == os.environ.get('FT_TEST_WORKERS', str(len(os.sched_getaffinity(0))))
    assert '-n' not in pytest_command(['-p', 'no:xdist'])
    assert pytest_command(['tests/workspace/test_suite.py'])[3] == 'tests/workspace/test_suite.py'


def test_bench_tests_prints_the_tables(tmp_path):
    records = [{'nodeid': f'tests/x/test_a.py::test_{i}', 'seconds': float(i), 'kind': kind, 'slow': i > 5,
                'outcome': 'passed', **({'campaign': 0.5, 'discover': 1.0} if i == 9 else {})}
               for i, kind in zip(range(1, 10), ['rest'] * 5 + ['ros'] * 2 + ['netns', 'rest'])]
    (tmp_path / 'd.json').write_text(json.dumps(records))
    r = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / 'bench_tests.py'), '--file', str(tmp_path / 'd.json'),
                        '--top', '3'], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert '9 tests, 45 s' in r.stdout and '| 1 | 9.0 | rest | `tests/x/test_a.py::test_9` |' in r.stdout
    assert '| making campaigns | 0 |' in r.stdout or '| making campaigns | 1 |' in r.stdout
    assert '| ROS graphs and nodes | 13 |' in r.stdout and '| network namespaces | 8 |' in r.stdout
    assert '| the rest | 22 |' in r.stdout   # 1..5 and 9 - 1.5 measured
    assert 'fast tier (not slow): 5 tests, 15 s' in r.stdout
    assert 'CPU' not in r.stdout   # records without CPU seconds (a JUnit report, an older file): no CPU table
    for rec in records:
        rec['cpu'] = rec['seconds'] / 2 if rec['kind'] == 'rest' else 0.5
    (tmp_path / 'd.json').write_text(json.dumps(records))
    r = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / 'bench_tests.py'), '--file', str(tmp_path / 'd.json'),
                        '--top', '3'], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert '14 CPU seconds' in r.stdout and '| 1 | 4.5 | 9.0 | rest | `tests/x/test_a.py::test_9` |' in r.stdout
    assert 'Workers' not in r.stdout   # no start and end times recorded: no worker table
    # each test's start and end on its worker: the span, each worker's time in tests, and the tail at the end
    t = 1000.0
    for i, rec in enumerate(records):
        rec['worker'] = f'gw{i % 2}'
        rec['start'] = t if i < 2 else records[i - 2]['end']
        rec['end'] = rec['start'] + rec['seconds']
    (tmp_path / 'd.json').write_text(json.dumps(records))
    r = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / 'bench_tests.py'), '--file', str(tmp_path / 'd.json'),
                        '--top', '3'], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    # gw0: tests 1, 3, 5, 7, 9 (25 s); gw1: 2, 4, 6, 8 (20 s): the span 25 s, the tail 5 s
    assert 'from start to end in 25 s' in r.stdout, r.stdout
    assert '| gw0 | 5 | 25 | 25 s |' in r.stdout and '| gw1 | 4 | 20 | 20 s |' in r.stdout, r.stdout
    assert 'ran out of tests): 5 s' in r.stdout, r.stdout
