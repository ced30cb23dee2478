"""Benchmark: an N-pull campaign end to end on Dask (./ft bench campaign --pulls N [--json FILE] [--scheduler ADDR]).

Stages, in this order, each timed with the peak RSS of this process (the client) and of every Dask worker:
1. generate: the truth rig's campaign (sets 1-5 in turn, N pulls in all, 2 s at 50 kHz each, seed 2013), each
   pull simulated and written as CSV on a worker (as ./ft thesis makes the reference campaign);
2. import: that campaign folder -> a bag (pull files read on the workers, the bag written here, streamed);
3. discover: ./ft discover on the campaign folder (its CLI function, in this process, on the same scheduler);
   the generated campaign is deleted after it;
4. export: the bag -> a campaign folder (its pull events read here, each pull read from the bag and written as
   CSV on a worker), then deleted.
Disk: about 16 MB of CSV and 8 MB of bag per pull, at most campaign + bag at once (24 GB for 1,000 pulls).

Peak RSS per stage: Linux's VmHWM (/proc/PID/status), reset before each stage by writing 5 to
/proc/PID/clear_refs, in this process and, through client.run, in each worker process. Where the reset is not
allowed, the figure is the peak since the process started (the table says so).
Per-pull cost: the stage's wall time / N on this machine's workers (cost per pull x N / workers for a cluster).

Bytes over the network per stage: each worker's host and the client's, from /proc/net/dev as that process sees
it (its network namespace or host; every interface but loopback and tun/tap), received and sent. Workers on one
host share the figure (the table shows it once per host). Per worker too: the payload bytes of that worker
process's TCP connections to other hosts, received and sent (the kernel's per-connection counters, `ss -tinp`,
sampled at the stage's ends and every 2 s between, so a connection that closed still counts); a worker lost
during a stage is missing from it (its bytes with it), a worker that joined counts from 0. On the embedded
cluster everything goes over loopback: 0.
--keep keeps the campaign, bag, discover report and exported campaign in --work (the output files of a run, to
compare with another run's).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETS = (1, 2, 3, 4, 5)
SEED = 2013


def peak_rss_mb(reset: bool = False) -> tuple:
    """(VmHWM of this process in MB, whether the peak could be reset before), optionally resetting it now."""
    ok = True
    if reset:
        try:
            with open('/proc/self/clear_refs', 'w') as fh:
                fh.write('5')
        except OSError:
            ok = False
    with open('/proc/self/status') as fh:
        for line in fh:
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024.0, ok
    return float('nan'), False


def _worker_peak(reset: bool = False):   # runs in each worker process (client.run)
    return peak_rss_mb(reset)


def net_bytes() -> tuple:
    """(received, sent) bytes on every interface but loopback and tun/tap devices (a user-space delay line's
    tap would count each frame twice), as this process's network namespace counts them."""
    rx = tx = 0
    with open('/proc/net/dev') as fh:
        for line in fh.readlines()[2:]:
            name, _, fields = line.partition(':')
            name = name.strip()
            if name != 'lo' and not os.path.exists(f'/sys/class/net/{name}/tun_flags'):
                values = fields.split()
                rx, tx = rx + int(values[0]), tx + int(values[8])
    return rx, tx


def socket_bytes(pid: int, seen: dict) -> tuple:
    """(received, sent) payload bytes of process ``pid``'s TCP connections to other hosts (loopback left out),
    from the kernel's per-connection counters (`ss -tinp`: bytes_received, bytes_acked). Cumulative: ``seen``
    keeps every connection's last counters, so one that closed since still counts (up to its last sample)."""
    out = subprocess.run(['ss', '-tinpHO'], capture_output=True, text=True, timeout=30).stdout
    tag = f'pid={pid},'
    for line in out.splitlines():
        f = line.split()
        if tag not in line or len(f) < 5:
            continue
        local, peer = f[3], f[4]
        if peer.startswith(('127.', '[::1]', '[::ffff:127.')):
            continue
        rx, tx = (int(m.group(1)) if m else 0 for m in (_RX.search(line), _TX.search(line)))
        old = seen.get((local, peer), (0, 0))
        if rx < old[0] or tx < old[1]:   # the same address pair on a new connection: keep the old one's bytes
            seen['closed'] = tuple(a + b for a, b in zip(seen.get('closed', (0, 0)), old))
        seen[(local, peer)] = (rx, tx)
    return tuple(sum(v[i] for v in seen.values()) for i in (0, 1))


_RX, _TX = re.compile(r'bytes_received:(\d+)'), re.compile(r'bytes_acked:(\d+)')
SOCKET_SAMPLE_S = 2.0   # how often a worker samples its connections' counters between the stage boundaries


