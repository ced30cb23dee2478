"""Where a test's time goes: the seconds it spends making campaigns and in `discover`, and its kind.

conftest.py wraps the campaign makers and `discover` with `timed` at start-up, adds each test's seconds to its
report (`user_properties`, which pytest-xdist carries from the workers), and `--record-durations FILE` writes them
with the test's kind; `./ft bench tests` prints the table of docs/tests.md from that file. The wrappers only time:
they return what the wrapped function returns.
"""
from __future__ import annotations

import functools
import time
from collections import defaultdict

#: the kinds a test's time is put under, in the table's order: the first two are measured inside the test, the
#: rest of a test's time goes to its marker's kind (ros, browser, netns), or to 'rest'
KINDS = ('campaign', 'discover', 'ros', 'browser', 'netns', 'rest')
LABELS = {'campaign': 'making campaigns', 'discover': '`discover`', 'ros': 'ROS graphs and nodes',
          'browser': 'the browser', 'netns': 'network namespaces', 'rest': 'the rest'}
#: the markers that name a test's kind (conftest.py registers them; each also makes the test `slow`), the most
#: telling first: a browser test also starts ROS nodes
MARKED_KINDS = ('netns', 'browser', 'ros')

#: a fast-tier test over this many seconds (setup + call + teardown) is named at the end of a run, to be marked slow
FAST_S = 5.0

_spent: dict = defaultdict(float)
_depth: dict = defaultdict(int)


def timed(kind: str):
    """Decorate a function so that the time spent in it counts as KIND (an inner call of the same kind counts once)."""
    def wrap(fn):
        if getattr(fn, '_timed_kind', None) == kind:
            return fn

        @functools.wraps(fn)
        def timed_fn(*args, **kwargs):
            _depth[kind] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                _depth[kind] -= 1
                if _depth[kind] == 0:
                    _spent[kind] += time.perf_counter() - t0
        timed_fn._timed_kind = kind
        return timed_fn
    return wrap


def take() -> dict:
    """The seconds spent per measured kind since the last call, and start again from zero."""
    out = {k: round(v, 4) for k, v in _spent.items() if v}
    _spent.clear()
    return out


def kind_of(markers) -> str:
    """The kind a test's own time goes under, from the names of its markers."""
    return next((k for k in MARKED_KINDS if k in markers), 'rest')
