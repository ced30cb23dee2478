"""What the fast paths need of a force_tester_msgs type, without building a rosbags typestore.

A type's facts are its definition text and RIHS01 hash (what an MCAP schema holds) and, for a type of base fields
and nested types only, its flat layout (fastcdr.encode_flat / decode_flat). rosbags computes them once for a set of
.msg files; the per-user cache (force_tester_common.core.cache) keeps them under a name made from the files'
contents, so a command started again imports no rosbags module (about 35 ms of `./ft bag correct`'s start:
benchmarks/bench_startup.py).
"""

from __future__ import annotations

import functools
import os
import zlib
from collections.abc import Mapping
from typing import NamedTuple

from force_tester_common.core.cache import cached_json

from .errors import BagError
from .fastcdr import FLAT_FORMATS
from .msgdirs import msg_dirs_of, type_files

#: Bumped when what an entry holds changes (old entries are then not read).
FACTS_VERSION = 1


class TypeFacts(NamedTuple):
    """A message type's ros2msg definition text, its RIHS01 hash and its flat layout ((field path, base type),
    ...; None when the type holds an array or a type encode_flat does not write)."""

    text: str
    rihs01: str
    layout: tuple | None


def type_facts(type_name: str, env: Mapping[str, str] = os.environ) -> TypeFacts:
    """The facts of a type of the force_tester_msgs directories that AMENT_PREFIX_PATH names (found once)."""
    dirs = msg_dirs_of(env.get('AMENT_PREFIX_PATH', ''))
    facts = _facts(dirs)
    if type_name not in facts:
        raise BagError(f'message type {type_name!r} is not defined in {[str(d) for d in dirs]!r}; expected one '
                       f'of {sorted(facts)!r}')
    return facts[type_name]


def flat_layout(type_name: str, env: Mapping[str, str] = os.environ) -> tuple:
    """type_facts(type_name).layout, which the type must have."""
    layout = type_facts(type_name, env).layout
    if layout is None:
        raise BagError(f'message type {type_name!r} holds an array or a type fastcdr does not write; expected a '
                       'type of base fields and nested types only')
    return layout


@functools.lru_cache(maxsize=4)
def _facts(dirs: tuple) -> dict:
    files = type_files(dirs)
    names = sorted(files)
    key = zlib.crc32(b'\x00'.join(name.encode() + b'\x01' + files[name].read_bytes() for name in names))
    got = cached_json(f'msgfacts-{FACTS_VERSION}-{len(names)}-{key:08x}', lambda: _compute(dirs, names),
                      lambda data: isinstance(data, dict) and sorted(data) == names and all(
                          isinstance(v, list) and len(v) == 3 for v in data.values()))
    return {name: TypeFacts(text, rihs01, None if layout is None else tuple(map(tuple, layout)))
            for name, (text, rihs01, layout) in got.items()}


def _compute(dirs: tuple, names: list) -> dict:
    """{type: [text, rihs01, layout]} of the named types in dirs, from rosbags."""
    from .typestore import flat_fields, make_typestore  # rosbags: only when the cache has no entry
    store = make_typestore(list(dirs))
    return {name: [store.generate_msgdef(name, ros_version=2)[0], store.hash_rihs01(name),
                   flat_fields(store, name, FLAT_FORMATS)] for name in names}
