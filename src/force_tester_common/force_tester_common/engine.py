"""The campaign engine: map a per-pull function over the pulls of a campaign on Dask.

``map_pulls(fn, items, names=..., scheduler=...)`` runs ``fn(item)`` for every item and returns a
:class:`PullMap` whose ``results`` are in the order of ``items``, whichever worker ran which pull and
in whatever order they finished; nothing is reduced on the way, so the numbers cannot depend on the
worker count or the completion order.

Where it runs (``resolve_scheduler``):
1. the ``scheduler`` argument, e.g. ``'tcp://HOST:8786'`` (a running ``dask scheduler``);
2. else the environment variable ``DASK_SCHEDULER_ADDRESS``;
3. else the embedded default: a ``distributed.LocalCluster`` started in this process on first use,
   one single-threaded worker process per CPU (``os.cpu_count()``; processes, so numpy-heavy pulls
   run in parallel), kept for later calls and closed at exit. A job of one item runs inline (in
   this process, no Dask), and so does ``scheduler='inline'``: the same function on the same item,
   hence the same result.

A pull that raises on a worker does not stop the others: it is caught on the worker and listed in
``PullMap.failed`` as (name, one line). A worker that dies (killed, out of memory, segfault) is not
an exception in the pull: the scheduler reruns the tasks it held on another worker, up to
``distributed.scheduler.allowed-failures`` times (the embedded cluster sets it to ``retries``; a
cluster of your own keeps its scheduler's setting, 3 by default), after which the pull fails with
KilledWorker. Those reruns are read back from the scheduler's own event log: each unexpected
``remove-worker`` event names the tasks that were processing on the worker (and results it held
that were lost); those pulls are listed in ``PullMap.retried``.

An address that does not answer within ``connect_timeout`` (3 s) raises :class:`EngineError` with
one line naming the address and what was expected; the CLIs exit 2 on it. So does a scheduler lost during
the map (its host gone, its link cut): the client notices when its connection has had no answer for
LINK_TIMEOUT (Dask's TCP timeout, set here for the clients this module makes), tries ``connect_timeout`` to
reconnect, and the pulls still in flight are then cancelled: map_pulls raises EngineError instead of
reporting them as failed pulls, and the outputs being written are removed as on any error.

Workers need this workspace's packages: the embedded cluster's workers are spawned from this
process (same interpreter, same ``sys.path``); a cluster's workers must run the same venv or have
the packages installed (docs/campaigns.md). Functions and items are pickled by reference
to their module, so ``fn`` must be a top-level function of an importable module.

Importing this module is cheap: dask and distributed are imported on first use.
"""
from __future__ import annotations

import atexit
import functools
import os
import threading
from typing import Any, Callable, Iterable, List, Optional, Sequence, Tuple

# the in-process map (``scheduler='inline'``), its result type and failure line live in core.mapping
from .core.mapping import INLINE, PullMap, map_here, one_line, pull_name

#: Environment variable naming the scheduler when no --scheduler is given (Dask's own name for it).
SCHEDULER_ENV = 'DASK_SCHEDULER_ADDRESS'
#: Seconds to wait for a scheduler to answer before giving up (Dask retries a refused connection until then;
#: a CLI's whole answer, interpreter start included, must come within 10 s).
CONNECT_TIMEOUT_S = 3.0
#: Reruns of a pull whose worker died (the embedded cluster's allowed-failures).
RETRIES = 2
#: The embedded cluster fails a task that has found no live worker for this long (Dask's no-workers-timeout;
#: its default waits forever): workers whose restarts keep failing become a reported pull, not a hang.
NO_WORKERS_TIMEOUT = '300s'
#: A connection to the scheduler with no answer for this long is broken (Dask's distributed.comm.timeouts.tcp, its
#: default, made explicit for the clients this module makes): a lost scheduler ends a map after about this long.
LINK_TIMEOUT = '30s'
#: A worker whose resident memory is above this when a pull returns gives its allocator's free pages back to the
#: system (glibc's malloc_trim): the heap that ./ft keeps for reuse (MALLOC_TRIM_THRESHOLD_) then does not pile up
#: over a long discover's stages (docs/speed-discover.md). Below it nothing is trimmed: a trim after every pull
#: cost 8 % more CPU in pages faulted in again.
TRIM_ABOVE_BYTES = 256 * 2 ** 20


