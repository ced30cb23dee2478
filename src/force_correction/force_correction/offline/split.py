"""A bag's segments corrected in two processes (offline `correct`, the fast path).

The correction, the scoring and the encoding are Python between numpy calls, so a second thread gains little (the
GIL: docs/speed-setup.md); a second process gets the second core. Once the input's blocks are decoded and the pull
windows known, the parent forks a child that corrects, scores and encodes the later segments, from a block where no
pull window is cut, while the parent does the earlier ones. The child encodes its /force_corrected messages into an
anonymous shared mapping as the output bag lays them out (ExtendedBag.reserve: the bytes do not depend on where
they go in the file) and sends its pulls' outcomes, short events, runs and NaN count through a pipe; the parent then
lays the same messages out in the bag after its own, so the output is byte for byte one process's. The child never
writes to the output file and leaves by os._exit.

The child's exception is raised in the parent; a child that ends without a word (a signal, a crash) is a
CorrectionError naming how it ended. Either way the parent reads the pipe to its end (the child's end of it closes
when the child ends) and reaps the child: no hang, no zombie.
"""
from __future__ import annotations

import os
import pickle
import signal
import threading

import numpy as np

from ..core.errors import CorrectionError

#: fewest pull windows for a second process (fewer: one); ./ft bench startup --pulls N (docs/speed-setup.md)
MIN_PULLS = 8
#: the child's share of the samples: the parent also decodes the pull events before and writes the results after
CHILD_SHARE = 0.5


def spare_core() -> bool:
    """Whether a core of this process's is idle, by the load average of the last minute: where none is, a second
    process only adds its cost (the fork, its page faults) to the CPU the others share."""
    try:
        return os.getloadavg()[0] <= len(os.sched_getaffinity(0)) - 1
    except (OSError, AttributeError):   # no load average or affinity here
        return False


def split_at(plan: list, ends: np.ndarray, stamps: np.ndarray, windows: list, stream) -> int | None:
    """Where the second process's segments begin (an index into ``plan``, [(first block, end block, first block of
    its run)]), or None for one process: too few pulls, no sink that takes the results piece by piece, or no
    segment boundary that cuts no pull window (with an extension, only a run's start: its prefilter's state is the
    run's whole past). ``ends``: cumulative sample counts of the blocks, ``stamps``: their first samples' stamps."""
    if len(windows) < MIN_PULLS or len(plan) < 2 or stream.sink is None or stream.keep \
            or not hasattr(stream.sink, 'alone') or not spare_core():
        return None
    starts = np.array([w[0] for w in windows], dtype=np.int64)
    stops = np.array([w[1] for w in windows], dtype=np.int64)
    total = int(ends[-1])
    best, gap = None, None
    for k in range(1, len(plan)):
        a, _b, lo = plan[k]
        t = stamps[a]
        if (stream.extension is not None and a != lo) or ((starts < t) & (stops > t)).any():
            continue
        g = abs(total - int(ends[a - 1]) - CHILD_SHARE * total)
        if gap is None or g < gap:
            best, gap = k, g
    return best


def in_two(stream, feed, own: list, theirs: list, blocks: tuple, frame: str, resume, progress=None) -> None:
    """feed(own, progress) here and feed(theirs, None) in a forked child, whose results this stream then takes
    (scorer.adopt). ``blocks``: (stamps, sample counts, rates) of each segment's blocks, own and theirs; resume():
    what the child does first (the correction state at its first block)."""
    sink = stream.sink
    mine_blocks, their_blocks = blocks
    t_split = int(their_blocks[0][0][0])
    mine = {i for i, w in enumerate(stream.scorer.windows) if w[0] >= t_split}
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:   # the child: never returns
        os.close(r)
        _child(w, stream, feed, theirs, resume, mine, (mine_blocks, frame))
    os.close(w)
    try:
        feed(own, progress)
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        _answer(r, pid)
        raise
    answer = _answer(r, pid)
    if isinstance(answer, int):
        raise CorrectionError(f'the second process (segments {len(own)} to {len(own) + len(theirs) - 1}) ended '
                              f'with {_how(answer)} before sending its results; expected its scores')
    if answer[0] == 'error':
        raise answer[1]
    _, outcomes, events, runs, nan_count = answer
    stream.runs += runs
    stream.nan_count += nan_count
    stream.scorer.adopt(outcomes, events)
    sink.skip(their_blocks, frame)


def _child(w: int, stream, feed, theirs, resume, mine, before) -> None:
    try:
        resume()
        stream.scorer.keep_only(mine)
        stream.runs = stream.nan_count = 0
        stream.sink.skip(*before)   # where the parent's messages go: ours follow
        stream.sink.alone()
        feed(theirs, None)
        outcomes, events = stream.scorer.settle()
        answer = ('ok', {i: outcomes[i] for i in mine}, events, stream.runs, stream.nan_count)
    except BaseException as exc:  # noqa: BLE001 - raised again by the parent
        answer = ('error', exc)
    try:
        data = pickle.dumps(answer)
    except Exception as exc:  # noqa: BLE001 - an exception that does not pickle: its text
        data = pickle.dumps(('error', CorrectionError(f'the second process failed: {type(exc).__name__}: {exc}; '
                                                      'expected its scores')))
    try:
        view = memoryview(len(data).to_bytes(8, 'little') + data)
        while view.nbytes:
            view = view[os.write(w, view):]
    finally:
        os._exit(0)


def _answer(r: int, pid: int):
    """The child's answer (what it sent, unpickled), or, if it ended before sending it all, its wait status. The
    child is reaped (on a thread once it has answered: its exit then costs this process nothing)."""
    parts, size = [], None
    try:
        while True:
            chunk = os.read(r, 1 << 16)
            if not chunk:
                break
            parts.append(chunk)
            data = b''.join(parts)
            if size is None and len(data) >= 8:
                size = int.from_bytes(data[:8], 'little')
            if size is not None and len(data) >= 8 + size:
                threading.Thread(target=os.waitpid, args=(pid, 0), daemon=True).start()
                return pickle.loads(data[8:8 + size])
    finally:
        os.close(r)
    return os.waitpid(pid, 0)[1]


def _how(status: int) -> str:
    if os.WIFSIGNALED(status):
        return f'signal {os.WTERMSIG(status)} ({signal.Signals(os.WTERMSIG(status)).name})'
    return f'exit status {os.waitstatus_to_exitcode(status)}'