def _worker_sockets(dask_worker=None):   # runs in each worker process (client.run): its (received, sent) bytes
    state = getattr(dask_worker, '_bench_sockets', None)
    if state is None:
        state = dask_worker._bench_sockets = {'seen': {}, 'lock': threading.Lock()}

        def sample():
            while True:
                time.sleep(SOCKET_SAMPLE_S)
                with state['lock']:
                    socket_bytes(os.getpid(), state['seen'])
        threading.Thread(target=sample, daemon=True, name='bench-sockets').start()
    with state['lock']:
        return socket_bytes(os.getpid(), state['seen'])


def _worker_net(dask_worker=None):   # runs in each worker process (client.run): (host address, received, sent)
    host = dask_worker.address.split('://', 1)[-1].rsplit(':', 1)[0]
    return (host, *net_bytes())


class Meter:
    """Peak RSS of the client and the workers over one stage, and its wall time."""

    def __init__(self, client) -> None:
        self.client = client

    def __enter__(self):
        self.client_reset = peak_rss_mb(reset=True)[1]
        self.worker_reset = all(ok for _mb, ok in self._workers(True).values())
        self.net0, self.sock0 = self._net(), self._sockets()
        self.t0 = time.perf_counter()
        return self

    def _net(self) -> dict:
        """host -> (received, sent): 'client' and each worker host (a worker that left is missing)."""
        out = {'client': net_bytes()}
        if self.client is not None:
            try:
                for host, rx, tx in self.client.run(_worker_net, on_error='ignore').values():
                    out[host] = (rx, tx)
            except Exception:  # noqa: BLE001,S110 - a worker lost between the listing and the call: next stage
                pass
        return out

    def _sockets(self) -> dict:
        """worker address -> (received, sent) bytes over its connections to other hosts, so far."""
        if self.client is None:
            return {}
        try:
            return {w: tuple(v) for w, v in self.client.run(_worker_sockets, on_error='ignore').items()
                    if isinstance(v, (tuple, list))}
        except Exception:  # noqa: BLE001 - a worker lost between the listing and the call: left out
            return {}

    def _workers(self, reset: bool) -> dict:
        if self.client is None:
            return {}
        return self.client.run(_worker_peak, reset, on_error='ignore')   # a worker lost meanwhile: left out

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.t0
        self.client_mb = peak_rss_mb()[0]
        self.workers_mb = {w: mb for w, (mb, _ok) in sorted(self._workers(False).items())}
        net1, sock1 = self._net(), self._sockets()
        # a worker that joined during the stage counts from 0; one lost during it is missing (its bytes with it)
        self.worker_net_mb = {w: tuple((b - a) / 1e6 for a, b in zip(self.sock0.get(w, (0, 0)), v))
                              for w, v in sorted(sock1.items())}
        # a host whose counters went down restarted its interface (or is a new host): counted from 0
        self.net_mb = {h: tuple(max(0, b - (a if a <= b else 0)) / 1e6 for a, b in zip(self.net0.get(h, (0, 0)), v))
                       for h, v in net1.items()}
        return False


