"""Campaigns on Dask (docs/campaigns.md): the same campaign generated, imported, exported and corrected on a
distributed.LocalCluster with 2 worker processes gives the same bytes as the default path; a scheduler that
does not answer, a corrupt pull file and a worker killed mid-campaign are reported by the CLIs."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from bag_tools.core.convert import bag_to_campaign, campaign_to_bag
from bag_tools.core.daq import campaign_index, read_campaign, write_campaign
from force_correction.offline import correct
from force_tester_common import engine
from force_tester_common.engine import Mapper
from force_tester_sim.core.campaign import campaign_jobs, generate_campaign, simulate_campaign_pull
from force_tester_sim.core.params import TRUTH_YAML, load_rig

ROOT = Path(__file__).resolve().parents[2]
cloudpickle.register_pickle_by_value(sys.modules[__name__])   # die_once below runs on the workers
SETS, PULLS, SEED = (3, 4), 1, 16


@pytest.fixture(scope='module')
def cluster():
    """A cluster of its own (not the embedded one): 2 worker processes, spawned from this venv."""
    from distributed import LocalCluster
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=':0',
                      host='127.0.0.1') as c:
        yield c.scheduler_address
        engine.shutdown(c.scheduler_address)


@pytest.fixture(autouse=True)
def no_env_scheduler(monkeypatch):
    monkeypatch.delenv(engine.SCHEDULER_ENV, raising=False)


def files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob('*')) if p.is_file()}


def ft(*args, env=None, timeout=300):
    return subprocess.run([sys.executable, '-m', 'ft_cli', *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, env=env)


def die_once(job):
    """simulate_campaign_pull, except that the first attempt at set 4 kills its worker process."""
    marker, inner = job
    if inner[1].test_set == 4 and not os.path.exists(marker):
        Path(marker).write_text(str(os.getpid()))
        os._exit(13)
    return simulate_campaign_pull(inner)


@pytest.mark.slow
def test_a_campaign_is_the_same_bytes_on_any_scheduler(cluster, tmp_path):
    rig = load_rig(TRUTH_YAML)
    jobs = campaign_jobs(rig, SETS, PULLS, SEED)
    here = generate_campaign(rig, SETS, PULLS, SEED)                      # in this process, no Dask
    there = generate_campaign(rig, SETS, PULLS, SEED, mapper=Mapper(cluster))
    for (ma, ca), (mb, cb) in zip(here, there, strict=True):
        assert ma == mb and all(ca[k].tobytes() == cb[k].tobytes() for k in ca)
    # generation as ./ft thesis does it: each pull simulated and written on a worker
    runs = {'default': Mapper(), 'cluster': Mapper(cluster)}
    for name, mapper in runs.items():
        write_campaign(tmp_path / f'gen_{name}', jobs, mapper=mapper, produce=simulate_campaign_pull)
    assert runs['default'].where.startswith('embedded LocalCluster')
    assert runs['cluster'].where.startswith(cluster) and '2 workers' in runs['cluster'].where
    write_campaign(tmp_path / 'gen_inline', here)
    ref = files(tmp_path / 'gen_inline')
    assert files(tmp_path / 'gen_default') == ref and files(tmp_path / 'gen_cluster') == ref
    src = tmp_path / 'gen_inline'
    # import, export, correct: default (embedded cluster) in this process; --scheduler through the CLI
    # (same output names in two folders: a bag's file is named after its folder)
    d, c = tmp_path / 'default', tmp_path / 'cluster'
    d.mkdir(), c.mkdir()
    campaign_to_bag(read_campaign(src, mapper=Mapper()), d / 'bag')
    bag_to_campaign(d / 'bag', d / 'exp', mapper=Mapper())
    correct(src, d / 'cor', mapper=Mapper())
    for args in (('import', src, c / 'bag'), ('export', d / 'bag', c / 'exp'), ('correct', src, c / 'cor')):
        r = ft('bag', *args, '--scheduler', cluster)
        assert r.returncode == 0, r.stderr
    for what in ('bag', 'exp', 'cor'):
        a, b = files(d / what), files(c / what)
        assert a == b and len(a) >= 2, what
    exported = read_campaign(d / 'exp')
    assert [p.channels['force_moving_n'].tobytes() for p in exported.pulls] == \
        [ch['force_moving_n'].tobytes() for _m, ch in here]
    assert np.isfinite(read_campaign(d / 'cor').pulls[0].channels['filtered_n']).any()


@pytest.mark.slow
def test_a_killed_worker_is_rerun_and_the_campaign_is_unchanged(cluster, tmp_path):
    rig = load_rig(TRUTH_YAML)
    marker = tmp_path / 'killed'
    jobs = [(m, (str(marker), job)) for m, job in campaign_jobs(rig, SETS, PULLS, SEED)]
    mapper = Mapper(cluster)
    write_campaign(tmp_path / 'c', jobs, mapper=mapper, produce=die_once)
    assert marker.is_file()                                    # a worker did die
    assert 'set4_pull01.csv' in mapper.retried                 # ... and the run says which pull was rerun
    write_campaign(tmp_path / 'ref', generate_campaign(rig, SETS, PULLS, SEED))
    assert files(tmp_path / 'c') == files(tmp_path / 'ref')


@pytest.mark.slow   # a Dask cluster of worker processes (5-14 s in the fast tier of a fresh run)
def test_a_corrupt_pull_is_named_and_the_rest_is_imported(cluster, tmp_path):
    from daq_data import T0, make_pulls
    src = write_campaign(tmp_path / 'camp', make_pulls(4, start=T0))
    (src / 'pull_0002.csv').write_text('time_s,force_moving_n\n0.0,1.0\nnot a number,2\n')
    for cmd, out in (('import', tmp_path / 'bag'), ('correct', tmp_path / 'cor')):
        r = ft('bag', cmd, src, out, '--scheduler', cluster)
        assert r.returncode == 2, r.stderr
        assert 'pull_0002.csv' in r.stderr and "pull 'pull_0002.csv' skipped" in r.stderr
        assert r.stderr.strip().splitlines()[-1].startswith(f'./ft bag {cmd}: error: 1 pull(s) failed')
    back = bag_to_campaign(tmp_path / 'bag', tmp_path / 'back')
    assert len(campaign_index(back)[3]) == 3 and len(campaign_index(tmp_path / 'cor')[3]) == 3


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line_and_exit_2_within_10_s(tmp_path):
    from daq_data import make_pulls
    src = write_campaign(tmp_path / 'camp', make_pulls(2))
    address = f'tcp://127.0.0.1:{free_port()}'
    commands = [('bag', 'import', src, tmp_path / 'b'), ('bag', 'export', tmp_path / 'nobag', tmp_path / 'e'),
                ('bag', 'correct', src, tmp_path / 'c'), ('thesis', '--cache', tmp_path / 'cache')]
    for args in commands:   # one after the other: each is timed alone
        t0 = time.monotonic()
        r = ft(*args, '--scheduler', address, timeout=60)
        elapsed = time.monotonic() - t0
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and address in lines[0] and 'unreachable' in lines[0], (args, r.stderr)
        assert elapsed < 10.0, (args, elapsed)
    assert not (tmp_path / 'b').exists() and not (tmp_path / 'c').exists()
