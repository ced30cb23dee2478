"""The suite's tiers, its workers' isolation, its bookkeeping, and the shared fixtures (docs/tests.md).

Tiers. `./ft test` runs everything; `./ft test --fast` runs `-m "not slow"`. A test is `slow` when it is marked so
by hand (it takes more than about 3 s on its own) or when it has a kind marker: `ros` (it starts ROS 2 nodes;
given automatically to every test that uses the ros_domain fixtures), `browser` or `netns`. A test of the fast
tier that takes longer than FAST_S is named at the end of the run, to be marked.

Workers. `./ft test` runs on pytest-xdist's workers (`--dist loadgroup`). Each worker has its own share of the ROS
domains (every test that talks over DDS takes one from the ros_domain fixtures; the worker's own default covers
the rest), so two workers' graphs never see each other. A test that cannot share the machine carries
`@pytest.mark.xdist_group(SOLO)`: those tests run one after another on one worker, beside the others.

Bookkeeping. Each test's report carries the seconds it spent making campaigns and in `discover` (tests/kinds.py)
and the CPU seconds it cost (`cpu`: this process's, its children's that were waited for, and the change in those
of the descendants still running: cpu_seconds);
`--record-durations FILE` writes every test's time, kind and those seconds as JSON (`./ft bench tests`).

Skips. Under CI=true a skipped test fails the run unless its node id is in tests/skips_allowed.txt, with its reason.
"""
from __future__ import annotations

import fnmatch
import itertools
import json
import os
import resource
import time
from pathlib import Path

import pytest
from kinds import FAST_S, MARKED_KINDS, kind_of, take, timed

from force_tester_common import engine
from force_tester_common.core.cache import CACHE_ENV
from force_tester_common.core.mapping import INLINE
from force_tester_common.engine import SCHEDULER_ENV

HERE = Path(__file__).resolve().parent
SKIPS_ALLOWED = HERE / 'skips_allowed.txt'
SOLO = 'solo'         # the xdist group of the tests that cannot share the machine with each other
ROS_DOMAINS = 100     # ROS_DOMAIN_ID 1..100 are shared out among the workers
_ROS_FIXTURES = {'ros_domain', 'module_ros_domain'}
_domains = itertools.count()
_RUN = {'tests': {}, 'skips': []}   # what the reports said, for the summary and --record-durations
_CPU_AT_START = pytest.StashKey[float]()
_WALL_AT_START = pytest.StashKey[float]()

MARKERS = {
    'slow': 'takes more than about 3 s on its own: left out of ./ft test --fast',
    'ros': 'starts ROS 2 nodes (in this process or as processes over Fast DDS); slow',
    'browser': 'drives a real browser; slow',
    'netns': 'makes network namespaces (needs root); slow',
}


def _worker() -> tuple:
    """(this xdist worker's index, the number of workers); (0, 1) without xdist."""
    name = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    return int(name.removeprefix('gw') or 0), int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1'))


def _domain_range() -> range:
    """This worker's ROS domains: the last is its default, the others are handed out by the fixtures."""
    k, n = _worker()
    span = ROS_DOMAINS // max(n, 1)
    return range(1 + k * span, 1 + (k + 1) * span)


def pytest_addoption(parser):
    parser.addoption('--record-durations', metavar='FILE', default=None,
                     help="write each test's time, kind and campaign/discover seconds to FILE (JSON)")


def pytest_configure(config):
    for name, text in MARKERS.items():
        config.addinivalue_line('markers', f'{name}: {text}')
    # a worker's ROS domain for the tests that start a graph without a domain fixture: never another worker's
    os.environ['ROS_DOMAIN_ID'] = str(_domain_range()[-1])
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    # the per-pull work of every campaign command a test runs (in this process or a CLI it starts) inline unless
    # the test asks for a scheduler: the embedded cluster's two worker processes cost a CLI call 7 s of CPU more
    # (27 s instead of 5 s for `bag import` of 3 pulls on a loaded machine). Inline is the same function on the same
    # item; the tests of the default path (`embedded_cluster`) and of Dask clusters give their own.
    os.environ.setdefault(SCHEDULER_ENV, INLINE)
    # the per-user cache (force_tester_common.core.cache) of every process the tests start: the workspace's own,
    # not the user's
    os.environ.setdefault(CACHE_ENV, str(Path(__file__).resolve().parents[1] / '.ft' / 'cache'))
    # the expensive steps, timed where they are defined (test modules import the timed names)
    import force_discovery.core.pipeline as pipeline
    import force_tester_sim.core.campaign as campaign
    pipeline.discover = timed('discover')(pipeline.discover)
    campaign.generate_campaign = timed('campaign')(campaign.generate_campaign)


def _shares_a_module_fixture(item) -> bool:
    """Whether ITEM uses a fixture its own module defines for more than one test (a graph, a campaign, a cluster)."""
    module = item.nodeid.split('::')[0]
    defs = getattr(getattr(item, '_fixtureinfo', None), 'name2fixturedefs', {})
    return any(d.scope != 'function' and d.baseid == module for ds in defs.values() for d in ds)


