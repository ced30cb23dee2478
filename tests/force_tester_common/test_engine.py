"""The campaign engine (force_tester_common.engine) on real Dask worker processes: results in item order
whatever the completion order, a failing pull reported by name while the rest finish, a killed worker's
pull rerun and reported, an unreachable scheduler refused fast."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import engine_jobs
import pytest

from force_tester_common import engine
from force_tester_common.engine import EngineError, map_pulls

cloudpickle.register_pickle_by_value(engine_jobs)
ITEMS = [(i, 6) for i in range(6)]


@pytest.fixture(scope='module')
def cluster():
    """A distributed.LocalCluster of its own: 2 worker processes, 1 thread each."""
    from distributed import LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0',
                      host='127.0.0.1') as c:
        yield c
        engine.shutdown(c.scheduler_address)   # the engine's client to it, before it goes


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_results_come_in_item_order_on_any_scheduler(cluster, monkeypatch):
    seen = []
    monkeypatch.delenv(engine.SCHEDULER_ENV, raising=False)
    inline = map_pulls(engine_jobs.square_slowly, ITEMS, scheduler='inline')
    assert inline.scheduler == 'inline' and inline.results == [i * i for i in range(6)]
    default = map_pulls(engine_jobs.square_slowly, ITEMS, progress=lambda d, t: seen.append((d, t)))
    assert default.scheduler.startswith('embedded LocalCluster')
    explicit = map_pulls(engine_jobs.square_slowly, ITEMS, scheduler=cluster.scheduler_address)
    assert explicit.scheduler.startswith(cluster.scheduler_address) and '2 workers' in explicit.scheduler
    monkeypatch.setenv(engine.SCHEDULER_ENV, cluster.scheduler_address)
    from_env = map_pulls(engine_jobs.square_slowly, ITEMS)
    assert from_env.scheduler == explicit.scheduler
    for r in (default, explicit, from_env):
        assert r.results == inline.results and r.failed == [] and r.retried == []
    assert seen[-1] == (6, 6) and [d for d, _ in seen] == list(range(1, 7))


@pytest.mark.slow
def test_the_embedded_workers_keep_the_allocator_settings_of_ft(monkeypatch):
    """./ft exports glibc's MALLOC_MMAP_THRESHOLD_ and MALLOC_TRIM_THRESHOLD_; Dask's nanny would give its workers
    a trim threshold of 64 KiB (which cost a 100-pull discover a third of its CPU in fresh pages) unless the
    environment sets one: the embedded cluster's workers run with ./ft's."""
    monkeypatch.delenv(engine.SCHEDULER_ENV, raising=False)
    wanted = engine_jobs.allocator_env(None)
    assert None not in wanted, f'./ft test exports no allocator settings: {wanted}'
    engine.shutdown(None)   # a new embedded cluster, started with this environment
    got = map_pulls(engine_jobs.allocator_env, range(4))
    assert got.scheduler.startswith('embedded LocalCluster') and set(got.results) == {wanted}
    engine.shutdown(None)


def test_streaming_in_item_order_without_keeping_results(cluster):
    got = []
    r = map_pulls(engine_jobs.square_slowly, iter(ITEMS), scheduler=cluster.scheduler_address, keep=False,
                  on_result=lambda i, v: got.append((i, v)))
    assert got == [(i, i * i) for i in range(6)] and r.results == [None] * 6


def test_a_failing_pull_is_reported_by_name_and_the_rest_finish(cluster):
    items = [ITEMS[0], 'bad', ITEMS[2]]
    names = ['a.csv', 'b.csv', 'c.csv']
    for sched in ('inline', cluster.scheduler_address):
        r = map_pulls(engine_jobs.square_slowly, items, names=names, scheduler=sched)
        assert r.results == [0, None, 4]
        assert r.failed == [('b.csv', "ValueError: pull content 'bad' is corrupt")]


def test_a_killed_worker_has_its_pull_rerun_and_reported(cluster, tmp_path):
    names = [f'pull_{i}.csv' for i in range(4)]
    r = map_pulls(engine_jobs.die_once, [(str(tmp_path), i) for i in range(4)], names=names,
                  scheduler=cluster.scheduler_address)
    killed = int((tmp_path / 'attempt_1').read_text())
    assert [x[0] for x in r.results] == [0, 1, 2, 3] and r.failed == []
    assert r.results[1][1] != killed           # the rerun ran in another process
    assert 'pull_1.csv' in r.retried            # ... and the report says so
    assert set(r.retried) <= set(names)


@pytest.mark.slow   # a Dask cluster of worker processes (5-14 s in the fast tier of a fresh run)
def test_a_pull_that_kills_every_worker_fails_alone(tmp_path, monkeypatch):
    """The embedded cluster allows RETRIES reruns, then the pull fails with KilledWorker (after one more try
    alone); the pulls that shared its dying workers finish."""
    monkeypatch.delenv(engine.SCHEDULER_ENV, raising=False)
    r = map_pulls(engine_jobs.always_die, [(str(tmp_path), i) for i in range(3)], names=['x', 'y', 'z'])
    assert r.results[1:] == [1, 2], r.failed   # z failed once in 17 fresh runs (load 11): why, here
    assert [n for n, _ in r.failed] == ['x'] and 'KilledWorker' in r.failed[0][1]
    assert len((tmp_path / 'deaths').read_text().split()) == 2 * (engine.RETRIES + 1)
    assert 'x' in r.retried
    engine.shutdown(None)   # the next test starts a fresh embedded cluster, not one whose workers were killed 6 times


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_error_within_10_s():
    address = f'tcp://127.0.0.1:{free_port()}'
    t0 = time.monotonic()
    with pytest.raises(EngineError) as err:
        map_pulls(engine_jobs.square_slowly, ITEMS, scheduler=address)
    assert time.monotonic() - t0 < 10.0
    msg = str(err.value)
    assert address in msg and 'expected a running dask scheduler' in msg and '\n' not in msg
    with pytest.raises(EngineError, match='expected tcp://HOST:PORT'):
        map_pulls(engine_jobs.square_slowly, ITEMS, scheduler='localhost')


def test_importing_the_engine_loads_no_dask():
    code = ('import sys, force_tester_common.engine\n'
            'print(sorted(m for m in sys.modules if m.startswith(("dask", "distributed"))))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == '[]'


def test_workers_are_real_processes_of_this_venv(cluster):
    from distributed import Client
    with Client(cluster.scheduler_address, set_as_default=False) as c:
        c.wait_for_workers(2, timeout=120)   # on a busy machine the second may register after the cluster returns
        exe = c.run(lambda: sys.executable)
        pids = c.run(lambda: __import__('os').getpid())
        mods = c.run(lambda: __import__('force_tester_common').__file__)
    assert set(exe.values()) == {sys.executable}
    assert len(set(pids.values())) == 2 and __import__('os').getpid() not in pids.values()
    assert all(Path(m).is_file() for m in mods.values())


def test_an_error_in_the_items_stops_the_map_and_reaches_the_caller(cluster):
    def items():
        yield from ITEMS[:3]
        raise ValueError('pull 4 is listed twice')

    with pytest.raises(ValueError, match='listed twice'):
        map_pulls(engine_jobs.square_slowly, items(), scheduler=cluster.scheduler_address)
    again = map_pulls(engine_jobs.square_slowly, ITEMS, scheduler=cluster.scheduler_address)
    assert again.results == [i * i for i in range(6)]     # the engine still works afterwards



HEAP_PROBE = """
import json, os
import numpy as np
from force_tester_common import engine
def resident():
    with open('/proc/self/statm') as f:
        return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE')
base = resident()
arrays = [np.ones(2 ** 17) for _ in range(160)]   # 160 MiB in 1 MiB arrays, each from the heap
del arrays
kept = resident()
above = engine.trim_above(kept + 2 ** 30)
after_above = resident()
below = engine.trim_above(0)
print(json.dumps([base, kept, above, after_above, below, resident()]))
"""


def test_a_worker_above_the_limit_gives_its_free_heap_back():
    """engine.trim_above, in a fresh process (a worker's heap, not this one's after other tests): with ./ft's
    allocator settings the heap keeps what a pull freed (up to 256 MiB); above the limit it is given back (glibc's
    malloc_trim), below it nothing is done."""
    r = subprocess.run([sys.executable, '-c', HEAP_PROBE], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    base, kept, above, after_above, below, after = json.loads(r.stdout)
    assert kept - base > 100 * 2 ** 20, ('the heap did not keep the freed arrays: ./ft exports '
                                         'MALLOC_TRIM_THRESHOLD_ and MALLOC_MMAP_THRESHOLD_', kept - base)
    assert above is False and after_above > kept - 2 ** 20
    assert below is True and after < kept - 100 * 2 ** 20, (kept - after) / 2 ** 20
