"""What a command would otherwise compute afresh at every start, kept per user on disk (pure Python + numpy):
arrays (cached_array) and plain data (cached_json).

The folder is $FT_CACHE_DIR, else $XDG_CACHE_HOME/force_tester, else ~/.cache/force_tester. A file there is only
a copy of what ``make`` computes: one that is missing, unreadable or not the shape asked for is computed again and
written anew, and a folder that cannot be written is simply not used. Writers replace a file whole (a temporary
name, then a rename), so two processes making the same entry at once leave one good copy.
"""
from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any, Callable, Mapping, Optional

import numpy as np

CACHE_ENV = 'FT_CACHE_DIR'
CACHE_SUBDIR = 'force_tester'   # under $XDG_CACHE_HOME or ~/.cache


def cache_dir(env: Optional[Mapping[str, str]] = None) -> Path:
    """$FT_CACHE_DIR, else $XDG_CACHE_HOME/force_tester, else ~/.cache/force_tester (~ expanded)."""
    env = os.environ if env is None else env
    if env.get(CACHE_ENV):
        return Path(env[CACHE_ENV]).expanduser()
    return Path(env.get('XDG_CACHE_HOME') or '~/.cache').expanduser() / CACHE_SUBDIR


def cached_array(name: str, shape: tuple, make: Callable[[], np.ndarray],
                 env: Optional[Mapping[str, str]] = None) -> np.ndarray:
    """The float64 array of ``shape`` that ``make()`` returns, read from the cache entry ``name`` when it holds
    one (``name``: a file name without extension that says everything the values depend on)."""
    path = cache_dir(env) / f'{name}.npy'
    try:
        got = np.load(path, allow_pickle=False)
        if got.shape == tuple(shape) and got.dtype == np.float64:
            return got
    except (OSError, ValueError, EOFError):
        pass     # missing or damaged: made again below
    made = np.asarray(make(), dtype=np.float64).reshape(shape)
    _keep(path, lambda fh: np.save(fh, made, allow_pickle=False))
    return made


def cached_json(name: str, make: Callable[[], Any], valid: Callable[[Any], bool],
                env: Optional[Mapping[str, str]] = None) -> Any:
    """What ``make()`` returns (JSON data: dicts, lists, strings, numbers), read from the cache entry ``name``
    when it holds data that ``valid`` accepts (``name``: a file name without extension that says everything the
    data depend on)."""
    path = cache_dir(env) / f'{name}.json'
    try:
        got = json.loads(path.read_bytes())
        if valid(got):
            return got
    except (OSError, ValueError):
        pass     # missing or damaged: made again below
    made = make()
    text = json.dumps(made).encode('utf-8')
    _keep(path, lambda fh: fh.write(text))
    return made


def _keep(path: Path, write: Callable) -> None:
    """``write(file)`` into a temporary name beside ``path``, then renamed to it; nothing kept when that fails."""
    tmp = path.with_name(f'.{path.name}.{os.getpid()}.tmp')
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, 'wb') as fh:
            write(fh)
        os.replace(tmp, path)
    except OSError:  # a read-only or full disk, or no folder: the values are right, only not kept
        with contextlib.suppress(OSError):
            tmp.unlink()