def run(n: int, scheduler: str | None, work: Path, keep: bool = False) -> dict:
    from bag_tools.core.convert import bag_to_campaign, campaign_to_bag
    from bag_tools.core.daq import write_campaign
    from force_tester_common.engine import INLINE, Mapper, get_client, resolve_scheduler
    from force_tester_sim.core.campaign import campaign_jobs, simulate_campaign_pull
    from force_tester_sim.core.params import TRUTH_YAML, load_rig

    address = resolve_scheduler(scheduler)
    client, where = (None, INLINE) if address == INLINE else get_client(address)
    per_set = -(-n // len(SETS))
    jobs = campaign_jobs(load_rig(TRUTH_YAML), SETS, per_set, SEED)
    jobs = [jobs[(i % len(SETS)) * per_set + i // len(SETS)] for i in range(n)]   # sets in turn, N in all
    camp, bag, out, exported = work / 'campaign', work / 'bag', work / 'discover', work / 'exported'
    stages = {}

    def stage(name, fn):
        before = len(mapper.retried)
        with Meter(client) as m:
            fn()
        stages[name] = m
        m.retried = mapper.retried[before:] if name != 'discover' else \
            json.loads((out / 'report.json').read_text()).get('retried_pulls', [])
        workers = ', '.join(f'{mb:.0f}' for mb in m.workers_mb.values()) or '-'
        net = '; '.join(f'{h} {rx:.1f}/{tx:.1f}' for h, (rx, tx) in m.net_mb.items())
        per_worker = '; '.join(f'{w.split("://")[-1]} {rx:.1f}/{tx:.1f}' for w, (rx, tx) in m.worker_net_mb.items())
        print(f'  {name:9s} {m.wall:8.1f} s  {m.wall / n:6.2f} s/pull  client peak {m.client_mb:6.0f} MB  '
              f'workers peak {workers} MB  network in/out MB: {net}'
              + (f'  per worker in/out MB: {per_worker}' if per_worker else ''), flush=True)

    print(f'campaign of {n} pulls on {where}; work folder {work}', flush=True)
    mapper = Mapper(scheduler)
    stage('generate', lambda: write_campaign(camp, jobs, mapper=mapper, produce=simulate_campaign_pull))
    stage('import', lambda: campaign_to_bag(camp, bag, mapper=mapper))
    stage('discover', lambda: discover(camp, out, scheduler))
    if not keep:
        shutil.rmtree(camp)
    stage('export', lambda: bag_to_campaign(bag, exported, mapper=mapper))
    total = sum(m.wall for m in stages.values())
    return {
        'pulls': n, 'scheduler': where, 'cpus': os.cpu_count(), 'wall_s': total, 's_per_pull': total / n,
        'retried': [*mapper.retried, *json.loads((out / 'report.json').read_text()).get('retried_pulls', [])],
        'stages': {k: {'wall_s': m.wall, 's_per_pull': m.wall / n, 'share': m.wall / total,
                       'client_peak_mb': m.client_mb, 'worker_peak_mb': list(m.workers_mb.values()),
                       'net_mb': {h: {'in': rx, 'out': tx} for h, (rx, tx) in m.net_mb.items()},
                       'worker_net_mb': {w: {'in': rx, 'out': tx} for w, (rx, tx) in m.worker_net_mb.items()},
                       'peak_reset': m.client_reset and m.worker_reset, 'retried': m.retried}
                   for k, m in stages.items()},
    }


def discover(folder: Path, out: Path, scheduler: str | None) -> None:
    """./ft discover FOLDER --out OUT [--scheduler S], through its CLI function (whatever options it has)."""
    from force_discovery.cli import add_arguments, main
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    argv = [str(folder), '--out', str(out)]
    if scheduler and any('--scheduler' in a.option_strings for a in ap._actions):
        argv += ['--scheduler', scheduler]
    rc = main(ap.parse_args(argv))
    if rc != 0:
        raise SystemExit(f'bench campaign: ./ft discover exited {rc}')


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench campaign', description=__doc__.splitlines()[0])
    ap.add_argument('--pulls', type=int, required=True, help='pulls in the campaign (N)')
    ap.add_argument('--json', help='write the figures to this file too')
    ap.add_argument('--scheduler', metavar='ADDRESS', default=None,
                    help='Dask scheduler (default: $DASK_SCHEDULER_ADDRESS, else the embedded local cluster)')
    ap.add_argument('--work', metavar='DIR', default=None,
                    help='folder for the campaign and bag (default: a temporary folder under runs/, removed)')
    ap.add_argument('--keep', action='store_true',
                    help='keep every output in --work: campaign/, bag/, discover/, exported/ (needs --work)')
    a = ap.parse_args()
    if a.pulls < 1:
        ap.error(f'--pulls {a.pulls} is invalid; expected an integer >= 1')
    if a.keep and not a.work:
        ap.error('--keep needs --work DIR; expected a folder to keep the outputs in')
    from force_tester_common.engine import EngineError
    (ROOT / 'runs').mkdir(exist_ok=True)
    work = Path(a.work) if a.work else Path(tempfile.mkdtemp(prefix='bench_campaign_', dir=ROOT / 'runs'))
    work.mkdir(parents=True, exist_ok=True)
    try:
        res = run(a.pulls, a.scheduler, work, keep=a.keep)
    except EngineError as exc:
        print(f'./ft bench campaign: error: {exc}', file=sys.stderr)
        return 2
    finally:
        if not a.work:
            shutil.rmtree(work, ignore_errors=True)
    print(f'total {res["wall_s"]:.1f} s, {res["s_per_pull"]:.2f} s/pull; shares: '
          + ', '.join(f'{k} {100 * v["share"]:.0f} %' for k, v in res['stages'].items())
          + ('' if all(v['peak_reset'] for v in res['stages'].values())
             else '; peaks: since process start (clear_refs not allowed)')
          + (f'; rerun after a worker died: {", ".join(res["retried"])}' if res['retried'] else ''))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1))
        print(f'json: {a.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
