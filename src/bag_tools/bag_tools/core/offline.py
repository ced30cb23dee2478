"""Offline correction and scoring of a bag or a campaign with the live nodes' core.

Bag input: the /force and /accel blocks (by type) are paired by force_correction's BlockAligner
in log order, exactly as correction_node does, and the filter restarts where the aligner
reports a discontinuity (pair.continuous False), exactly as the node does. Each continuous run
is corrected in one correct_block call: the core guarantees the result equals block-by-block
streaming bit for bit, so the numbers equal the live node's. Pulls are cut by the PullEvent
START/END windows by sample time and scored with score_pull (what PullAccumulator.score does)
and SetStatistics, like validator_node.

Campaign input: each pull is one run; consecutive pulls form one run only when the second's
start_ns is exactly where the first ends (a contiguous recording, as the sim publishes).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import asdict, replace
from heapq import merge
from pathlib import Path
from typing import Any, Callable

import numpy as np

from force_correction.core import (BlockAligner, CorrectionError, CorrectionParams,
                                   SetStatistics, correct_block, initial_state, score_pull)
from force_tester_common.channels import PULL_EVENT_TYPE

from .convert import (CORRECTED_NAME, CORRECTED_TOPIC, block_cdr, header, place_pulls,
                      stamp_of)
from .daq import (CAMPAIGN_FILE, NS_PER_S, Campaign, DaqPull, end_stamp_ns, read_campaign,
                  sample_stamps_ns, write_campaign)
from .errors import BagError
from .reader import open_bag
from .typestore import default_typestore
from .writer import BagWriter

FORCE_TYPE = 'force_tester_msgs/msg/ForceBlock'
ACCEL_TYPE = 'force_tester_msgs/msg/AccelBlock'
SCORE_TYPE = 'force_tester_msgs/msg/PullScore'
SUMMARY_TYPE = 'force_tester_msgs/msg/SetSummary'
OUTPUT_TOPICS = (CORRECTED_TOPIC, '/pull_score', '/set_summary')
SCORE_FIELDS = ('stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
                'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'raw_rms_n',
                'corrected_rms_n', 'filtered_rms_n')

Progress = Callable[[int, int], None]


def source_kind(src: str | Path) -> str:
    p = Path(src)
    if (p / CAMPAIGN_FILE).is_file():
        return 'campaign'
    if (p / 'metadata.yaml').is_file() or any(p.glob('*.mcap')):
        return 'bag'
    if not p.exists():
        raise BagError(f'source {str(p)!r} does not exist; expected a bag or a campaign folder')
    raise BagError(f'source {str(p)!r} is neither a bag (metadata.yaml) nor a campaign '
                   f'({CAMPAIGN_FILE})')


def _params(mass_kg, window) -> CorrectionParams:
    try:
        return CorrectionParams(mass_kg=mass_kg, window=window)
    except CorrectionError as exc:
        raise BagError(str(exc)) from None


class _Runs:
    """Concatenated corrected samples of the whole recording, in time order."""

    def __init__(self, params: CorrectionParams) -> None:
        self.params = params
        self.parts: dict = {k: [] for k in ('t', 'stationary', 'raw', 'inertial', 'corrected',
                                            'filtered')}
        self.nan_count = 0
        self.runs = 0

    def add_run(self, stamps: np.ndarray, force: np.ndarray, accel: np.ndarray,
                stationary: np.ndarray) -> Any:
        out, _ = correct_block(force, accel, self.params, initial_state(self.params))
        self.nan_count += out.nan_count
        self.runs += 1
        for k, v in (('t', stamps), ('stationary', stationary), ('raw', out.raw_n),
                     ('inertial', out.inertial_n), ('corrected', out.corrected_n),
                     ('filtered', out.filtered_n)):
            self.parts[k].append(v)
        return out

    def arrays(self) -> dict:
        return {k: (np.concatenate(v) if v else np.empty(0)) for k, v in self.parts.items()}


def _score(arrays: dict, windows: list, events: list, loaded_fraction: float,
           warnings: list) -> tuple:
    """Score each (start, end, set, pull_id) window; returns (per-pull dicts, SetStatistics)."""
    t = arrays['t']
    stats = SetStatistics()
    pulls = []
    ev_stamps = np.array(sorted(events), dtype=np.int64) if events else np.empty(0, np.int64)
    for start, end, set_id, pull_id in windows:
        lo, hi = np.searchsorted(t, [start, end])
        if hi <= lo:
            warnings.append(f'pull {pull_id} (set {set_id}): no corrected samples; not scored')
            continue
        try:
            s = score_pull(*(arrays[k][lo:hi] for k in ('stationary', 'raw', 'corrected',
                                                        'filtered')),
                           loaded_fraction=loaded_fraction)
        except CorrectionError as exc:
            warnings.append(f'pull {pull_id} (set {set_id}) not scored: {exc}')
            continue
        dropped = int(np.count_nonzero((ev_stamps >= start) & (ev_stamps < end)))
        d = {'pull_id': int(pull_id), 'set': int(set_id), 'start_ns': int(start),
             'end_ns': int(end), 'dropped_blocks': dropped,
             **{k: float(getattr(s, k)) for k in SCORE_FIELDS}}
        stats.add(set_id, replace(s, dropped_blocks=dropped))
        pulls.append(d)
    return pulls, stats


def _summaries(stats: SetStatistics) -> list:
    return [asdict(stats.summary(s)) for s in sorted(stats.sets())]


# --------------------------------------------------------------------------- bag
def _read_bag(src: Path, runs: _Runs, warnings: list, progress: Progress | None) -> dict:
    with open_bag(src) as bag:
        topics = bag.topics()
        force_t = [n for n, t in topics.items() if t.type_name == FORCE_TYPE]
        accel_t = [n for n, t in topics.items() if t.type_name == ACCEL_TYPE]
        event_t = [n for n, t in topics.items() if t.type_name == PULL_EVENT_TYPE]
        for what, found, default in (('ForceBlock', force_t, '/force'),
                                     ('AccelBlock', accel_t, '/accel')):
            if not found:
                raise BagError(f'bag {str(src)!r} has no {what} topic; expected {default} '
                               'blocks to correct')
        force_topic = '/force' if '/force' in force_t else sorted(force_t)[0]
        accel_topic = '/accel' if '/accel' in accel_t else sorted(accel_t)[0]
        aligner = BlockAligner(('force', 'accel'))
        pairs: list = []
        run: list = []
        drop_events: list = []
        starts: dict = {}
        windows: list = []
        frame = ''

        def flush():
            if run:
                f = np.concatenate([p[1] for p in run])
                a = np.concatenate([p[2] for p in run])
                s = np.concatenate([p[3] for p in run])
                st = np.concatenate([sample_stamps_ns(p[0].stamp_ns, p[0].n_samples,
                                                      p[0].sample_rate_hz) for p in run])
                runs.add_run(st, f, a, s)
                pairs.extend((p[0].stamp_ns, p[0].n_samples, p[0].sample_rate_hz) for p in run)
                run.clear()

        if not event_t:
            warnings.append(f'bag {str(src)!r} has no {PULL_EVENT_TYPE} topic: corrected, but '
                            'no pull can be scored')
        wanted = [force_topic, accel_topic, *event_t]
        total = sum(topics[t].count for t in wanted)
        for k, (topic, type_name, _log, cdr) in enumerate(bag.messages(wanted)):
            msg = bag.deserialize(cdr, type_name)
            if type_name == PULL_EVENT_TYPE:
                if int(msg.event) == 0:
                    starts[int(msg.pull_id)] = (stamp_of(msg), int(msg.test_set))
                else:
                    st = starts.pop(int(msg.pull_id), None)
                    if st is None:
                        warnings.append(f'END of pull {msg.pull_id} without its START; '
                                        'not scored')
                    else:
                        windows.append((st[0], stamp_of(msg), st[1], int(msg.pull_id)))
                continue
            channel = 'force' if topic == force_topic else 'accel'
            n = len(msg.moving_n) if channel == 'force' else len(msg.axial_m_s2)
            if channel == 'force':
                frame = msg.header.frame_id
            try:
                new, events = aligner.push(channel, stamp_of(msg), int(msg.seq),
                                           float(msg.sample_rate_hz), n, msg)
            except CorrectionError as exc:
                raise BagError(f'{topic} block seq {msg.seq}: {exc}') from None
            for ev in events:
                if ev.kind in ('dropped', 'unmatched'):
                    drop_events.append(ev.stamp_ns)
                if ev.kind != 'discontinuity':
                    warnings.append(f'{ev.kind} block on {ev.channel}: {ev.detail}')
            for pair in new:
                if not pair.continuous:
                    flush()
                fm, am = pair['force'], pair['accel']
                run.append((pair, np.asarray(fm.moving_n, dtype=np.float64),
                            np.asarray(am.axial_m_s2, dtype=np.float64),
                            np.asarray(fm.stationary_n, dtype=np.float64)))
            if progress and k % 20000 == 0:
                progress(k, total)
        flush()
        for pid, st in starts.items():
            warnings.append(f'pull {pid} has no END; not scored')
    if not pairs:
        raise BagError(f'bag {str(src)!r}: no /force block pairs with an /accel block of the '
                       'same stamp; nothing to correct')
    return {'pairs': pairs, 'windows': sorted(windows), 'drops': drop_events, 'frame': frame}


def _write_bag(src: Path, dst: Path, runs: _Runs, data: dict, pulls: list,
               stats_by_pull: list, warnings: list) -> None:
    store = default_typestore()
    arr = runs.arrays()
    generated = []
    pos = 0
    for seq, (stamp, n, rate) in enumerate(data['pairs']):
        sl = slice(pos, pos + n)
        pos += n
        last = int(arr['t'][pos - 1]) if n else stamp  # log time: the block's last sample
        cdr = block_cdr(store, CORRECTED_NAME, stamp, rate, seq,
                        {'raw_n': arr['raw'][sl], 'inertial_n': arr['inertial'][sl],
                         'corrected_n': arr['corrected'][sl],
                         'filtered_n': arr['filtered'][sl]}, data['frame'])
        generated.append((last, 0, CORRECTED_TOPIC, CORRECTED_NAME, cdr))
    T = store.types
    for k, (p, summ) in enumerate(zip(pulls, stats_by_pull)):
        msg = T[SCORE_TYPE](header=header(store, p['start_ns']), pull_id=p['pull_id'],
                            test_set=p['set'], dropped_blocks=p['dropped_blocks'],
                            **{f: p[f] for f in SCORE_FIELDS})
        generated.append((p['end_ns'], 1, '/pull_score', SCORE_TYPE,
                          store.serialize_cdr(msg, SCORE_TYPE)))
        msg = T[SUMMARY_TYPE](
            header=header(store, p['start_ns']), test_set=p['set'], pulls=summ['pulls'],
            stationary_peak_mean_n=summ['mean_stationary_peak_n'],
            raw_diff_mean_pct=summ['raw_mean_pct'], raw_diff_std_pct=summ['raw_std_pct'],
            corrected_diff_mean_pct=summ['corrected_mean_pct'],
            corrected_diff_std_pct=summ['corrected_std_pct'],
            filtered_diff_mean_pct=summ['filtered_mean_pct'],
            filtered_diff_std_pct=summ['filtered_std_pct'])
        generated.append((p['end_ns'], 2, '/set_summary', SUMMARY_TYPE,
                          store.serialize_cdr(msg, SUMMARY_TYPE)))
    generated.sort(key=lambda g: (g[0], g[1]))
    with open_bag(src) as bag, BagWriter(dst, store) as writer:
        topics = bag.topics()
        keep = [t for t in topics if t not in OUTPUT_TOPICS]
        replaced = [t for t in topics if t in OUTPUT_TOPICS]
        if replaced:
            warnings.append(f'input topics {", ".join(replaced)} replaced by the offline '
                            'results')
        for t in keep:
            type_name = topics[t].type_name
            if type_name not in store.types:
                try:
                    store.register({type_name: bag.typestore.fielddefs[type_name]})
                except Exception:  # noqa: BLE001
                    warnings.append(f'topic {t} ({type_name}) not copied: its type is unknown')
                    continue
            writer.add_topic(t, type_name)
        for t, type_name in ((CORRECTED_TOPIC, CORRECTED_NAME), ('/pull_score', SCORE_TYPE),
                             ('/set_summary', SUMMARY_TYPE)):
            writer.add_topic(t, type_name)
        keep = [t for t in keep if t in writer.topics]
        src_iter = ((m.stamp_ns, -1, m.topic, m.type_name, m.cdr) for m in bag.messages(keep)) \
            if keep else iter(())
        for log, _o, topic, _type, cdr in merge(src_iter, iter(generated),
                                                 key=lambda g: (g[0], g[1])):
            writer.write(topic, log, cdr)


# --------------------------------------------------------------------------- campaign
def _campaign_runs(camp: Campaign, runs: _Runs) -> tuple:
    """Correct each pull (joining contiguous pulls into one run). Returns (windows, outs)."""
    rate = camp.sample_rate_hz
    placed = place_pulls(camp)
    windows = []
    groups: list = []
    prev_end = None
    for (start, pid), p in zip(placed, camp.pulls):
        n = len(p.channels['time_s'])
        contiguous = p.meta.get('start_ns') is not None and prev_end == start
        if contiguous:
            groups[-1].append((start, n, p))
        else:
            groups.append([(start, n, p)])
        prev_end = end_stamp_ns(start, n, rate) if p.meta.get('start_ns') is not None else None
        windows.append((start, end_stamp_ns(start, n, rate), int(p.meta['set']), pid))
    outs = []
    for g in groups:
        ch = [x[2].channels for x in g]
        out = runs.add_run(np.concatenate([sample_stamps_ns(s, n, rate) for s, n, _ in g]),
                           np.concatenate([c['force_moving_n'] for c in ch]),
                           np.concatenate([c['accel_axial_m_s2'] for c in ch]),
                           np.concatenate([c['force_stationary_n'] for c in ch]))
        pos = 0
        for _s, n, _p in g:
            outs.append({k: getattr(out, k)[pos:pos + n] for k in
                         ('inertial_n', 'corrected_n', 'filtered_n')})
            pos += n
    return windows, outs


def correct(src: str | Path, dst: str | Path, mass_kg: float = 1.152, window: int = 140,
            loaded_fraction: float = 0.1, to: str | None = None,
            progress: Progress | None = None, warnings: list | None = None) -> dict:
    """Correct and score a bag or a campaign; write the result to dst (a new bag or campaign).

    to: 'bag' or 'campaign' (default: the kind of src; a campaign can only be written as a
    campaign here, use `import` afterwards for a bag). Returns {'params', 'pulls' (per-pull
    scores), 'sets' (per-set SetSummary dicts, thesis Tables 8-9), 'nan_samples', 'runs',
    'warnings'}.
    """
    warnings = [] if warnings is None else warnings
    params = _params(mass_kg, window)
    src, dst = Path(src), Path(dst)
    kind = source_kind(src)
    to = to or kind
    if to not in ('bag', 'campaign'):
        raise BagError(f'output kind {to!r} is invalid; expected bag or campaign')
    if dst.exists():
        raise BagError(f'output {str(dst)!r} exists already; expected a new directory name')
    if kind == 'campaign' and to == 'bag':
        # campaign -> bag (the same placement of pulls), then correct that bag
        from .convert import campaign_to_bag
        if not dst.parent.is_dir():
            raise BagError(f'parent directory {str(dst.parent)!r} of output {str(dst)!r} '
                           'does not exist')
        tmp = Path(tempfile.mkdtemp(prefix=f'.{dst.name}.import-', dir=dst.parent))
        try:
            campaign_to_bag(src, tmp / 'bag', warnings=warnings)
            return correct(tmp / 'bag', dst, mass_kg, window, loaded_fraction, 'bag',
                           progress, warnings)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    runs = _Runs(params)
    if kind == 'bag':
        data = _read_bag(src, runs, warnings, progress)
        arrays = runs.arrays()
        windows = [(s, e, ts, pid) for s, e, ts, pid in data['windows']]
        pulls, stats = _score(arrays, windows, data['drops'], loaded_fraction, warnings)
    else:
        camp = read_campaign(src)
        warnings.extend(camp.warnings)
        windows, outs = _campaign_runs(camp, runs)
        pulls, stats = _score(runs.arrays(), windows, [], loaded_fraction, warnings)
    # running per-set summary after each pull (what /set_summary carries live)
    running, by_pull, seen = SetStatistics(), [], {}
    for p in pulls:
        k = seen.get(p['set'], 0)
        seen[p['set']] = k + 1
        running.add(p['set'], stats.scores(p['set'])[k])
        by_pull.append(asdict(running.summary(p['set'])))
    result = {'params': {'mass_kg': params.mass_kg, 'window': params.window,
                         'loaded_fraction': loaded_fraction},
              'pulls': pulls, 'sets': _summaries(stats), 'nan_samples': runs.nan_count,
              'runs': runs.runs, 'warnings': warnings}
    if to == 'bag':
        _write_bag(src, dst, runs, data, pulls, by_pull, warnings)
    else:
        if kind == 'bag':
            from .convert import read_bag_pulls
            rate, bpulls = read_bag_pulls(src, [], None)
            arrays = runs.arrays()
            new = []
            for i, p in enumerate(bpulls):
                start = p.meta['start_ns']
                n = len(p.channels['time_s'])
                t = sample_stamps_ns(start, n, rate)
                lo, hi = np.searchsorted(arrays['t'], [t[0], t[-1] + 1])
                idx = np.rint((arrays['t'][lo:hi] - start) * (rate / NS_PER_S)).astype(np.int64)
                ch = dict(p.channels)
                for col, key in (('inertial_n', 'inertial'), ('corrected_n', 'corrected'),
                                 ('filtered_n', 'filtered')):
                    out = np.full(n, np.nan)
                    out[idx] = arrays[key][lo:hi]
                    ch[col] = out
                p.meta['file'] = f'pull_{i + 1:04d}.csv'
                new.append(DaqPull(p.meta, ch))
            camp_pulls, rig, rate_out = new, None, rate
        else:
            camp_pulls = [DaqPull(p.meta, {**p.channels, **o}) for p, o in zip(camp.pulls, outs)]
            rig = (camp.path / camp.rig) if camp.rig else None
            rate_out = camp.sample_rate_hz
        doc = {k: v for k, v in result.items() if k != 'warnings'}
        write_campaign(dst, camp_pulls, rig=rig, sample_rate_hz=rate_out,
                       extra={'scores.json': json.dumps(doc, indent=1, default=_json) + '\n'})
    return result


def _json(x):
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    return str(x)