class EngineError(Exception):
    """The engine cannot run: an unreachable or invalid scheduler address, a lost scheduler. The message
    names the address and what was expected."""


def resolve_scheduler(scheduler: Optional[str] = None) -> Optional[str]:
    """The address to use: ``scheduler``, else $DASK_SCHEDULER_ADDRESS, else None (the embedded
    cluster). 'inline' is returned as is."""
    for value in (scheduler, os.environ.get(SCHEDULER_ENV)):
        if value is not None and str(value).strip():
            return str(value).strip()
    return None


def _run_one(fn: Callable, item: Any) -> tuple:
    """Runs on the worker: ('ok', result) or ('error', one line). Catching here keeps a pull's own
    exception out of Dask's retries (a corrupt file is corrupt on every worker)."""
    try:
        return 'ok', fn(item)
    except Exception as exc:  # noqa: BLE001 - reported by name, the rest goes on
        return 'error', one_line(exc)
    finally:
        trim_above(TRIM_ABOVE_BYTES)


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    """(glibc's malloc_trim, the page size), or None where there is none (not glibc)."""
    try:
        import ctypes
        return ctypes.CDLL(None).malloc_trim, os.sysconf('SC_PAGE_SIZE')
    except (OSError, AttributeError, ValueError):
        return None


def trim_above(limit: int) -> bool:
    """If this process's resident memory is above limit bytes, return the allocator's free pages to the system
    (glibc's malloc_trim(0)); True when it trimmed. Elsewhere (no glibc, no /proc) it does nothing."""
    trim = _malloc_trim()
    if trim is None:
        return False
    try:
        with open('/proc/self/statm', 'rb') as f:
            resident = int(f.read().split()[1]) * trim[1]
    except (OSError, ValueError, IndexError):
        return False
    if resident <= limit:
        return False
    trim[0](0)
    return True


# --------------------------------------------------------------------------- clients
_lock = threading.Lock()
_clients: dict = {}   # address or None (embedded) -> (client, cluster or None, description)


