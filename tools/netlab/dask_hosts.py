"""A Dask cluster across the hosts of a netlab Star: `dask scheduler` in one host, `dask worker`s in others.

Every process runs the workspace's interpreter with the environment it is given (``./ft env``'s: the venv and
install/), as the README's "a cluster of your own" recipe runs them; the namespaces share this machine's file
system, which plays the cluster's shared storage (the campaign folders are seen at the same path everywhere).

    cluster = DaskHosts(net, env, log_dir)        # net: an entered netns.Star
    cluster.scheduler('a'); cluster.workers('b'); cluster.workers('c')
    watch = cluster.watch('a')                    # its lines name every worker: wait for 4 there
    cluster.run('a', [...])                       # a client command inside host a (Popen)

``run_campaign`` does all of it for one client command, and can lose a host mid-run and bring it back.

``python -m netlab.dask_hosts watch ADDRESS`` (run inside a host) prints, as JSON lines, which task keys each
worker is processing whenever that changes, every worker the scheduler has included (what run_campaign waits on:
the workers to register, then the task before it removes a host); ``... executed ADDRESS`` prints how many tasks
each worker has run, from the worker's own state machine (what shows that a host brought back was used). They
reach Dask through the engine (force_tester_common.engine.get_client), the one module that imports it.
"""
from __future__ import annotations

import json
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

from netlab.netns import Impairment, NetnsError, Star

PORT = 8786
NWORKERS = 2      # worker processes per worker host (dask worker --nworkers), one thread each
WORKER_HOSTS = ('b', 'c')   # run_campaign's worker hosts (the scheduler is in a)
WATCH_S = 0.1   # how often the watcher asks the scheduler (a pull's task lasts 0.3 s and more on these hosts)


class DaskHosts:
    """The scheduler and worker processes of one cluster on a Star; they end with the Star (its close())."""

    def __init__(self, net: Star, env: dict, log_dir: Path, port: int = PORT):
        self.net = net
        self.env = {**env, 'PYTHONUNBUFFERED': '1'}
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.port = port
        self.address = None
        self.procs = {}      # name -> Popen

    def _popen(self, host: str, name: str, cmd: list, stdout=None) -> subprocess.Popen:
        log = open(self.log_dir / f'{name}.log', 'a')
        proc = subprocess.Popen([*self.net.host(host).prefix(), *cmd], env=self.env, stdin=subprocess.DEVNULL,
                                stdout=stdout or log, stderr=log, cwd=self.env.get('FT_ROOT'))
        self.procs[name] = proc
        return proc

    def scheduler(self, host: str) -> str:
        """Start `dask scheduler` in ``host``; returns its address (tcp://ADDRESS:PORT)."""
        h = self.net.host(host)
        self._popen(host, f'scheduler_{host}', [sys.executable, '-m', 'distributed.cli.dask_scheduler',
                                                '--host', h.address, '--port', str(self.port), '--no-dashboard'])
        self.address = f'tcp://{h.address}:{self.port}'
        return self.address

    def workers(self, host: str, nworkers: int = NWORKERS) -> subprocess.Popen:
        """Start `dask worker ADDRESS --nworkers N --nthreads 1` in ``host`` (a nanny per worker process)."""
        if self.address is None:
            raise NetnsError('no scheduler yet; expected scheduler(host) before workers(host)')
        h = self.net.host(host)
        n = sum(1 for k in self.procs if k.startswith(f'workers_{host}'))
        scratch = self.log_dir / f'scratch_{host}_{n}'
        return self._popen(host, f'workers_{host}' + (f'_{n}' if n else ''), [
            sys.executable, '-m', 'distributed.cli.dask_worker', self.address, '--nworkers', str(nworkers),
            '--nthreads', '1', '--host', h.address, '--no-dashboard', '--local-directory', str(scratch)])

    def run(self, host: str, name: str, cmd: list) -> subprocess.Popen:
        """A client command inside ``host``; stdout and stderr piped (text)."""
        proc = subprocess.Popen([*self.net.host(host).prefix(), *cmd], env=self.env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=self.env.get('FT_ROOT'))
        self.procs[name] = proc
        return proc

    def watch(self, host: str) -> subprocess.Popen:
        """The watcher in ``host``: JSON lines {worker address: [task keys processing]} on its stdout, every
        worker the scheduler has in each (so the first line with n of them says that n have registered)."""
        return self.run(host, f'watch_{host}', [sys.executable, '-m', 'netlab.dask_hosts', 'watch', self.address])

    def wait(self, lines: queue.Queue, n: int, timeout: float = 120.0) -> None:
        """Wait until the watcher's ``lines`` (its stdout, read into a queue) name ``n`` workers: no process of
        its own (each would import Dask: about 1.3 CPU-s)."""
        deadline, last = time.monotonic() + timeout, {}
        while len(last) < n:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                line = None
            if line is None:   # the deadline passed, or the watcher ended
                raise NetnsError(f'the scheduler at {self.address} did not get {n} workers within {timeout:g} s '
                                 f'(it had {sorted(last)}); logs in {self.log_dir}')
            last = json.loads(line)


    def executed(self, host: str = 'a') -> dict:
        """{worker address: tasks it has run}, as each worker's own state machine counts them (asked from
        ``host``); {} when the scheduler does not answer."""
        res = subprocess.run([*self.net.host(host).prefix(), sys.executable, '-m', 'netlab.dask_hosts', 'executed',
                              self.address], env=self.env, capture_output=True, text=True, timeout=120)
        return json.loads(res.stdout) if res.returncode == 0 and res.stdout.strip() else {}

    def tail(self, name: str, lines: int = 15) -> str:
        path = self.log_dir / f'{name}.log'
        return '\n'.join(path.read_text(errors='replace').splitlines()[-lines:]) if path.is_file() else ''


