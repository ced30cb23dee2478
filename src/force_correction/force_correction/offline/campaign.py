"""Offline `correct` on a DAQ campaign, and the corrected campaign it writes.

Each pull is one run; consecutive pulls form one run only when the second's start_ns is exactly
where the first ends (a contiguous recording, as the sim publishes).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from bag_tools.core import daq
from bag_tools.core.convert import BagPulls, place_pulls, read_bag_pulls
from bag_tools.core.daq import Campaign, DaqPull, Mapper, write_campaign
from force_tester_common.core.channels import ABSENTABLE_CHANNELS
from force_tester_common.core.clock import NS_PER_S, end_stamp_ns, record_stamps_ns

from .stream import CorrectionStream

# campaign column <- stream piece key
CORRECTED_COLUMNS = tuple((c, c.removesuffix('_n')) for c in daq.CORRECTED_COLUMNS)


class PullWindow(NamedTuple):
    """Where a pull lies in the stream: its first and last sample stamps (ns), its test set and its pull id."""

    start_ns: int
    end_ns: int
    set_id: int
    pull_id: int


class CorrectedRuns(NamedTuple):
    """A campaign corrected: each pull's window, and each pull's corrected columns {column: array}."""

    windows: list
    columns: list


def correct_runs(camp: Campaign, stream: CorrectionStream) -> CorrectedRuns:
    """Correct each pull (joining contiguous pulls into one run)."""
    rate = camp.sample_rate_hz
    windows, groups, prev_end = [], [], None
    for (start, pid), p in zip(place_pulls(camp), camp.pulls):
        n = len(p.channels['time_s'])
        placed = p.meta.get('start_ns') is not None
        if placed and prev_end == start:
            groups[-1].append((start, n, p))
        else:
            groups.append([(start, n, p)])
        prev_end = end_stamp_ns(start, n, rate) if placed else None
        windows.append(PullWindow(start, end_stamp_ns(start, n, rate), int(p.meta['set']), pid))
    columns = []
    for g in groups:
        ch = [x[2].channels for x in g]
        out = stream.add(np.concatenate([record_stamps_ns(s, n, rate) for s, n, _ in g]),
                         np.concatenate([c['force_moving_n'] for c in ch]),
                         np.concatenate([c['accel_axial_m_s2'] for c in ch]),
                         np.concatenate([c['force_stationary_n'] if 'force_stationary_n' in c   # absent: unscored
                                         else np.full(len(c['time_s']), np.nan) for c in ch]), rate)
        pos = 0
        for _s, n, _p in g:
            columns.append({c: getattr(out, c)[pos:pos + n] for c, _ in CORRECTED_COLUMNS})
            pos += n
    return CorrectedRuns(windows, columns)


def bag_pulls_with_columns(src: Path, arrays: dict) -> BagPulls:
    """The pulls of a corrected bag as campaign pulls with the corrected columns (NaN where the
    stream has no sample), and their rate."""
    rate, pulls = read_bag_pulls(src, [], None)
    out = []
    for i, p in enumerate(pulls):
        start = p.meta['start_ns']
        n = len(p.channels['time_s'])
        t = record_stamps_ns(start, n, rate)
        lo, hi = np.searchsorted(arrays['t'], [t[0], t[-1] + 1])
        idx = np.rint((arrays['t'][lo:hi] - start) * (rate / NS_PER_S)).astype(np.int64)
        ch = dict(p.channels)
        for col, key in CORRECTED_COLUMNS:
            values = np.full(n, np.nan)
            values[idx] = arrays[key][lo:hi]
            ch[col] = values
        p.meta['file'] = f'pull_{i + 1:04d}.csv'
        out.append(DaqPull(p.meta, ch))
    return BagPulls(rate, out)


def write_corrected_campaign(dst: Path, pulls: list, rate: float, rig, scores: dict,
                             mapper: Mapper | None = None) -> None:
    absent = [c for c in ABSENTABLE_CHANNELS if pulls and c not in pulls[0].channels]
    write_campaign(dst, pulls, rig=rig, sample_rate_hz=rate, mapper=mapper, absent=absent,
                   extra={'scores.json': json.dumps(scores, indent=1, default=_json) + '\n'})


def _json(x):
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.floating):
        return float(x)
    return str(x)
