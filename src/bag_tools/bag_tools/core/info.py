"""Summarise a bag: topics, counts, block sample rates and seq gaps, pulls found."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from rosbags.typesys.store import Typestore

from force_tester_common.core.channels import PULL_EVENT_TYPE, PULL_START
from force_tester_common.core.clock import NS_PER_S

from .errors import BagError, one_line
from .msgdirs import MSG_PACKAGE
from .reader import BagReaderHandle, open_bag


def _iso(ns: int) -> str:
    return datetime.fromtimestamp(ns / NS_PER_S, tz=timezone.utc).isoformat(timespec='milliseconds')


def _is_block_type(bag: BagReaderHandle, type_name: str) -> bool:
    """A block message (fields seq and sample_rate_hz) of ours. Only force_tester_msgs types
    are built to find out: a foreign type info cannot decode is listed, never built."""
    if not type_name.startswith(f'{MSG_PACKAGE}/'):
        return False
    cls = bag.type_class(type_name)
    fields = getattr(cls, '__dataclass_fields__', {})
    return 'seq' in fields and 'sample_rate_hz' in fields


def _first_array_len(msg: Any) -> int:
    for name in msg.__dataclass_fields__:
        val = getattr(msg, name)
        if hasattr(val, '__len__') and not isinstance(val, (str, bytes)) \
                and name not in ('header', '__msgtype__'):
            return len(val)
    return 0


def _count(msg: Any, topic: str, type_name: str, state: dict, pulls: dict) -> None:
    """Add one block or pull event message to bag_info's tallies."""
    if type_name == PULL_EVENT_TYPE:
        if int(msg.event) == PULL_START:
            pulls['count'] += 1
            ts = int(msg.test_set)
            pulls['per_test_set'][ts] = pulls['per_test_set'].get(ts, 0) + 1
            pulls['pull_ids'].append(int(msg.pull_id))
        else:
            pulls['ends'] += 1
        return
    st = state[topic]
    st['rates'].add(float(msg.sample_rate_hz))
    st['samples'] += _first_array_len(msg)
    seq = int(msg.seq)
    if st['first'] is None:
        st['first'] = seq
    elif seq > st['last']:
        st['gaps'] += seq - st['last'] - 1
    else:  # repeated or going back: publisher restart, not a drop
        st['resets'] += 1
    st['last'] = seq


def bag_info(path: str | Path, typestore: Typestore | None = None) -> dict[str, Any]:
    """Inspect a bag. Raises BagError for anything that is not a readable bag (an empty but
    valid bag has 0 messages).

    Returns {'path', 'storage_files' (metadata.yaml's relative_file_paths), 'storage'
    (identifier and compression), 'message_count' (read from the storage),
    'metadata_message_count', 'count_differences' ([(topic, metadata.yaml count or None,
    storage count)], empty when they agree), 'start_ns', 'end_ns', 'start',
    'end' (ISO UTC), 'duration_s', 'topics': {name: {'type', 'count', and for block
    messages (fields seq + sample_rate_hz): 'sample_rate_hz' (single rate or None),
    'sample_rates_hz' (distinct), 'samples', 'seq_first', 'seq_last', 'seq_gaps'
    (dropped blocks), 'seq_resets'}}, 'pulls': {'count', 'test_sets', 'per_test_set',
    'pull_ids', 'ends'}}.
    """
    path = Path(path)
    with open_bag(path, typestore, allow_empty=True) as bag:
        topics: dict[str, dict[str, Any]] = {
            name: {'type': t.type_name, 'count': t.count} for name, t in bag.topics().items()
        }
        block_topics = [n for n, t in topics.items()
                        if t['count'] and _is_block_type(bag, t['type'])]
        pull_topics = [n for n, t in topics.items()
                       if t['count'] and t['type'] == PULL_EVENT_TYPE]
        state: dict[str, dict[str, Any]] = {
            n: {'rates': set(), 'samples': 0, 'first': None, 'last': None, 'gaps': 0,
                'resets': 0} for n in block_topics}
        pulls: dict[str, Any] = {'count': 0, 'test_sets': [], 'per_test_set': {},
                                 'pull_ids': [], 'ends': 0}
        wanted = block_topics + pull_topics
        if wanted:
            for topic, type_name, _stamp, cdr in bag.messages(wanted):
                msg = bag.deserialize(cdr, type_name)
                try:
                    _count(msg, topic, type_name, state, pulls)
                except (AttributeError, TypeError, ValueError) as exc:   # the bag's own definition of the type
                    raise BagError(f'bag {str(path)!r}: a {type_name} message on {topic} is not what the type says '
                                   f'({one_line(exc)}); expected the message definition of {type_name}') from None
        for name, st in state.items():
            rates = sorted(st['rates'])
            topics[name].update({
                'sample_rate_hz': rates[0] if len(rates) == 1 else None,
                'sample_rates_hz': rates,
                'samples': st['samples'],
                'seq_first': st['first'],
                'seq_last': st['last'],
                'seq_gaps': st['gaps'],
                'seq_resets': st['resets'],
            })
        pulls['test_sets'] = sorted(pulls['per_test_set'])
        pulls['per_test_set'] = dict(sorted(pulls['per_test_set'].items()))
        meta = bag.metadata
        compression = ' '.join(str(meta.get(k) or '') for k in ('compression_format',
                                                                'compression_mode')).strip()
        return {
            'path': str(path),
            'storage_files': [str(f) for f in meta.get('relative_file_paths') or []],
            'storage': str(meta.get('storage_identifier', '')) +
            (f' ({compression} compression)' if compression else ''),
            'message_count': bag.message_count,
            'metadata_message_count': bag.metadata_message_count,
            'count_differences': [tuple(d) for d in bag.count_differences()],
            'start_ns': bag.start_ns,
            'end_ns': bag.end_ns,
            'start': _iso(bag.start_ns),
            'end': _iso(bag.end_ns),
            'duration_s': bag.duration_ns / NS_PER_S,
            'topics': dict(sorted(topics.items())),
            'pulls': pulls,
        }


