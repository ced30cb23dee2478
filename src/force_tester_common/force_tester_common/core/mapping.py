"""The per-pull map run here, in this process (ROS-free, standard library only).

``map_here(fn, items)`` is the one in-process loop: the cores run their pulls with it when no
``mapper=`` is given, and force_tester_common.engine runs an inline job (``scheduler='inline'``, or
a job of one item) with it. Its :class:`PullMap` is the engine's.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, List, Optional, Sequence, Tuple

#: ``scheduler`` value (and ``PullMap.scheduler``) of the pulls run in this process, one after the other.
INLINE = 'inline'


@dataclass
class PullMap:
    """What a map did (``map_here``, ``force_tester_common.engine.map_pulls``).

    results: one per item, in the order of the items; None for a failed pull (and for every pull
        when ``keep=False``).
    failed: (name, one line) per pull that raised or whose workers died too often, in item order.
    retried: names of the pulls the scheduler reran because a worker died under them, in item order.
    scheduler: where it ran ('inline', 'embedded LocalCluster ...' or the address and its workers).
    """
    results: List[Any] = field(default_factory=list)
    failed: List[Tuple[str, str]] = field(default_factory=list)
    retried: List[str] = field(default_factory=list)
    scheduler: str = INLINE

    @property
    def ok(self) -> bool:
        return not self.failed


def one_line(exc: BaseException) -> str:
    """'Type: message' on one line (the exception's type name alone when it has no message)."""
    msg = ' '.join(str(exc).split())
    return f'{type(exc).__name__}: {msg}' if msg else type(exc).__name__


def pull_name(names: Optional[Sequence[str]], i: int) -> str:
    """Item i's name in ``failed`` and ``retried``: names[i], else 'pull i+1'."""
    return str(names[i]) if names is not None and i < len(names) else f'pull {i + 1}'


def map_here(fn: Callable, items: Iterable, *, names: Optional[Sequence[str]] = None,
             progress: Optional[Callable[[int, int], None]] = None, total: int = 0, keep: bool = True,
             on_result: Optional[Callable[[int, Any], None]] = None, catch=Exception) -> PullMap:
    """``fn(item)`` for every item, here, in item order.

    catch: the exception type(s) that fail one pull (listed in ``failed`` as (name, one line), its
        result None) while the others go on; any other exception stops the map and propagates
        (``catch=()``: the first error does).
    progress(done, total), keep, on_result(index, result), names: as ``engine.map_pulls``.
    """
    out = PullMap(scheduler=INLINE)
    for i, item in enumerate(items):
        try:
            value = fn(item)
        except catch as exc:
            out.failed.append((pull_name(names, i), one_line(exc)))
            out.results.append(None)
        else:
            if on_result is not None:
                on_result(i, value)
            out.results.append(value if keep else None)
        if progress:
            progress(i + 1, total)
    return out


__all__ = ['INLINE', 'PullMap', 'one_line', 'pull_name', 'map_here']