def _embedded(retries: int):
    import logging

    import dask
    from distributed import Client, LocalCluster
    n = len(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else (os.cpu_count() or 1)
    # a task that finds no worker for NO_WORKERS_TIMEOUT fails (its pull is reported) instead of waiting forever
    with dask.config.set({'distributed.scheduler.allowed-failures': int(retries),
                          'distributed.scheduler.no-workers-timeout': NO_WORKERS_TIMEOUT}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host='127.0.0.1',
                               dashboard_address=':0', silence_logs=logging.CRITICAL)
    client = Client(cluster, set_as_default=False)
    return client, cluster, f'embedded LocalCluster ({n} worker processes x 1 thread) at {cluster.scheduler_address}'


def _probe(address: str, timeout: float) -> None:
    """One plain TCP connect before Dask is imported (check_scheduler: a CLI's address): a port nobody listens
    on is refused at once, so the one line comes in well under a second instead of after Dask's retries for the
    whole timeout. get_client itself keeps trying for its timeout (a scheduler that is still starting)."""
    scheme, rest = address.split('://', 1)
    host, _, port = rest.rpartition(':')
    if scheme != 'tcp' or not port.isdigit():
        return   # another transport, or no port: Dask's own connect judges it
    import socket  # here: a command that never probes a scheduler (./ft bag correct) does not pay for it
    try:
        socket.create_connection((host.strip('[]') or '127.0.0.1', int(port)), timeout=timeout).close()
    except OSError as exc:
        why = f'no answer within {timeout:g} s' if isinstance(exc, TimeoutError) else (exc.strerror or one_line(exc))
        raise _unreachable(address, why.lower()) from None


def _unreachable(address: str, why: str) -> EngineError:
    return EngineError(f'scheduler {address!r} is unreachable ({why}); expected a running dask scheduler there '
                       f'(no --scheduler, no ${SCHEDULER_ENV}: a local one)')


def _connect(address: str, timeout: float):
    if '://' not in address or not address.split('://', 1)[1]:
        raise EngineError(f'scheduler address {address!r} is invalid; expected tcp://HOST:PORT '
                          f'(a running dask scheduler), or leave out --scheduler and ${SCHEDULER_ENV} '
                          'for the embedded cluster')
    import logging

    import dask
    from distributed import Client
    # a lost scheduler is reported as one EngineError line (map_pulls), not also as Dask's log of the reconnection
    logging.getLogger('distributed.client').setLevel(logging.CRITICAL)
    try:
        with dask.config.set({'distributed.comm.timeouts.tcp': LINK_TIMEOUT}):
            client = Client(address, timeout=timeout, set_as_default=False)
    except Exception as exc:  # noqa: BLE001 - refused, unresolvable, timed out, not a scheduler
        why = f'no answer within {timeout:g} s' if 'Timed out' in str(exc) else one_line(exc)
        raise _unreachable(address, why) from None
    info = client.scheduler_info()
    workers = info.get('workers', {})
    threads = sum(w.get('nthreads', 0) for w in workers.values())
    return client, None, f'{address} ({len(workers)} workers, {threads} threads)'


def get_client(scheduler: Optional[str] = None, *, retries: int = RETRIES,
               connect_timeout: float = CONNECT_TIMEOUT_S):
    """(distributed.Client, description) for ``scheduler`` (resolved as in map_pulls; not 'inline'),
    made on first use and kept for the life of the process."""
    address = resolve_scheduler(scheduler)
    if address == INLINE:
        raise EngineError(f"scheduler {INLINE!r} runs in this process and has no Dask client; expected an "
                          'address or the embedded default')
    with _lock:
        entry = _clients.get(address)
        if entry is not None and entry[0].status not in ('running', 'connecting'):
            _close(address)
            entry = None
        if entry is None:
            entry = _embedded(retries) if address is None else _connect(address, connect_timeout)
            _clients[address] = entry
    return entry[0], entry[2]


def _close(address) -> None:
    client, cluster, _ = _clients.pop(address)
    try:
        client.close()
        if cluster is not None:
            cluster.close()
    except Exception:  # noqa: BLE001,S110 - closing at exit: nothing left to report to
        pass


def shutdown(scheduler: Optional[str] = '*') -> None:
    """Close the client this process made for ``scheduler`` (None: the embedded cluster, which closes too);
    by default every client. Called at exit."""
    with _lock:
        for address in list(_clients):
            if scheduler == '*' or address == scheduler:
                _close(address)


atexit.register(shutdown)


def check_scheduler(scheduler: Optional[str] = None, *, connect_timeout: float = CONNECT_TIMEOUT_S) -> str:
    """Connect now (a CLI calls this before its long reads, so a bad address fails fast). Returns the
    description; EngineError when the address is not usable. The embedded default and 'inline' need
    no connection."""
    address = resolve_scheduler(scheduler)
    if address is None or address == INLINE:
        return INLINE if address == INLINE else 'embedded LocalCluster (started on first use)'
    if '://' in address:
        _probe(address, connect_timeout)
    return get_client(address, connect_timeout=connect_timeout)[1]


def add_scheduler_argument(parser) -> None:
    """The --scheduler option of every CLI that maps pulls (argparse; no Dask imported)."""
    parser.add_argument('--scheduler', metavar='ADDRESS', default=None,
                        help=f'Dask scheduler to run the per-pull work on, e.g. tcp://HOST:8786 (default: '
                        f'${SCHEDULER_ENV}, else a local cluster in this process, one worker per CPU; '
                        f'{INLINE!r}: in this process, one pull at a time)')


# --------------------------------------------------------------------------- map
def map_pulls(fn: Callable, items: Iterable, *, names: Optional[Sequence[str]] = None,
              scheduler: Optional[str] = None, progress: Optional[Callable[[int, int], None]] = None,
              retries: int = RETRIES, keep: bool = True,
              on_result: Optional[Callable[[int, Any], None]] = None,
              connect_timeout: float = CONNECT_TIMEOUT_S, inline_max: int = 1,
              total: Optional[int] = None) -> PullMap:
    """Run ``fn(item)`` for every item; results in item order (see the module docstring).

    names: one per item, used in ``failed`` and ``retried`` (default 'pull 1', 'pull 2', ...); read when
        needed, so a list that the items' iterator fills as it goes will do.
    progress(done, total): called as pulls finish (total: the argument, else len(items), else 0).
    retries: reruns after a worker death (embedded cluster only; a cluster keeps its own setting). A pull
        that still fails with KilledWorker runs once more alone, since the scheduler blames every task a
        dying worker held; results after it wait for that (on_result stays in item order).
    keep: False drops the results after ``on_result`` saw them (bounded memory for big campaigns).
    on_result(index, result): called in item order for each pull that succeeded.
    inline_max: jobs of at most this many items run inline when no scheduler was asked for.
    Items are submitted a few per worker thread at a time, so an iterator of large items (arrays)
    is read only as fast as the workers take them.
    """
    address = resolve_scheduler(scheduler)
    if total is None:
        try:
            total = len(items)  # type: ignore[arg-type]
        except TypeError:
            total = 0
    if address == INLINE or (address is None and total and total <= inline_max):
        return map_here(fn, items, names=names, progress=progress, total=total, keep=keep, on_result=on_result)
    client, where = get_client(address, retries=retries, connect_timeout=connect_timeout)
    return _map_dask(client, where, fn, items, names, progress, total, keep, on_result)


class Mapper:
    """map_pulls bound to one scheduler, remembering every PullMap it returned: what a CLI hands to the
    cores as their ``mapper=`` (they call it like map_pulls), then reports from (``retried``, ``where``)."""

    def __init__(self, scheduler: Optional[str] = None, **options) -> None:
        self.scheduler = scheduler
        self.options = options
        self.runs: List[PullMap] = []

    def __call__(self, fn: Callable, items: Iterable, **kwargs) -> PullMap:
        done = map_pulls(fn, items, scheduler=self.scheduler, **{**self.options, **kwargs})
        self.runs.append(done)
        return done

    @property
    def retried(self) -> List[str]:
        return [name for r in self.runs for name in r.retried]

    @property
    def failed(self) -> List[Tuple[str, str]]:
        return [f for r in self.runs for f in r.failed]

    @property
    def where(self) -> str:
        return self.runs[-1].scheduler if self.runs else 'nothing run'


def _settle(out: PullMap, i: int, status: str, value, names, keep, on_result) -> None:
    if status == 'ok':
        if on_result is not None:
            on_result(i, value)
        out.results.append(value if keep else None)
    else:
        out.failed.append((pull_name(names, i), value))
        out.results.append(None)


def _map_dask(client, where, fn, items, names, progress, total, keep, on_result) -> PullMap:
    import dask
    from distributed import as_completed
    token = os.urandom(6).hex()
    prefix = f'pull-{getattr(fn, "__name__", "fn")}-{token}'
    out = PullMap(scheduler=where)
    it = iter(enumerate(items))
    pending: dict = {}        # future key -> (item index, item), while in flight
    keys: dict = {}           # every key submitted -> item index, for the rerun report
    ready: dict = {}          # item index -> (status, value), waiting for its predecessors
    suspects: list = []       # (index, item) of pulls failed with KilledWorker beside others
    state = {'next': 0, 'done': 0}
    ac = as_completed(loop=client.loop)

    def window() -> int:
        try:
            threads = sum(client.nthreads().values())
        except Exception:  # noqa: BLE001 - the next refill asks again
            threads = 1
        return 2 * max(threads, 1) + 2

    def submit(i: int, item, key: str):
        # an item may carry a pull's arrays (tens of MB, read from a bag here): that is the task's payload,
        # not a graph that repeats data, so Dask's large-graph warning does not apply
        with dask.config.set({'distributed.admin.large-graph-warning-threshold': '2GB'}):
            fut = client.submit(_run_one, fn, item, key=key, pure=False, retries=0)
        pending[key] = (i, item, fut)
        keys[key] = i
        return fut

    def refill(n: int) -> int:
        k = 0
        while k < n:
            nxt = next(it, None)
            if nxt is None:
                break
            ac.add(submit(nxt[0], nxt[1], f'{prefix}-{nxt[0]}'))
            k += 1
        return k

    def settle(i: int, result: tuple) -> None:
        ready[i] = result
        state['done'] += 1
        while state['next'] in ready:
            status, value = ready.pop(state['next'])
            _settle(out, state['next'], status, value, names, keep, on_result)
            state['next'] += 1
        if progress:
            progress(state['done'], total)

    def outcome(fut) -> tuple:
        """(status, value) of a finished future, and whether its workers died under it. A future whose result was
        lost with its worker after it finished ('lost', or 'pending' again: a worker that another pull killed held
        it) runs again, alone, like a pull that shared a dying worker (test_engine's kill-every-worker test met it
        twice in 18 fresh runs, the pull reported failed with no error)."""
        if fut.status == 'finished':
            return fut.result(), False
        if fut.status in ('lost', 'pending'):
            return ('error', 'its result was lost with the worker that held it'), True
        try:
            exc = fut.exception()
        except Exception as e:  # noqa: BLE001 - cancelled: reported like any failure
            exc = e
        return ('error', _death_line(exc)), type(exc).__name__ == 'KilledWorker'

    def check_scheduler(fut) -> None:
        """A future cancelled though we cancelled nothing, or a client no longer running: the scheduler is gone
        (or dropped our tasks), and no pull still in flight can come back."""
        if fut.status != 'finished' and (fut.status == 'cancelled' or client.status != 'running'):
            raise OSError(f'{pull_name(names, keys[fut.key])} {fut.status}, client {client.status}')

    try:
        in_flight = refill(window())
        while in_flight:
            fut = next(ac)
            in_flight -= 1
            i, item, _f = pending.pop(fut.key)
            check_scheduler(fut)
            result, killed = outcome(fut)
            fut.release()
            if killed:
                suspects.append((i, item))
            else:
                settle(i, result)
            in_flight += refill(max(0, window() - in_flight))
        # A worker's death counts against every task it held, the queued ones too: a pull that only shared a
        # dying worker with the culprit can fail with KilledWorker. Each such pull runs once more, alone.
        for i, item in suspects:
            fut = submit(i, item, f'{prefix}-{i}-alone')
            try:
                fut.exception()   # waits until the pull is done (None when it succeeded)
            except Exception:  # noqa: BLE001,S110 - outcome() reads what happened
                pass
            pending.pop(fut.key)
            check_scheduler(fut)
            result, _ = outcome(fut)
            fut.release()
            settle(i, result)
    except (OSError, TimeoutError) as exc:
        _cancel(client, pending)
        raise EngineError(f'lost the scheduler {where.split(" (")[0]} during the campaign ({one_line(exc)}); '
                          'expected it to stay up until the last pull') from None
    except BaseException:   # the items' iterator or on_result raised, or Ctrl-C: stop the pulls in flight
        _cancel(client, pending)
        raise
    out.retried = _reran(client, keys, names)
    return out


def _cancel(client, pending: dict) -> None:
    try:
        client.cancel([f for _i, _item, f in pending.values()])
    except Exception:  # noqa: BLE001,S110 - the scheduler is gone: nothing runs for us any more
        pass
    pending.clear()


def _death_line(exc: BaseException) -> str:
    if type(exc).__name__ == 'KilledWorker':
        return (f'KilledWorker: the workers running this pull died {getattr(exc, "allowed_failures", 0) + 1} '
                'times (out of memory, killed, crashed); not retried again')
    return one_line(exc)


def _reran(client, keys: dict, names) -> List[str]:
    """Names of the pulls the scheduler reran after an unexpected worker removal, from its event log."""
    try:
        events = client.get_events('all')
    except Exception:  # noqa: BLE001 - a scheduler that keeps no events: nothing known
        return []
    hit = set()
    for _t, msg in events:
        if not isinstance(msg, dict) or msg.get('action') != 'remove-worker' or msg.get('expected'):
            continue
        for key in (*msg.get('processing-tasks', ()), *msg.get('lost-computed-tasks', ())):
            if key in keys:
                hit.add(keys[key])
    return [pull_name(names, i) for i in sorted(hit)]


__all__ = ['EngineError', 'PullMap', 'Mapper', 'map_pulls', 'add_scheduler_argument', 'resolve_scheduler',
           'check_scheduler', 'get_client', 'shutdown', 'SCHEDULER_ENV', 'INLINE', 'CONNECT_TIMEOUT_S', 'RETRIES']
