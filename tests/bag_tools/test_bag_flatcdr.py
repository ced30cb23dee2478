"""Flat messages (fastcdr.encode_flat / decode_flat) against rosbags, and the type facts (typefacts) the fast path
reads them with: the same bytes, definitions and hashes as rosbags gives, kept in the per-user cache."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bag_tools.core import make_typestore
from bag_tools.core.errors import BagError
from bag_tools.core.fastcdr import FLAT_FORMATS, FastPathError, decode_flat, encode_flat
from bag_tools.core.typefacts import flat_layout, type_facts
from force_tester_common.core.cache import CACHE_ENV

MSG_DIR = Path(__file__).resolve().parents[2] / 'src' / 'force_tester_msgs' / 'msg'
TYPES = sorted(f'force_tester_msgs/msg/{p.stem}' for p in MSG_DIR.glob('*.msg'))
FLAT = [t for t in TYPES if type_facts(t).layout is not None]
INTS = {'int8': 8, 'int16': 16, 'int32': 32, 'int64': 64}


@pytest.fixture(scope='module')
def store():
    return make_typestore([MSG_DIR])


def values_of(base: str):
    """A hypothesis strategy of one field's values."""
    if base == 'string':
        return st.text(max_size=12)
    if base == 'bool':
        return st.booleans()
    if base.startswith('float'):
        return st.floats(allow_nan=False, width=32 if base == 'float32' else 64)
    bits = int(base.lstrip('uint'))
    return st.integers(0, 2**bits - 1) if base.startswith('u') else st.integers(-2**(bits - 1), 2**(bits - 1) - 1)


def message(store, type_name: str, values: dict, prefix: str = ''):
    """The rosbags message of a flat dict of field values."""
    fields = {}
    for name, desc in store.fielddefs[type_name][1]:
        nested = desc[0].name == 'NAME'
        fields[name] = message(store, desc[1], values, f'{prefix}{name}.') if nested else values[prefix + name]
    return store.types[type_name](**fields)


def test_the_facts_are_rosbags_definitions_hashes_and_layouts(store):
    """Each type's definition and hash are rosbags'; a layout names every base field (nested ones spelled out) in
    order, and a type with an array has none."""
    assert len(FLAT) >= 3 and 'force_tester_msgs/msg/PullEvent' in FLAT
    for t in TYPES:
        facts = type_facts(t)
        assert facts[:2] == (store.generate_msgdef(t, ros_version=2)[0], store.hash_rihs01(t))
        text = (MSG_DIR / f'{t.rsplit("/", 1)[1]}.msg').read_text()
        has_array = any('[' in line.split('#')[0] for line in text.splitlines())
        assert (facts.layout is None) == has_array, t
    layout = flat_layout('force_tester_msgs/msg/PullEvent')
    assert layout[:3] == (('header.stamp.sec', 'int32'), ('header.stamp.nanosec', 'uint32'),
                          ('header.frame_id', 'string'))
    assert [p for p, _b in layout[3:]] == [n for n, _d in store.fielddefs['force_tester_msgs/msg/PullEvent'][1][1:]]
    with pytest.raises(BagError, match="'force_tester_msgs/msg/ForceBlock' holds an array"):
        flat_layout('force_tester_msgs/msg/ForceBlock')
    with pytest.raises(BagError, match="'force_tester_msgs/msg/Nope' is not defined"):
        type_facts('force_tester_msgs/msg/Nope')


@settings(max_examples=60, deadline=None)
@given(data=st.data(), type_name=st.sampled_from(FLAT))
def test_encode_and_decode_flat_equal_rosbags(store, data, type_name):
    layout = flat_layout(type_name)
    values = {path: data.draw(values_of(base), label=path) for path, base in layout}
    cdr = bytes(store.serialize_cdr(message(store, type_name, values), type_name))
    assert encode_flat(layout, values) == cdr
    decoded = decode_flat(layout, cdr)
    assert encode_flat(layout, decoded) == cdr and list(decoded) == [p for p, _b in layout]
    assert message(store, type_name, decoded) == store.deserialize_cdr(cdr, type_name)
    padded = cdr + bytes(-len(cdr) % 4)   # rmw pads a payload to a multiple of 4
    assert decode_flat(layout, padded) == decoded


def test_flat_messages_that_do_not_fit_are_fast_path_errors():
    layout = flat_layout('force_tester_msgs/msg/PullEvent')
    values = dict.fromkeys((p for p, _b in layout), 1)
    values['header.frame_id'] = 'frame'
    cdr = encode_flat(layout, values)
    cases = {'big-endian': b'\x00\x00' + cdr[2:], 'cut short': cdr[:-1], 'bytes beyond': cdr + bytes(4),
             'string too long': cdr[:12] + struct.pack('<I', 99) + cdr[16:],
             'no NUL': cdr[:16] + b'frame!' + cdr[22:], 'bad UTF-8': cdr[:16] + b'\xff' + cdr[17:]}
    for what, bad in cases.items():
        with pytest.raises(FastPathError):
            decode_flat(layout, bad)
            pytest.fail(what)
    with pytest.raises(FastPathError, match=r'pull_id = -1 is not a uint32'):
        encode_flat(layout, {**values, 'pull_id': -1})
    assert set(FLAT_FORMATS) >= {b for t in FLAT for _p, b in flat_layout(t)}


def test_facts_are_kept_in_the_cache_and_a_damaged_entry_is_made_again(tmp_path, monkeypatch, store):
    """Other message files (a prefix of their own) get an entry of their own; damaged, it is computed anew."""
    msg = tmp_path / 'share' / 'force_tester_msgs' / 'msg'
    shutil.copytree(MSG_DIR, msg)
    (msg / 'Extra.msg').write_text('uint8 a\nstring b\nfloat32 c\n')
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / 'cache'))
    env = {'AMENT_PREFIX_PATH': str(tmp_path)}
    extra = type_facts('force_tester_msgs/msg/Extra', env)
    assert extra.layout == (('a', 'uint8'), ('b', 'string'), ('c', 'float32'))
    (entry,) = (tmp_path / 'cache').glob('msgfacts-*.json')
    kept = json.loads(entry.read_text())
    assert sorted(kept) == sorted([*TYPES, 'force_tester_msgs/msg/Extra'])
    assert kept['force_tester_msgs/msg/PullScore'][1] == store.hash_rihs01('force_tester_msgs/msg/PullScore')
    entry.write_text('{"damaged": ')                     # damaged: made again when next read
    again = {'AMENT_PREFIX_PATH': f'{tmp_path}:{tmp_path}'}   # a new prefix list, so not the facts in memory
    assert type_facts('force_tester_msgs/msg/Extra', again) == extra and json.loads(entry.read_text()) == kept
    (msg / 'Extra.msg').write_text('uint16 a\n')       # other contents: an entry of their own
    other = {'AMENT_PREFIX_PATH': f'{tmp_path}:{tmp_path}:{tmp_path}'}   # (a process reads the files once)
    assert type_facts('force_tester_msgs/msg/Extra', other).layout == (('a', 'uint16'),)
    assert len(list((tmp_path / 'cache').glob('msgfacts-*.json'))) == 2