@pytest.hookimpl(tryfirst=True)   # before pytest-xdist's own, which reads the groups
def pytest_collection_modifyitems(config, items):
    """Kinds and tiers; the xdist groups (SOLO, and a module's tests that share its fixture: it is made once, on one
    worker); the order: the groups first (xdist hands out the larger ones first), then the slow tests, so that no
    long test starts last."""
    for item in items:
        if _ROS_FIXTURES & set(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.ros)
        if any(item.get_closest_marker(k) for k in MARKED_KINDS):
            item.add_marker(pytest.mark.slow)
        if item.get_closest_marker('netns'):
            item.add_marker(pytest.mark.xdist_group(SOLO))
        elif not item.get_closest_marker('xdist_group') and _shares_a_module_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split('::')[0]))
    items.sort(key=lambda i: (not i.get_closest_marker('xdist_group'), not i.get_closest_marker('slow')))
    if getattr(config.option, 'loadgroup', False):   # set on xdist's workers under --dist loadgroup
        for item in items:
            _name_the_group(item)


def _name_the_group(item) -> None:
    """'NODEID@GROUP', the id by which pytest-xdist's loadgroup scheduler keeps a group on one worker. xdist 3.8
    writes it to `item._nodeid`, which pytest 9 no longer reads (the id is `item._id`, a NodeId), so every group
    was spread over the workers; this writes it where pytest 9 keeps it. NodeId.parse gives back the same string."""
    from _pytest.nodeid import NodeId
    group = item.get_closest_marker('xdist_group')
    if group is not None and '@' not in item.nodeid:
        item._id = NodeId.parse(f'{item.nodeid}@{group.args[0]}')


def _children(pid: int) -> list:
    """The pids of PID's live (or not yet waited-for) children, from every thread's /proc children list."""
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out += [int(c) for c in (task / 'children').read_text().split()]
        except OSError:   # the thread or process ended meanwhile
            continue
    return out


def _tree_cpu(pid: int) -> float:
    """CPU seconds of PID's descendants that are still in the tree: each one's own user + system time and that
    of the children it has waited for (which have left the tree), from /proc."""
    total, todo = 0, _children(pid)
    while todo:
        child = todo.pop()
        try:
            fields = Path(f'/proc/{child}/stat').read_text().rsplit(')', 1)[1].split()
        except OSError:
            continue
        total += sum(int(f) for f in fields[11:15])   # utime, stime, cutime, cstime (clock ticks)
        todo += _children(child)
    return total / os.sysconf('SC_CLK_TCK')


def cpu_seconds() -> float:
    """This process's CPU seconds (user + system), its children's that were waited for, and those of the
    descendants still running (or not yet waited for). A test's cost is the difference at its start and end: a
    process it started that outlives it (the embedded Dask cluster, a module's graph) is counted in the tests that
    ran while it worked, not all at once in the test during which it is waited for; RUSAGE_CHILDREN alone gave one
    test 51 CPU-s in 5 s on 2 cores (test_engine's allocator test, which shuts down the worker's embedded
    cluster)."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime + _tree_cpu(os.getpid())


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    take()
    item.stash[_CPU_AT_START] = cpu_seconds()
    item.stash[_WALL_AT_START] = time.time()
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item, nextitem):
    """After a test's own teardown: the embedded Dask cluster it started (the default path) is closed, not kept
    for the rest of the worker's session, where its idle scheduler and two worker processes cost about 7 CPU-s a
    minute (measured: 7.1 CPU-s in 60 s idle) on a suite that is CPU-bound."""
    yield
    engine.shutdown(None)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if call.when == 'teardown':
        spent = {**take(), 'cpu': round(cpu_seconds() - item.stash.get(_CPU_AT_START, cpu_seconds()), 3),
                 'start': round(item.stash.get(_WALL_AT_START, time.time()), 3), 'end': round(time.time(), 3),
                 'worker': os.environ.get('PYTEST_XDIST_WORKER', 'main')}
        report.user_properties.append(('spent', json.dumps(spent)))


def pytest_runtest_logreport(report):
    """Collected where the reports arrive (the controller under xdist): each test's phases, and every skip."""
    if report.skipped and not hasattr(report, 'wasxfail'):
        _RUN['skips'].append((_own_id(report.nodeid), _skip_reason(report)))
    nodeid = _own_id(report.nodeid)
    rec = _RUN['tests'].setdefault(nodeid, {'nodeid': nodeid, 'seconds': 0.0, 'outcome': 'passed'})
    rec['seconds'] = round(rec['seconds'] + report.duration, 4)
    rec['kind'] = kind_of(report.keywords)
    rec['slow'] = 'slow' in report.keywords
    if report.failed or report.skipped:
        rec['outcome'] = report.outcome
    for key, value in report.user_properties:
        if key == 'spent':
            rec.update(json.loads(value))


