"""Typestore with the ROS 2 Jazzy types plus the force_tester_msgs types.

No rclpy, no generated message modules: the .msg files are parsed with rosbags.
"""

from __future__ import annotations

import functools
import os
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from force_tester_common.core.clock import ns_to_stamp, stamp_to_ns

from .errors import BagError, one_line
from .msgdirs import MSG_PACKAGE, find_msg_dirs, msg_dirs_of, msg_files

#: rosbag2's separator between a definition and each dependency it embeds ('MSG: pkg/msg/Dep').
_DEP_SEPARATOR = '=' * 80
SERVICE_EVENT_SUFFIX = '_Event'


def normalize_type(type_name: str) -> str:
    """A full 'pkg/msg/Type' name; old bags name types 'pkg/Type' (rosbag2 accepts both)."""
    parts = str(type_name).split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    return str(type_name)


def types_from_definition(type_name: str, text: str) -> dict:
    """The rosbags type definitions of type_name from the definition a bag embeds for it.

    A service event ('pkg/srv/Name_Event', or 'pkg/msg/Name_Event' from an old 'pkg/Name_Event'
    name) comes as rosbag2 writes it: the srv text (request
    '---' response) rather than the event's own fields. It is built as the event message
    rosidl generates (service_msgs/ServiceEventInfo info, Request[<=1] request, Response[<=1]
    response); rosbags names parsed types 'pkg/msg/...', so the request and response are
    registered as 'pkg/msg/Name_Request' / '_Response'. Raises whatever rosbags' parser raises.
    """
    parts = type_name.split('/')
    main, sep, deps = text.partition(_DEP_SEPARATOR)
    lines = main.splitlines()
    if len(parts) == 3 and parts[2].endswith(SERVICE_EVENT_SUFFIX) \
            and '---' in (line.strip() for line in lines):  # no message has a '---' line
        pkg, base = parts[0], parts[2][:-len(SERVICE_EVENT_SUFFIX)]
        cut = [line.strip() for line in lines].index('---')
        tail = sep + deps
        types = get_types_from_msg('\n'.join(lines[:cut]) + '\n' + tail,
                                   f'{pkg}/msg/{base}_Request')
        types.update(get_types_from_msg('\n'.join(lines[cut + 1:]) + '\n' + tail,
                                        f'{pkg}/msg/{base}_Response'))
        event = get_types_from_msg(
            f'service_msgs/msg/ServiceEventInfo info\n{pkg}/msg/{base}_Request[<=1] request\n'
            f'{pkg}/msg/{base}_Response[<=1] response\n', f'{pkg}/msg/{base}_Event')
        types[type_name] = event.pop(f'{pkg}/msg/{base}_Event')
        return types
    return get_types_from_msg(text, type_name)


def make_typestore(msg_dirs: Iterable[str | os.PathLike[str]]) -> Typestore:
    """ROS2_JAZZY typestore + every .msg found in msg_dirs registered as 'pkg/msg/Name'.

    Each entry is a '<pkg>/msg' directory (package = name of its parent directory,
    e.g. '<prefix>/share/force_tester_msgs/msg') or a single .msg file in such a
    directory. Earlier entries win when the same type appears twice (overlay order).
    """
    if isinstance(msg_dirs, (str, os.PathLike)):
        msg_dirs = [msg_dirs]
    dirs = [Path(d) for d in msg_dirs]
    if not dirs:
        raise BagError('no message definition directories given; expected at least one '
                       f'<prefix>/share/{MSG_PACKAGE}/msg directory')
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for directory in dirs:
        for package, file in msg_files(directory):
            name = f'{package}/msg/{file.stem}'
            if name in types:
                continue
            try:
                types.update(get_types_from_msg(file.read_text(encoding='utf-8'), name))
            except Exception as exc:  # noqa: BLE001 - parser errors are many types
                raise BagError(f'cannot parse message definition {str(file)!r}: '
                               f'{one_line(exc)}') from None
    try:
        store.register(types)
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot register message types from {[str(d) for d in dirs]!r}: '
                       f'{one_line(exc)}') from None
    return store