def _lines(stream, q: queue.Queue) -> None:
    for line in stream:
        q.put(line)
    q.put(None)


#: The stages of `./ft bench campaign`, in order, and the function each maps over the pulls (the engine's task
#: keys are pull-<function>-<token>-<i>); None: discover's, any function but import's.
STAGES = (('generate', 'write_pull'), ('import', 'read_pull'), ('discover', None), ('export', 'write_pull'))


class StageClock:
    """Which stage of `./ft bench campaign` the cluster is in, from the task keys the scheduler reports: a key
    of a map not seen before (a new token) whose function is the next stage's moves it on (-1: none yet)."""

    def __init__(self, stages=STAGES):
        self.stages = stages
        self.i = -1
        self.tokens = set()

    @property
    def name(self) -> str | None:
        return self.stages[self.i][0] if self.i >= 0 else None

    def see(self, key: str) -> None:
        parts = key.split('-')
        if len(parts) < 4 or parts[0] != 'pull' or parts[2] in self.tokens:
            return
        fn, token = parts[1], parts[2]
        self.tokens.add(token)
        if self.i + 1 < len(self.stages):
            want = self.stages[self.i + 1][1]
            now = self.stages[self.i][1] if self.i >= 0 else None
            if fn == want or (want is None and fn != now):
                self.i += 1