def _own_id(nodeid: str) -> str:
    """A test's id without the '@GROUP' of its xdist group (_name_the_group)."""
    head, at, group = nodeid.rpartition('@')
    return head if at and not set(group) & set('[]:') else nodeid


def _skip_reason(report) -> str:
    longrepr = report.longrepr
    return str(longrepr[2] if isinstance(longrepr, tuple) else longrepr).removeprefix('Skipped: ')


def allowed_skips(path: Path = SKIPS_ALLOWED) -> list:
    """[(node-id pattern, reason)] of the skips CI accepts: 'PATTERN  # REASON' per line, '#' lines are comments."""
    out = []
    for line in path.read_text().splitlines() if path.exists() else []:
        if line.strip() and not line.lstrip().startswith('#'):
            pattern, _, reason = line.partition('#')
            out.append((pattern.strip(), reason.strip()))
    return out


def unallowed_skips(skips, allowed) -> list:
    return [(nodeid, why) for nodeid, why in skips if not any(fnmatch.fnmatchcase(nodeid, p) for p, _ in allowed)]


def pytest_sessionfinish(session, exitstatus):
    config = session.config
    if hasattr(config, 'workerinput'):
        return
    records = list(_RUN['tests'].values())
    path = config.getoption('--record-durations')
    if path:
        Path(path).write_text(json.dumps(records, indent=1))
    _RUN['slow_unmarked'] = sorted((r for r in records if not r['slow'] and r['seconds'] > FAST_S),
                                   key=lambda r: -r['seconds'])
    if os.environ.get('CI') == 'true':
        _RUN['bad_skips'] = unallowed_skips(_RUN['skips'], allowed_skips())
        if _RUN['bad_skips'] and session.exitstatus == 0:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    tr = terminalreporter
    slow = _RUN.get('slow_unmarked', [])
    if slow:
        tr.section(f'fast-tier tests over {FAST_S:g} s: mark them slow (docs/tests.md)', yellow=True)
        for r in slow[:20]:
            tr.write_line(f"{r['seconds']:7.1f} s  {r['nodeid']}")
    bad = _RUN.get('bad_skips', [])
    if bad:
        tr.section('skipped under CI=true, not in tests/skips_allowed.txt: the run fails', red=True)
        for nodeid, why in bad:
            tr.write_line(f'{nodeid}: {why}')


# ------------------------------------------------------------------------------------------------ fixtures
def isolated_ros_env(mp: pytest.MonkeyPatch) -> int:
    """Give this process (and the nodes it starts) a ROS domain of its own, discovery on localhost: one of this
    worker's domains (its last is kept as the worker's default), offset by the process id so that two runs on one
    machine seldom meet."""
    own = _domain_range()[:-1]
    domain = own[(os.getpid() + 17 * next(_domains)) % len(own)]
    mp.setenv('ROS_DOMAIN_ID', str(domain))
    mp.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return domain


@pytest.fixture
def embedded_cluster(monkeypatch):
    """The default path of the campaign engine: no scheduler named, so the embedded LocalCluster (the suite runs
    the per-pull work inline otherwise, pytest_configure)."""
    monkeypatch.delenv(SCHEDULER_ENV, raising=False)


@pytest.fixture
def ros_domain(monkeypatch):
    return isolated_ros_env(monkeypatch)


@pytest.fixture(scope='module')
def module_ros_domain():
    with pytest.MonkeyPatch.context() as mp:
        yield isolated_ros_env(mp)


SHARED_REPORTS = 'shared_discovery_reports'   # the xdist group of the tests that share a `discovered` report


@pytest.fixture(scope='session')
def discovered(tmp_path_factory):
    """discovered(departures, seed, nuisance_seed=None, **make_campaign's keywords) -> (report, output folder):
    the streamed discovery (inline) of the discovery generator's campaign, made once per session and content for
    every test that asserts on it (those carry `@pytest.mark.xdist_group(SHARED_REPORTS)`, so that one worker makes
    it); each caller gets its own copy of the report and of the folder (no PNGs: no caller looks at them)."""
    import copy
    import shutil

    from generator import draw_nuisance, make_campaign  # tests/force_discovery, on the path of its tests

    from force_discovery.core.pipeline import discover
    from force_tester_sim.core.params import load_rig
    made = {}

    def get(departures, seed, nuisance_seed=None, **kw):
        key = json.dumps([departures, seed, nuisance_seed, kw], sort_keys=True, default=str)
        if key not in made:
            out = tmp_path_factory.mktemp('discovered')
            nuisance = draw_nuisance(nuisance_seed) if nuisance_seed is not None else None
            made[key] = (discover(make_campaign(departures, seed=seed, nuisance=nuisance, **kw), load_rig(), out,
                                  scheduler='inline', plots=False), out)
        report, out = made[key]
        mine = tmp_path_factory.mktemp('report')
        shutil.copytree(out, mine, dirs_exist_ok=True)
        return copy.deepcopy(report), mine

    return get
