"""Per-pull functions for the engine's tests (pickled by value, so the workers need not import this file)."""
from __future__ import annotations

import os
import time
from pathlib import Path


def square_slowly(item):
    """(i, n) -> i * i after a sleep that makes later items finish first; item 'bad' raises."""
    if item == 'bad':
        raise ValueError(f'pull content {item!r} is corrupt')
    i, n = item
    time.sleep(0.02 * (n - i))
    return i * i


def allocator_env(item):
    """The glibc allocator settings this worker process started with."""
    return tuple(os.environ.get(v) for v in ('MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_'))


def die_once(item):
    """(marker folder, i): the first attempt at i == 1 kills its worker process (no exception, no cleanup)."""
    folder, i = item
    marker = Path(folder) / f'attempt_{i}'
    if i == 1 and not marker.exists():
        marker.write_text(str(os.getpid()))
        os._exit(13)
    time.sleep(0.1)
    return (i, os.getpid())


def always_die(item):
    folder, i = item
    if i == 0:
        with open(Path(folder) / 'deaths', 'a') as fh:
            fh.write(f'{os.getpid()}\n')
        os._exit(13)
    return i