def count_lines(info: dict[str, Any]) -> list[str]:
    """What differs between metadata.yaml's counts and the storage's, for format_info: one
    answer (the storage's, which every command reads) and the difference, never two."""
    diffs = info.get('count_differences') or []
    meta_total = info.get('metadata_message_count', info['message_count'])
    if not diffs and meta_total == info['message_count']:
        return []
    out = [f"  (read from the storage; metadata.yaml says {meta_total})"]
    for topic, meta, stored in diffs[:10]:
        said = 'does not list it' if meta is None else f'says {meta}'
        out.append(f'  {topic}: storage holds {stored}, metadata.yaml {said}')
    if len(diffs) > 10:
        out.append(f'  ... and {len(diffs) - 10} more topics differ')
    return out


def format_info(info: dict[str, Any]) -> str:
    """Human-readable table of a bag_info() result."""
    try:
        empty = not info['message_count']
        lines = [
            f"Bag:       {info['path']}",
            f"Files:     {', '.join(info.get('storage_files', [])) or '-'}",
            *([f"Storage:   {info['storage']}"] if info.get('storage') else []),
            f"Messages:  {info['message_count']}",
            *count_lines(info),
            f"Start:     {'-' if empty else info['start']}  ({info['start_ns']} ns)",
            f"End:       {'-' if empty else info['end']}  ({info['end_ns']} ns)",
            f"Duration:  {info['duration_s']:.3f} s",
            '',
        ]
        rows = [('Topic', 'Type', 'Count', 'Rate Hz', 'Samples', 'Seq gaps')]
        for name, t in info['topics'].items():
            if 'seq_gaps' in t:
                rate = t['sample_rate_hz']
                rate_s = f'{rate:g}' if rate is not None else \
                    '/'.join(f'{r:g}' for r in t['sample_rates_hz']) or '-'
                gaps = str(t['seq_gaps']) + (f" (+{t['seq_resets']} resets)"
                                             if t['seq_resets'] else '')
                rows.append((name, t['type'], str(t['count']), rate_s, str(t['samples']),
                             gaps))
            else:
                rows.append((name, t['type'], str(t['count']), '-', '-', '-'))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
        for i, row in enumerate(rows):
            lines.append('  '.join(c.ljust(w) if j < 2 else c.rjust(w)
                                   for j, (c, w) in enumerate(zip(row, widths))).rstrip())
            if i == 0:
                lines.append('  '.join('-' * w for w in widths))
        pulls = info['pulls']
        lines.append('')
        if pulls['count']:
            per = ', '.join(f'set {k}: {v}' for k, v in pulls['per_test_set'].items())
            lines.append(f"Pulls:     {pulls['count']} ({per})")
        else:
            lines.append('Pulls:     none')
    except (KeyError, TypeError) as exc:
        raise BagError(f'format_info got a malformed info dict (missing/invalid {exc!s}); '
                       'expected the result of bag_info()') from None
    return '\n'.join(lines)
