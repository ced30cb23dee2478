"""Raw CDR sample blocks, as the monitor receives them, decoded a batch at a time.

The monitor subscribes to serialized messages (it forwards the bytes to Foxglove unchanged) and
decodes what arrived since its last pass with bag_tools' vectorised CDR reader: a few numpy calls
per batch, not per message. Anything on a topic is input from outside: a batch the fast path
refuses is decoded message by message, and a message that cannot be decoded or fails the block
checks is counted with its reason and left out.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Sequence

import numpy as np

from bag_tools.core.fastcdr import decode_blocks
from force_tester_common.core.blocks import block_problem, stamp_problem
from force_tester_common.core.clock import NS_PER_S


@dataclass
class Batch:
    """The usable messages of one batch, in arrival order."""
    arrival_ns: np.ndarray                     # int64 (m,)
    stamp_ns: np.ndarray                       # int64 (m,)
    seq: np.ndarray                            # int64 (m,)
    rate_hz: np.ndarray                        # float64 (m,)
    values: dict                               # field -> list of m float64 arrays
    nan_samples: int = 0                       # NaN or inf samples in every field
    problems: List[str] = field(default_factory=list)  # one per message left out

    def __len__(self) -> int:
        return int(self.arrival_ns.size)


def _decode(buf: bytes, starts, lengths, fields):
    blocks = decode_blocks(buf, np.asarray(starts, np.int64), np.asarray(lengths, np.int64), fields)
    out = {}
    for f in fields:
        counts = blocks.counts[f]
        flat = blocks.values(f)
        out[f] = np.split(flat, np.cumsum(counts)[:-1]) if counts.size else []
    return blocks.stamp_ns, blocks.seq.astype(np.int64), blocks.rate_hz, out


def decode_batch(items: Sequence[tuple], fields: Sequence[str], required: Sequence[str] = ()) -> Batch:
    """items: (arrival_ns, CDR bytes incl. the encapsulation header) pairs of one block type,
    whose float64[] fields are ``fields`` in order. ``required``: fields that must be non-empty."""
    arrival = np.fromiter((a for a, _ in items), np.int64, len(items))
    datas = [d for _, d in items]
    lengths = np.fromiter((len(d) for d in datas), np.int64, len(datas))
    starts = np.concatenate(([0], np.cumsum(lengths)[:-1])) if len(datas) else np.zeros(0, np.int64)
    problems: List[str] = []
    try:
        stamp, seq, rate, values = _decode(b''.join(datas), starts, lengths, fields)
        keep = np.ones(len(datas), bool)
    except Exception:  # noqa: BLE001 - a malformed message somewhere in the batch: one at a time
        keep = np.zeros(len(datas), bool)
        parts = []
        for i, d in enumerate(datas):
            try:
                parts.append(_decode(d, [0], [len(d)], fields))
                keep[i] = True
            except Exception as exc:  # noqa: BLE001 - input from outside
                problems.append(f'undecodable message of {len(d)} bytes: {type(exc).__name__}: {exc}')
        stamp = np.array([p[0][0] for p in parts], np.int64)
        seq = np.array([p[1][0] for p in parts], np.int64)
        rate = np.array([p[2][0] for p in parts], np.float64)
        values = {f: [p[3][f][0] for p in parts] for f in fields}
    arrival = arrival[keep]
    ok = np.ones(arrival.size, bool)
    for i in range(arrival.size):
        sec, nsec = divmod(int(stamp[i]), NS_PER_S)
        problem = stamp_problem(sec, nsec) or block_problem(
            float(rate[i]), {f: values[f][i].size for f in fields}, required)
        if problem:
            problems.append(problem)
            ok[i] = False
    if not ok.all():
        idx = np.flatnonzero(ok)
        arrival, stamp, seq, rate = arrival[idx], stamp[idx], seq[idx], rate[idx]
        values = {f: [values[f][i] for i in idx] for f in fields}
    nan = sum(int(np.count_nonzero(~np.isfinite(np.concatenate(v)))) for v in values.values() if v)
    return Batch(arrival, stamp, seq, rate, values, nan, problems)
