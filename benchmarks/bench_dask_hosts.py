"""Benchmark: one campaign on the embedded cluster and on a Dask cluster across three hosts (needs root).

    ./ft bench dask_hosts [--pulls 8] [--loss 1] [--delay 20] [--lose-in STAGES] [--json FILE] [--work DIR]

Runs `./ft bench campaign --pulls N --keep` (generate, import, discover, export) three times in one go:
1. embedded: the default path, in this process's host (a LocalCluster, one worker per CPU);
2. cluster, clean link: hosts a, b, c (network namespaces on one switch, netlab.netns.Star), `dask scheduler`
   and the client in a, a `dask worker --nworkers 2 --nthreads 1` in each of b and c;
3. cluster, impaired: the same with --loss % loss and --delay ms delay each way on every path; host c is lost
   (switch port down, every process SIGKILLed) in each stage (--lose-in), once one of its workers runs a pull
   of that stage, and brought back (port up, its workers started again) once the scheduler has let them go.
Prints each run's table (bench campaign's: wall and cost per pull per stage, peak RSS, the bytes each host and
each worker moved over the network per stage), each loss's timeline (lost, dropped by the scheduler, back,
registered, first task of a new worker), the tasks each worker ran (its own count),
the veth counters per host, and whether the outputs of 2 and 3 (campaign, bag, exported campaign, extension.yaml;
report.json but for where and when it ran) are byte-identical to 1's. Exits 1 if a run failed or differs.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from ft_cli.paths import RUNS
from netlab.dask_hosts import STAGES, run_campaign
from netlab.netns import Impairment, probe

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / 'benchmarks' / 'bench_campaign.py'


def files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob('*')) if p.is_file()}


def differences(ref: Path, out: Path) -> list:
    """What differs between two runs' outputs (empty: byte-identical; report.json equal but for where and when it
    ran: scheduler, retried_pulls, the plots' folder, simulation_check.time_s)."""
    bad = []
    for what in ('campaign', 'bag', 'exported'):
        a, b = files(ref / what), files(out / what)
        if not a or a != b:
            bad.append(f'{what}: ' + (', '.join(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
                                      or 'empty'))
    try:
        ra, rb = (json.loads((d / 'discover' / 'report.json').read_text()) for d in (ref, out))
    except OSError as exc:
        return [*bad, f'report.json: {exc}']
    for r in (ra, rb):   # where and when it ran: the scheduler, the rerun pulls, the plots' paths, a wall time
        r.pop('scheduler', None)
        r.pop('retried_pulls', None)
        r.get('simulation_check', {}).pop('time_s', None)
        r['plots'] = [Path(f).name for f in r.get('plots', [])]
    if ra != rb:
        bad.append('report.json: ' + ', '.join(k for k in sorted(set(ra) | set(rb)) if ra.get(k) != rb.get(k)))
    if (ref / 'discover' / 'extension.yaml').read_bytes() != (out / 'discover' / 'extension.yaml').read_bytes():
        bad.append('extension.yaml')
    return bad


def _after(loss: dict, what: str) -> str:
    t = loss.get(what)
    return 'never' if t is None else f'{t - loss["lost_s"]:.1f} s after'


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench dask_hosts', description=__doc__.splitlines()[0])
    ap.add_argument('--pulls', type=int, default=8, help='pulls in the campaign (default 8)')
    ap.add_argument('--loss', type=float, default=1.0, help='loss in %% on every path of the impaired run (default 1)')
    ap.add_argument('--delay', type=float, default=20.0, help='delay in ms each way on every path (default 20)')
    ap.add_argument('--lose-in', default='generate,import,discover,export', metavar='STAGES',
                    help='stages in which host c is lost in the impaired run, comma-separated (default: all four: '
                         'generate,import,discover,export; "" for none)')
    ap.add_argument('--json', help='write the figures to this file too')
    ap.add_argument('--work', metavar='DIR', default=None,
                    help='folder for the three runs\' outputs (default: a temporary folder under runs/, removed)')
    a = ap.parse_args()
    if a.pulls < 1:
        ap.error(f'--pulls {a.pulls} is invalid; expected an integer >= 1')
    stages = [s for s, _fn in STAGES]
    lose_in = tuple(x.strip() for x in a.lose_in.split(',') if x.strip())
    if any(x not in stages for x in lose_in) or list(lose_in) != sorted(set(lose_in), key=stages.index):
        ap.error(f'--lose-in {a.lose_in!r} is invalid; expected stages among {",".join(stages)}, in that order')
    support = probe()
    if not support.netns:
        print(f'./ft bench dask_hosts: error: three hosts need network namespaces: {support.reason}', file=sys.stderr)
        return 2
    impaired = Impairment(loss_pct=a.loss, delay_ms=a.delay)
    RUNS.mkdir(exist_ok=True)
    work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix='bench_dask_hosts_', dir=RUNS))
    work.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, 'FT_ROOT': str(ROOT)}
    env.pop('DASK_SCHEDULER_ADDRESS', None)

    def bench(name: str) -> list:
        out = work / name
        shutil.rmtree(out, ignore_errors=True)
        return [sys.executable, str(BENCH), '--pulls', str(a.pulls), '--work', str(out / 'work'), '--keep',
                '--json', str(out / 'work' / 'bench.json')]
    figures, ok = {}, True
    try:
        print(f'== embedded ({a.pulls} pulls)', flush=True)
        cmd = bench('embedded')
        (work / 'embedded').mkdir(parents=True)
        r = subprocess.run(cmd, cwd=ROOT, env=env, text=True, capture_output=True)
        print(r.stdout, end='', flush=True)
        if r.returncode:
            print(f'./ft bench dask_hosts: error: the embedded run exited {r.returncode}: {r.stderr[-1500:]}',
                  file=sys.stderr)
            return 1
        figures['embedded'] = json.loads((work / 'embedded' / 'work' / 'bench.json').read_text())
        for name, imp, lose in (('clean', Impairment(), ()), ('impaired', impaired, lose_in)):
            print(f'== three hosts, {imp.describe()}' + (f', host c lost in {", ".join(lose)}, brought back after '
                                                          'each loss' if lose else ''), flush=True)
            res = run_campaign(work / name, env, bench(name), imp, lose='c' if lose else None, lose_in=lose,
                               back=bool(lose), say=print)
            print(res['stdout'], end='')
            for x in res['losses']:
                print(f'  host c lost in {x["stage"]} at {x["lost_s"]:.1f} s; dropped by the scheduler '
                      f'{_after(x, "dropped_s")}; back {_after(x, "back_s")}; its new workers registered '
                      f'{_after(x, "registered_s")} and got a pull {_after(x, "used_s")}')
            if res['missed']:
                print(f'  host c not lost in {", ".join(res["missed"])}: the stage ended before c was back')
            if res['executed']:
                print('  tasks each worker ran (its own count): '
                      + ', '.join(f'{w.split("://")[-1]} {n}' for w, n in sorted(res['executed'].items())))
            for h, c in res['counters'].items():
                print(f'  host {h} link: sent {c["tx_bytes"] / 1e6:.1f} MB in {c["tx_packets"]} packets, received '
                      f'{c["rx_bytes"] / 1e6:.1f} MB, lost on the way in {c["lost"]} packets')
            bad = differences(work / 'embedded' / 'work', work / name / 'work') if res['rc'] == 0 else \
                [f'exit {res["rc"]}: {res["stderr"][-1500:]}']
            print('  outputs: ' + ('byte-identical to the embedded run\'s' if not bad else 'DIFFER: ' + '; '.join(bad)),
                  flush=True)
            ok = ok and not bad
            bench_json = work / name / 'work' / 'bench.json'
            figures[name] = {'link': imp.describe(), 'method': res['method'], 'differences': bad,
                             'lost_s': res['lost_s'], 'after_loss_s': res['after_loss_s'], 'back_s': res['back_s'],
                             'used_after_back': res['used_after_back'], 'counters': res['counters'],
                             'losses': res['losses'], 'missed': res['missed'], 'executed': res['executed'],
                             'bench': json.loads(bench_json.read_text()) if bench_json.is_file() else None}
    finally:
        if not a.work:
            shutil.rmtree(work, ignore_errors=True)
    if a.json:
        Path(a.json).write_text(json.dumps(figures, indent=1))
        print(f'json: {a.json}')
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
