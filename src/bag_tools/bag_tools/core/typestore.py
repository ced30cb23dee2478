"""Typestore with the ROS 2 Jazzy types plus the force_tester_msgs types.

No rclpy, no generated message modules: the .msg files are parsed with rosbags.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype
from rosbags.typesys.store import Typestore

from force_tester_common.core.clock import ns_to_stamp, stamp_to_ns

from .errors import BagError, one_line
from .msgdirs import MSG_PACKAGE, find_msg_dirs, type_files

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
    for name, file in type_files(dirs).items():
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
