"""Acceptance: a campaign on a Dask cluster across three hosts, over a lossy, slow link, losing a host.

Host A (a network namespace) runs `dask scheduler` and the client, hosts B and C each a `dask worker --nworkers 2
--nthreads 1`; all three hang on one switch (netlab.netns.Star) whose links drop 1 % of the packets and delay
them 5 ms each way. Every process runs this workspace's venv and install/ (this test's environment, which ./ft
gave it); the campaign folders are on the file system they share. The client is `./ft bench campaign --pulls 8
--scheduler tcp://A:8786 --keep`: generate, import, discover (./ft discover's CLI function) and export. While
discover's first pass runs on C's workers, C's switch port goes down and every process in C is SIGKILLed, with no
goodbye to the scheduler; the campaign ends on B. Its outputs are compared with the same campaign's on the
embedded cluster of the default path, and the rerun pulls must be named. Then a fourth host D imports that
campaign on a fresh cluster and host A (the scheduler's) is lost. Needs root (skipped otherwise, with the
reason); the hosts are deleted whatever happens. About 4-6 minutes on a busy 2-core machine.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from netlab.dask_hosts import run_campaign
from netlab.netns import Impairment, probe

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
BENCH = ROOT / 'benchmarks' / 'bench_campaign.py'
PULLS = 8
LINK = Impairment(loss_pct=1.0, delay_ms=5.0)
TIMEOUT_S = 1500      # the client's whole run; a hang is a failure, not a CI job that never ends


def bench(*args, work: Path) -> list:
    return [sys.executable, str(BENCH), '--pulls', str(PULLS), '--work', str(work), '--keep',
            '--json', str(work / 'bench.json'), *args]


def files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob('*')) if p.is_file()}


@pytest.fixture(scope='module')
def runs(tmp_path_factory):
    support = probe()
    if not support.netns:
        pytest.skip(f'three hosts need network namespaces: {support.reason}')
    if not support.bpf or not (support.netem or support.delay_line):
        pytest.skip('this kernel can neither drop nor delay packets on a veth (no cls_bpf, no netem or tap+mirred)')
    ref, out = tmp_path_factory.mktemp('embedded'), tmp_path_factory.mktemp('three_hosts')
    env = {**os.environ, 'FT_ROOT': str(ROOT)}
    env.pop('DASK_SCHEDULER_ADDRESS', None)
    embedded = subprocess.run(bench(work=ref), cwd=ROOT, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert embedded.returncode == 0, embedded.stderr[-2000:]
    # C is lost while one of its workers runs a pull of discover's first pass (./ft discover's survey)
    res = run_campaign(out, env, bench(work=out / 'work'), LINK, lose='c', lose_on='pull-survey-',
                       timeout=TIMEOUT_S, say=lambda _m: None)
    return {**res, 'embedded': embedded, 'ref': ref, 'out': out / 'work'}


def test_the_campaign_completes_on_b_after_c_is_lost(runs):
    assert runs['rc'] == 0, runs['stderr'][-3000:]
    assert runs['removed'], 'no process was killed in host C'
    assert runs['left'] == [], runs['left']
    figures = json.loads((runs['out'] / 'bench.json').read_text())
    assert figures['scheduler'].startswith(runs['address']) and '4 workers' in figures['scheduler'], figures
    # every host's link carried the cluster's traffic, and the loss dropped some of it
    assert all(runs['counters'][h]['tx_bytes'] > 0 for h in 'abc'), runs['counters']
    assert sum(runs['counters'][h]['lost'] for h in 'abc') > 0, runs['counters']


def test_export_sends_no_pull_samples_to_the_workers(runs):
    """The workers read their pulls from the bag on the shared storage: the client (host A) sends them a
    small fraction of the bag's bytes over the network during export (17 MB a pull when it sent the arrays),
    while during import, whose single bag writer needs every pull's arrays, it receives about the bag's size."""
    assert runs['rc'] == 0, runs['stderr'][-3000:]
    stages = json.loads((runs['out'] / 'bench.json').read_text())['stages']
    bag = sum(f.stat().st_size for f in (runs['out'] / 'bag').iterdir())
    export, imported = stages['export']['net_mb']['client'], stages['import']['net_mb']['client']
    assert export['out'] * 1e6 < bag / 50, (export, bag)
    assert imported['in'] * 1e6 > bag / 2, (imported, bag)


def test_the_rerun_pulls_are_named(runs):
    """discover's CLI says which pulls ran again, and so does the run's summary; they are pulls of the campaign."""
    names = {p.name for p in (runs['ref'] / 'campaign').glob('*.csv')}
    line = next((ln for ln in runs['stderr'].splitlines() if ln.startswith('rerun after a worker died: ')), '')
    assert line, runs['stderr'][-3000:]
    rerun = line.split(': ', 1)[1].split(', ')
    assert rerun and set(rerun) <= names, (rerun, sorted(names))
    figures = json.loads((runs['out'] / 'bench.json').read_text())
    assert set(rerun) <= set(figures['retried']), figures['retried']


@pytest.mark.parametrize('what', ['campaign', 'bag', 'exported'])
def test_the_files_are_byte_identical_to_the_embedded_clusters(runs, what):
    assert runs['rc'] == 0, runs['stderr'][-3000:]
    a, b = files(runs['ref'] / what), files(runs['out'] / what)
    assert sorted(a) == sorted(b) and len(a) >= 2, (what, sorted(a), sorted(b))
    assert [k for k in a if a[k] != b[k]] == [], what


def test_discovery_finds_the_same_with_the_host_lost(runs):
    """report.json and extension.yaml as on the embedded cluster, but for what says where and when it ran: the
    scheduler, the rerun pulls, the plots' paths (in each run's folder) and the re-simulation's wall time."""
    assert runs['rc'] == 0, runs['stderr'][-3000:]
    ref, out = runs['ref'] / 'discover', runs['out'] / 'discover'
    a, b = (json.loads((d / 'report.json').read_text()) for d in (ref, out))
    assert a['scheduler'].startswith('embedded') and b['scheduler'].startswith(runs['address']), \
        (a['scheduler'], b['scheduler'])
    assert a['retried_pulls'] == [] and b['retried_pulls'], (a['retried_pulls'], b['retried_pulls'])
    for r, d in ((a, ref), (b, out)):
        del r['scheduler'], r['retried_pulls'], r['simulation_check']['time_s']
        assert all(Path(f).parent == d for f in r['plots']), r['plots']
        r['plots'] = [Path(f).name for f in r['plots']]
    assert a == b
    assert (ref / 'extension.yaml').read_bytes() == (out / 'extension.yaml').read_bytes()


def test_losing_the_schedulers_host_is_one_line_and_exit_2_and_no_bag(runs, tmp_path):
    """The client in a fourth host D imports the campaign; host A (the scheduler's) is lost while the workers
    read its pulls. The command ends by itself: one line naming the scheduler, exit 2, and no bag (the one it
    was writing is removed; it never had a metadata.yaml)."""
    bag = tmp_path / 'bag'
    cmd = [sys.executable, '-m', 'ft_cli', 'bag', 'import', str(runs['ref'] / 'campaign'), str(bag)]
    env = {**os.environ, 'FT_ROOT': str(ROOT)}
    res = run_campaign(tmp_path / 'net', env, cmd, LINK, lose='a', lose_on='pull-read_pull-', client='d',
                       timeout=TIMEOUT_S, say=lambda _m: None)
    assert res['removed'], 'no process was killed in host A'
    lines = res['stderr'].strip().splitlines()
    assert res['rc'] == 2 and len(lines) == 1, (res['rc'], res['stderr'][-3000:])
    assert lines[0].startswith('./ft bag import: error: lost the scheduler ' + res['address']), lines
    assert not bag.exists() and res['left'] == []
