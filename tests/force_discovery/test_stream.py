"""Issue 16, section 1: discover streams its pulls. Memory is flat in the number of pulls, the streamed report is the
one-pass report (to rounding: the force model is fitted from per-pull sufficient statistics), and the per-pull
stages run on Dask with the same results; a pull that cannot be read is left out and named.

The campaigns come from the test GENERATOR (generator.py); the code under test gets the data and the nominal rig.
"""
from __future__ import annotations

import argparse
import gc
import json
import math
import time
import tracemalloc
import weakref

import numpy as np
import pytest
from generator import make_campaign
from one_pass import discover_in_memory

from force_discovery import cli as discover_cmd
from force_discovery.core.pipeline import discover
from force_discovery.core.prep import Pull
from force_tester_sim.core.params import load_rig

STREAMED = {'scheduler', 'failed_pulls', 'retried_pulls', 'plots'}   # keys that say how it ran, not what it found
BEYOND = {'beyond_catalog', 'beyond_search'}   # the search beyond the catalog: the stream's only (no one-pass twin)
TIMING = ('simulation_check', 'time_s')


def _leaves(x, path=()):
    """(path, value) of every leaf of a JSON document."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(x, list):
        for i, v in enumerate(x):
            yield from _leaves(v, path + (i,))
    else:
        yield path, x


def _differences(a: dict, b: dict, rtol: float, skip=STREAMED) -> list:
    """Leaves of two reports that differ: numbers by more than rtol (relative), anything else at all."""
    la = {p: v for p, v in _leaves({k: v for k, v in a.items() if k not in skip}) if p[:2] != TIMING}
    lb = {p: v for p, v in _leaves({k: v for k, v in b.items() if k not in skip}) if p[:2] != TIMING}
    out = sorted(set(la) ^ set(lb), key=str)
    for p in set(la) & set(lb):
        x, y = la[p], lb[p]
        if isinstance(x, float) or isinstance(y, float):
            # a budget line is the change of a parameter between two fits: rounding at the parameter's scale
            est = None
            if p[0] == 'uncertainty_budget':   # the report's own budget section: {cause: {parameter: {line: u}}}
                est = la.get(('candidates', p[1], 'parameters', p[2]))
            elif 'uncertainty_budget' in p:
                est = la.get(p[:p.index('uncertainty_budget')] + ('parameters', p[-2]))
            floor = rtol * abs(est) if isinstance(est, float) and math.isfinite(est) else 1e-300
            if not (isinstance(x, (int, float)) and isinstance(y, (int, float))
                    and math.isclose(x, y, rel_tol=rtol, abs_tol=floor)):
                out.append((p, x, y))
        elif x != y:
            out.append((p, x, y))
    return out


def _args(*argv):
    ap = argparse.ArgumentParser()
    discover_cmd.add_arguments(ap)
    return ap.parse_args([str(a) for a in argv])


@pytest.mark.slow
def test_streamed_report_is_the_one_pass_report(tmp_path):
    """Every decision the same; every number to rounding, and the re-simulation bit for bit given the same
    extension. The mount, hum, friction, gain, mass and delay are all in the campaign, so every stage's per-pull
    path (force statistics, free decay, current, hum, re-simulation) is compared."""
    import yaml

    from force_discovery.core.decision import decide
    from force_discovery.core.report import clean
    from force_discovery.core.stream import Stream
    from force_tester_common.engine import Mapper
    # (the hum at 4 N: with 4 held-out pulls a 3 N hum's t sits at the significance threshold of 4, 3.99 on this
    # seed since the delay became a shift, and this test is about the two paths agreeing, not the hum's power)
    deps = {'mount_resonance': {'frequency_hz': 1100.0, 'damping_ratio': 0.02}, 'coulomb_friction': {'force_n': 120.0},
            'mains_hum': {'frequency_hz': 50.0, 'amplitude_n': 4.0}, 'accel_delay': {'delay_s': 4e-5},
            'moving_cell_gain': {'gain': 1.02}, 'effective_mass': {'mass_kg': 1.3}}
    camp = make_campaign(deps, seed=61, sets=(2, 3), pulls=4)
    rig = load_rig()
    one = discover_in_memory(camp, rig, tmp_path / 'one')
    streamed = discover(camp, rig, tmp_path / 'streamed', scheduler='inline')
    assert streamed['cause'] == one['cause'] == 'mount_resonance'
    assert [c['name'] for c in streamed['causes']] == [c['name'] for c in one['causes']]
    assert {c['name'] for c in streamed['causes']} == set(deps)
    for key in ('within_tolerance', 'inconclusive'):
        assert [(c['name'], c['tolerance']['verdict']) for c in streamed[key]] == \
            [(c['name'], c['tolerance']['verdict']) for c in one[key]], key
    for key in ('fitted_pulls', 'held_out_pulls', 'data_quality'):
        assert streamed[key] == one[key], key
    ring = [r['simulation_check']['ring'] for r in (one, streamed)]
    assert ring[0]['within_tolerance'] and ring[1]['within_tolerance']
    assert streamed['failed_pulls'] == [] and streamed['retried_pulls'] == []
    # the stream's force model sums per pull, then over pulls: the order of the additions differs, nothing else
    # (1e-8: the T^2 check's fit is the worst conditioned, about 2e-9 here; the rest agree to 1e-10 or better)
    sim = {'simulation', 'simulation_check'}
    assert _differences(one, streamed, rtol=1e-8, skip=STREAMED | sim | BEYOND) == []
    # The re-simulation's per-pull fits (break instants shorter than a sample) turn a change of the extension in
    # its 13th digit into one in the 4th digit of the simulated RMS; so it is checked given the one-pass extension:
    # the stream re-simulates the held-out pulls to the last bit as the one pass does.
    ext = yaml.safe_load((tmp_path / 'one' / 'extension.yaml').read_text())
    (tmp_path / 'spill').mkdir()
    st = Stream(camp, rig, Mapper('inline'), str(tmp_path / 'spill'))
    analysis = st.analyse()
    _left, _errors, check = st.held_out_results(analysis, decide(analysis, rig), ext)
    assert clean(check.as_dict()) == one['simulation']
    assert clean(check.details())['quantities'] == one['simulation_check']['quantities']
    assert clean(check.ring) == one['simulation_check']['ring']
    on_disk = json.loads((tmp_path / 'streamed' / 'report.json').read_text())
    assert _differences(on_disk, streamed, rtol=0.0, skip={'plots'}) == []
    assert (tmp_path / 'streamed' / 'ringing.png').is_file() and (tmp_path / 'streamed' / 'residuals.png').is_file()


def _traced_peak(camp, tmp, live: list, made: list) -> int:
    """tracemalloc's peak (bytes allocated by discover itself: the campaign's channels exist before) of a streamed
    discovery in this process; live: the number of prepared pulls alive each time a pull finishes a stage (made
    holds a weak reference to every Pull made: a pull still referenced, even from a cycle, counts as alive)."""
    def progress(stage, done, total):
        live.append(sum(ref() is not None for ref in made))
    gc.collect()
    tracemalloc.start()
    try:
        # no PNGs: matplotlib's allocations are not the stream's (and under tracemalloc they cost 8 s)
        discover(camp, load_rig(), tmp, scheduler='inline', progress=progress, plots=False)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_memory_is_flat_in_the_number_of_pulls(tmp_path, monkeypatch):
    """The streamed discovery of 16 pulls allocates at its peak less than one pull's channels more than that of 8
    pulls: the pulls pass through one at a time and only small results stay. Not timed: tracemalloc counts every
    numpy allocation (within about 1 MB from run to run). And no prepared pull outlives its stage (counted when each
    pull finishes)."""
    small = make_campaign(None, seed=62, sets=(2, 3), pulls=4)
    large = make_campaign(None, seed=62, sets=(2, 3), pulls=8)
    live_small, live_large, made = [], [], []
    init = Pull.__init__

    def counted(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(weakref.ref(self))
    monkeypatch.setattr(Pull, '__init__', counted)
    peak_small = _traced_peak(small, tmp_path / 'small', live_small, made)
    peak_large = _traced_peak(large, tmp_path / 'large', live_large, made)
    one_pull = sum(np.asarray(v).nbytes for v in large[0][1].values())   # one pull's channels
    # the measure sees the work (a pull is prepared, filtered and re-simulated) ...
    assert peak_small > one_pull, (peak_small, one_pull)
    # ... and it does not grow with the pulls: 8 more pulls add less than one pull's channels (holding them all would
    # add 8 pulls' worth; what does grow is each pull's small results: 6.0-6.8 MB for 8 pulls on 2026-11-28, where a
    # margin of 10 % of the peak, 6.6 MB, failed once)
    assert peak_large - peak_small < one_pull, (peak_large / 2 ** 20, peak_small / 2 ** 20, one_pull / 2 ** 20)
    assert len(live_large) >= 2 * 16 and max(live_small + live_large) == 0, (live_small, live_large)


@pytest.fixture(scope='module')
def on_dask(tmp_path_factory):
    """One campaign folder with one unreadable pull file, discovered inline and then on a distributed.LocalCluster of
    2 worker processes (real workers: they import the workspace's packages from this venv), one of which is
    SIGKILLed while it runs a pull: the two tests below assert on these two reports (one cluster, one inline run)."""
    import contextlib
    import io
    import os
    import signal
    import threading

    from distributed import Client, LocalCluster

    from bag_tools.core.daq import write_campaign
    tmp = tmp_path_factory.mktemp('on_dask')
    camp = make_campaign({'effective_mass': {'mass_kg': 1.4}}, seed=63, sets=(3,), pulls=7)
    write_campaign(tmp / 'camp', camp)
    bad = camp[2][0]['file']
    (tmp / 'camp' / bad).write_text('time_s,force_moving_n\n0.0,1.0\nnot a number,oops\n')
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        inline_rc = discover_cmd.main(_args(tmp / 'camp', '--out', tmp / 'inline', '--scheduler', 'inline',
                                             '--no-plots'))
    killed, dask_err = [], io.StringIO()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        pids = client.run(os.getpid)
        done = threading.Event()

        def kill_a_busy_worker():
            while not done.is_set() and not killed:
                busy = [addr for addr, tasks in client.processing().items() if tasks and addr in pids]
                if busy:
                    os.kill(pids[busy[0]], signal.SIGKILL)
                    killed.append(busy[0])
                done.wait(0.02)
        watcher = threading.Thread(target=kill_a_busy_worker, daemon=True)
        watcher.start()
        try:
            with contextlib.redirect_stderr(dask_err):
                dask_rc = discover_cmd.main(_args(tmp / 'camp', '--out', tmp / 'dask', '--scheduler',
                                                  cluster.scheduler_address, '--no-plots'))
        finally:
            done.set()
            watcher.join()
    return {'tmp': tmp, 'bad': bad, 'inline_rc': inline_rc, 'inline_err': err.getvalue(), 'dask_rc': dask_rc,
            'dask_err': dask_err.getvalue(), 'killed': killed,
            'inline': json.loads((tmp / 'inline' / 'report.json').read_text()),
            'on_dask': json.loads((tmp / 'dask' / 'report.json').read_text())}


@pytest.mark.slow
def test_a_corrupt_pull_is_named_and_dask_workers_give_the_same_report(on_dask):
    """A campaign folder with one unreadable pull file: discover leaves it out, names it in report.json, report.md
    and on stderr, and finishes. Run on a distributed.LocalCluster of 2 worker processes it gives the report it
    gives inline, number for number (but for the pulls rerun after the kill of test_a_worker_killed_...)."""
    tmp, bad, inline, dask = on_dask['tmp'], on_dask['bad'], on_dask['inline'], on_dask['on_dask']
    assert on_dask['inline_rc'] == 0 and on_dask['dask_rc'] == 0, (on_dask['inline_err'], on_dask['dask_err'])
    assert f'pull {bad} left out' in on_dask['inline_err'], on_dask['inline_err']
    assert f'pull {bad} left out' in on_dask['dask_err'], on_dask['dask_err']
    assert [f['pull'] for f in inline['failed_pulls']] == [bad] and 'line 3' in inline['failed_pulls'][0]['error']
    assert inline['cause'] == 'effective_mass' and bad not in inline['fitted_pulls'] + inline['held_out_pulls']
    assert len(inline['fitted_pulls'] + inline['held_out_pulls']) == 6
    assert bad in (tmp / 'inline' / 'report.md').read_text()
    assert '2 workers' in dask['scheduler'] and inline['scheduler'] == 'inline'
    assert _differences(inline, dask, rtol=1e-12, skip={'scheduler', 'plots', 'retried_pulls'}) == []


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line_and_exit_2(tmp_path, capsys):
    from bag_tools.core.daq import write_campaign
    write_campaign(tmp_path / 'camp', make_campaign(None, seed=64, sets=(2,), pulls=4))
    t0 = time.monotonic()
    code = discover_cmd.main(_args(tmp_path / 'camp', '--out', tmp_path / 'o', '--scheduler', 'tcp://127.0.0.1:9'))
    assert code == 2 and time.monotonic() - t0 < 10
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'tcp://127.0.0.1:9' in err[0] and err[0].startswith('./ft discover: error: '), err
    assert not (tmp_path / 'o' / 'report.json').exists()


@pytest.mark.slow
def test_a_worker_killed_mid_discovery_is_rerun_and_the_report_says_so(on_dask):
    """discover on a LocalCluster of 2 worker processes; one worker is SIGKILLed while it runs a pull (on_dask).
    Dask reruns that worker's pulls; the report lists them as rerun (retried_pulls, report.md, stderr) and is
    otherwise the inline report, number for number."""
    inline, dask = on_dask['inline'], on_dask['on_dask']
    assert on_dask['dask_rc'] == 0, on_dask['dask_err']
    assert on_dask['killed'], 'no worker was busy long enough to be killed'
    assert dask['retried_pulls'] and inline['retried_pulls'] == []
    assert set(dask['retried_pulls']) <= set(dask['fitted_pulls'] + dask['held_out_pulls'] + [on_dask['bad']])
    assert f'rerun after a worker died: {", ".join(dask["retried_pulls"])}' in on_dask['dask_err']
    assert 'Rerun because the worker running them died' in (on_dask['tmp'] / 'dask' / 'report.md').read_text()
    assert _differences(inline, dask, rtol=1e-12, skip={'scheduler', 'plots', 'retried_pulls'}) == []