def run_campaign(out: Path, env: dict, client_cmd: list, impairment: Impairment | None = None,
                 lose: str | None = 'c', lose_on: str | None = None, back: bool = False,
                 lose_in: tuple = (), timeout: float = 1500.0, client: str = 'a', say=print,
                 worker_hosts: tuple = WORKER_HOSTS, nworkers: int = NWORKERS) -> dict:
    """Star a and the ``worker_hosts`` (b and c by default; and d if ``client`` is 'd'): the scheduler in a, the
    client command (``client_cmd`` + ``--scheduler ADDRESS``) in ``client``, a ``dask worker --nworkers
    NWORKERS --nthreads 1`` in each worker host (one is enough where the host lost is the scheduler's or the
    client's; ``nworkers`` processes each, NWORKERS by default).

    With ``lose``: once a worker in that host (any worker, for a host with none) is processing a task whose key
    starts with ``lose_on`` (the engine's keys are pull-<function>-...), its switch port goes down and every
    process in it is SIGKILLed. With ``back`` too: once the scheduler has let the lost workers go, the port comes
    up and the host's workers are started again (they join during the run).
    With ``lose_in`` (stage names of `./ft bench campaign`, see STAGES; a worker host only): the host is lost in
    each of those stages, once one of its workers processes a task of it, and brought back after each loss (after
    the last one only with ``back``); a stage that ended before the host was back is listed in ``missed``.

    Waits for the client (at most ``timeout``), asks every worker still there how many tasks it ran, then deletes
    the hosts. Returns what happened: the client's exit code and output, the pids killed, each loss's timeline
    (``losses``: stage, lost_s, dropped_s when the scheduler let its workers go, back_s, registered_s, used_s and
    the first task a new worker of the host processed), the tasks each worker ran (``executed``), the link
    counters."""
    if lose is not None and not lose_in and not lose_on:
        raise ValueError(f'lose={lose!r} needs lose_on (a task key prefix) or lose_in (stages)')
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    res = {'rc': None, 'stdout': '', 'stderr': '', 'removed': [], 'lost_s': None, 'back_s': None,
           'used_after_back': [], 'address': None, 'losses': [], 'missed': [], 'executed': {}, 'lost_workers': []}
    if lose_in and lose not in worker_hosts:
        raise NetnsError(f'lose_in needs a worker host ({worker_hosts}); got {lose!r}')
    names = ('a', *worker_hosts)
    with Star((*names, *((client,) if client not in names else ())), impairment, log_dir=out) as net:
        cluster = DaskHosts(net, env, out / 'logs')
        res['address'] = address = cluster.scheduler('a')
        for h in worker_hosts:
            cluster.workers(h, nworkers)
        watch, seen = cluster.watch(client), queue.Queue()
        threading.Thread(target=_lines, args=(watch.stdout, seen), daemon=True).start()
        cluster.wait(seen, len(worker_hosts) * nworkers)
        say(f'cluster: scheduler {address} in {net.host("a").netns}, {nworkers} workers in each of '
            f'{", ".join(worker_hosts)}; {net.impairment.describe()} ({net.method})')
        t0 = time.monotonic()
        proc = cluster.run(client, 'client', [*client_cmd, '--scheduler', address])
        lost = net.host(lose).address if lose else None
        clock, todo = StageClock(), list(lose_in)
        state = 'up' if lose else 'done'
        gone: set = set()     # worker addresses of the host that were lost
        loss: dict = {}

        def now() -> float:
            return round(time.monotonic() - t0, 1)

        while state != 'done' and proc.poll() is None:
            try:
                line = seen.get(timeout=1.0)
            except queue.Empty:
                continue
            if line is None:
                break
            processing = json.loads(line)
            for keys in processing.values():
                for k in keys:
                    clock.see(k)
            mine = {w: keys for w, keys in processing.items() if f'//{lost}:' in w}
            if lose_in:
                while todo and clock.i > [s for s, _ in STAGES].index(todo[0]):   # that stage ended meanwhile
                    res['missed'].append(todo.pop(0))
            # a worker host is lost while one of its workers runs such a task; another host while any worker does
            busy = mine if lose in worker_hosts else processing
            keys = [k for ks in busy.values() for k in ks]
            hit = (todo and clock.name == todo[0] and keys) if lose_in else \
                any(k.startswith(lose_on) for k in keys)
            if state == 'starting' and set(mine) - gone:   # its new workers registered
                loss['registered_s'] = now()
                state = 'up'
            if state == 'up' and loss and 'used_s' not in loss and any(mine.get(w) for w in set(mine) - gone):
                loss['used_s'] = now()
                loss['used'] = sorted({k for w in set(mine) - gone for k in mine[w]})
                res['used_after_back'] = loss['used']
                say(f'host {lose} in use again at {loss["used_s"]:.1f} s ({clock.name}: {loss["used"][:2]})')
                if not lose_in and back:
                    state = 'done'
            if state == 'up' and hit:
                net.cut(lose)      # the cable first: no FIN or RST of the dying processes gets out
                res['removed'] += net.kill(lose)
                gone |= set(mine)
                loss = {'stage': clock.name, 'lost_s': now(), 'processing': sorted(k for ks in mine.values()
                                                                                    for k in ks)}
                res['losses'].append(loss)
                res['lost_s'] = res['lost_s'] if res['lost_s'] is not None else loss['lost_s']
                if lose_in:
                    todo.pop(0)
                say(f'host {lose} lost at {loss["lost_s"]:.1f} s in {clock.name or "the run"} '
                    f'(processing {loss["processing"]})')
                state = 'lost' if (back or todo) else 'done'
            elif state == 'lost' and not (set(mine) & gone):   # the scheduler let the lost workers go
                loss['dropped_s'] = now()
                net.plug(lose)
                cluster.workers(lose, nworkers)
                loss['back_s'] = res['back_s'] = now()
                say(f'host {lose} back at {loss["back_s"]:.1f} s (the scheduler dropped its workers at '
                    f'{loss["dropped_s"]:.1f} s; they start again)')
                state = 'starting'
        try:
            res['stdout'], res['stderr'] = proc.communicate(timeout=max(1.0, timeout - (time.monotonic() - t0)))
        except subprocess.TimeoutExpired:
            proc.kill()
            res['stdout'], res['stderr'] = proc.communicate()
            res['stderr'] += f'\n(killed after {timeout:g} s)'
        res['rc'] = proc.returncode
        res['seconds'] = time.monotonic() - t0
        res['missed'] += todo
        res['lost_workers'] = sorted(gone)
        res['after_loss_s'] = res['seconds'] - res['losses'][-1]['lost_s'] if res['losses'] else None
        if lose is None or lose in worker_hosts:   # what a worker host brought back ran (the scheduler is there)
            res['executed'] = cluster.executed()
        res['counters'] = net.counters()
        res['method'] = net.method
    res['left'] = net.left()
    return res


def _watch(address: str) -> int:
    from force_tester_common.engine import get_client  # the one module that imports Dask
    client, last = get_client(address, connect_timeout=120.0)[0], None   # the scheduler may still be starting
    while True:
        now = {w: sorted(str(k) for k in keys) for w, keys in client.processing().items()}
        if now != last:
            print(json.dumps(now), flush=True)
            last = now
        time.sleep(WATCH_S)


def _executed_count(dask_worker=None) -> int:   # runs in each worker (client.run)
    return dask_worker.state.executed_count


def _executed(address: str) -> int:
    from force_tester_common.engine import get_client
    client = get_client(address, connect_timeout=30.0)[0]
    print(json.dumps(client.run(_executed_count, on_error='ignore')))
    return 0


if __name__ == '__main__':
    args = sys.argv[1:]
    if args[:1] == ['watch'] and len(args) == 2:
        sys.exit(_watch(args[1]))
    if args[:1] == ['executed'] and len(args) == 2:
        sys.exit(_executed(args[1]))
    sys.exit('usage: python -m netlab.dask_hosts watch ADDRESS | executed ADDRESS')