def default_typestore(env: Mapping[str, str] = os.environ) -> Typestore:
    """make_typestore(find_msg_dirs(env))."""
    return make_typestore(find_msg_dirs(env))


# The only standard types the force_tester_msgs types use (definitions as in ROS 2 Jazzy).
_STD_TYPES = {'builtin_interfaces/msg/Time': 'int32 sec\nuint32 nanosec\n',
              'std_msgs/msg/Header': 'builtin_interfaces/Time stamp\nstring frame_id\n'}


def _named(fields) -> list:
    """The message types that a parsed definition's fields name (of arrays and sequences too)."""
    out = []
    for _field, desc in fields:
        while desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            desc = desc[1][0]
        if desc[0] == Nodetype.NAME:
            out.append(desc[1])
    return out


class _Shared:
    """The shared store of some msg directories: a type is parsed and registered, with the types it uses, when it
    is first asked for (parsing and registering all 16 costs ~15 ms; `./ft bag correct` uses 6 of them)."""

    def __init__(self, dirs: tuple) -> None:
        self.store = get_typestore(Stores.EMPTY)  # ~10x faster to build than the full Jazzy store
        self.files: dict = {}
        for directory in dirs:
            for package, file in msg_files(directory):
                self.files.setdefault(f'{package}/msg/{file.stem}', file)   # earlier directories win
        self.lock = threading.Lock()

    def having(self, names: Iterable[str]) -> Typestore:
        """The store, with ``names`` (and what they use) registered; a name it does not define is left for the
        store to report when it is used."""
        todo = [n for n in names if n not in self.store.fielddefs]
        if not todo:
            return self.store
        with self.lock:
            types: dict = {}
            while todo:
                name = todo.pop()
                if name in types or name in self.store.fielddefs:
                    continue
                text = _STD_TYPES.get(name)
                if text is None and name in self.files:
                    text = self.files[name].read_text(encoding='utf-8')
                if text is not None:
                    parsed = get_types_from_msg(text, name)
                    types.update(parsed)
                    todo += [n for _consts, fields in parsed.values() for n in _named(fields)]
            if types:
                self.store.register(types)
        return self.store


@functools.lru_cache(maxsize=4)
def _shared(dirs: tuple) -> _Shared:
    return _Shared(dirs)


def shared_typestore(env: Mapping[str, str] = os.environ, names: Iterable[str] | None = None) -> Typestore:
    """The force_tester_msgs types (with std_msgs/Header and builtin_interfaces/Time), one store per process (and
    AMENT_PREFIX_PATH) for read-only use: serialising, deserialising, definitions and hashes (the same as
    default_typestore's; tested). ``names``: the types the caller uses, which it is sure to hold (with the types
    they use); None: every type. Never register types into it."""
    shared = _shared(msg_dirs_of(env.get('AMENT_PREFIX_PATH', '')))
    return shared.having([*_STD_TYPES, *shared.files] if names is None else names)


def flat_fields(store: Typestore, type_name: str, formats) -> list | None:
    """[[field path, base type], ...] of a type with its nested types spelled out ('header.stamp.sec'), when every
    field is a base type in ``formats`` or such a type; None when one is an array, a sequence or another type."""
    out = []
    for name, desc in store.fielddefs[type_name][1]:
        if desc[0] == Nodetype.NAME:
            inner = flat_fields(store, desc[1], formats)
            if inner is None:
                return None
            out += [[f'{name}.{path}', base] for path, base in inner]
        elif desc[0] == Nodetype.BASE and desc[1][0] in formats:
            out.append([name, desc[1][0]])
        else:
            return None
    return out


def header(store: Typestore, stamp_ns: int, frame_id: str = ''):
    """A std_msgs/Header of ``store``'s types stamped at ``stamp_ns``."""
    T = store.types
    sec, nanosec = ns_to_stamp(stamp_ns)
    return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec),
                                    frame_id=frame_id)


def stamp_of(msg: Any) -> int:
    """A message's header stamp, ns."""
    return stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
