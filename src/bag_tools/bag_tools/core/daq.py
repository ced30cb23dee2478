"""The DAQ export format: a campaign folder of per-pull CSV files (or NI TDMS) + campaign.yaml.

See the bag_tools README for the format. ROS-free: numpy, yaml and the standard library
(npTDMS is imported lazily, only to read .tdms files).

Validation (every error is a BagError with one line quoting the value, the file and what was
expected): missing required column, channels of different lengths, non-monotonic or non-finite
time, a sample rate disagreeing with the time column, bad pull metadata.
NaN samples (outside time_s) are kept as NaN and reported as a warning with their count: the
correction core ignores NaN samples (the corrected sample is NaN, the moving average skips it,
scoring uses nanmax), so keeping them changes no finite value and hides nothing.
"""

from __future__ import annotations

import itertools
import math
import numbers
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, NamedTuple, Sized

import numpy as np
import yaml

from force_tester_common.core.channels import (
    CHANNELS,
    CORE_CHANNELS,
    CORRECTED_FIELDS,
    OPTIONAL_CHANNELS,
    REQUIRED_CHANNELS,
)
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.mapping import map_here
from force_tester_common.core.partial import Marked, clear_stale, tell

from .daqfiles import (  # noqa: F401 - read_csv and time_column are part of this module's interface
    FORMATS,
    NOTHING_TO_CORRECT,
    ChannelMap,
    apply_map,
    check_absent,
    file_format,
    load_channel_map,
    quiet,
    read_csv,
    read_records,
    time_column,
)
from .errors import BagError, one_line

CAMPAIGN_FILE = 'campaign.yaml'
FORMAT = 'force_tester_daq/1'
#: Columns written by `correct` into a campaign (optional extras, also accepted on reading).
CORRECTED_COLUMNS = tuple(f for f in CORRECTED_FIELDS if f != 'raw_n')
KNOWN_COLUMNS = CHANNELS + CORRECTED_COLUMNS
#: Relative tolerance between campaign.yaml's sample_rate_hz and the rate of the time column.
RATE_RTOL = 1e-6
#: Stamp of the first pull's first sample when campaign.yaml gives no start_ns (2000-01-01Z).
DEFAULT_EPOCH_NS = 946_684_800 * NS_PER_S
#: Gap between pulls placed without start_ns (a time gap: the live filter restarts there).
DEFAULT_GAP_NS = NS_PER_S

META_REQUIRED = ('file',)
#: What a pull's metadata says when campaign.yaml (or ./ft bag import) does not: 0, unknown (another lab's rig
#: has no test set, coupon rating, commanded speed or deceleration of ours).
META_DEFAULTS = {'set': 0, 'coupon_lbf': 0.0, 'velocity_fps': 0.0, 'decel_g': 0.0}
#: Every key a pull's metadata has once checked (check_meta), in the order campaign.yaml is written.
META_KEYS = META_REQUIRED + tuple(META_DEFAULTS)
META_OPTIONAL = ('start_ns', 'pull_id')


class DaqPull(NamedTuple):
    """One pull: meta (dict with META_REQUIRED keys, start_ns / pull_id or None) and channels
    (column name -> float64 array; time_s included)."""

    meta: dict
    channels: dict


@dataclass
class Campaign:
    path: Path
    sample_rate_hz: float
    pulls: list  # [DaqPull]
    rig: str | None = None
    warnings: list = field(default_factory=list)
    failed: list = field(default_factory=list)  # [(file, one line)]: pulls left out by read_campaign
    #: required channels this campaign does not have (campaign.yaml ``absent:``): never NaN columns
    absent: tuple = ()

    def missing_optional(self) -> list:
        """Optional channels absent from at least one pull."""
        return [c for c in OPTIONAL_CHANNELS
                if any(c not in p.channels for p in self.pulls)]


# --------------------------------------------------------------------------- helpers
def _is_int(x) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


def _is_real(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(float(x))


def check_meta(meta: Mapping, where: str, index: int) -> dict:
    """Validated copy of one pull's metadata (campaign.yaml entry): only ``file`` is required; set, coupon_lbf,
    velocity_fps and decel_g default to META_DEFAULTS (unknown), start_ns and pull_id to None."""
    if not isinstance(meta, Mapping):
        raise BagError(f'{where}: pull #{index} is {meta!r}; expected a mapping with keys '
                       f'{", ".join(META_REQUIRED)} (optional {", ".join(META_KEYS[1:] + META_OPTIONAL)})')
    for key in META_REQUIRED:
        if key not in meta:
            raise BagError(f'{where}: pull #{index} lacks {key!r}; expected keys '
                           f'{", ".join(META_REQUIRED)} (optional {", ".join(META_KEYS[1:] + META_OPTIONAL)})')
    out = {**META_DEFAULTS, **meta}
    f = out['file']
    if not isinstance(f, str) or not f or '/' in f or '\\' in f or f.startswith('.'):
        raise BagError(f'{where}: pull #{index} file {f!r} is invalid; expected a plain file '
                       'name inside the campaign folder')
    s = out['set']
    if not _is_int(s) or not 0 <= s <= 255:
        raise BagError(f'{where}: pull #{index} set {s!r} is invalid; expected an integer 0..255')
    for key in ('coupon_lbf', 'velocity_fps', 'decel_g'):
        if not _is_real(out[key]):
            raise BagError(f'{where}: pull #{index} {key} {out[key]!r} is invalid; expected a '
                           'finite number')
        out[key] = float(out[key])
    for key in META_OPTIONAL:
        v = out.get(key)
        if v is None:
            out[key] = None
        elif not _is_int(v) or v < 0 or (key == 'pull_id' and v >= 2**32) \
                or (key == 'start_ns' and v >= 2**63):
            raise BagError(f'{where}: pull #{index} {key} {v!r} is invalid; expected a '
                           'non-negative integer' + (' (ns since epoch)' if key == 'start_ns'
                                                     else ''))
    return out


# --------------------------------------------------------------------------- validation
def check_channels(channels: Mapping[str, Any], where: str, rate_hz: float | None,
                   warnings: list | None = None, absent: Iterable = ()) -> tuple[dict, float]:
    """Validate one pull's channels; returns (float64 channels, sample rate).

    rate_hz None: the rate is taken from the time column. absent: required channels the campaign
    names as absent (they may be missing; the core channels never may).
    """
    core = [c for c in CORE_CHANNELS[1:] if c not in channels]
    if core:
        raise BagError(f'{where}: required column {core[0]!r} is missing; {NOTHING_TO_CORRECT}')
    missing = [c for c in REQUIRED_CHANNELS if c not in channels and c not in absent]
    if missing:
        raise BagError(f'{where}: required column {missing[0]!r} is missing; expected columns '
                       f'{", ".join(REQUIRED_CHANNELS)} (found {", ".join(channels) or "none"}), or '
                       f"the channel named in campaign.yaml's absent: list")
    out = {}
    n = None
    for name, values in channels.items():
        a = np.asarray(values, dtype=np.float64)
        if a.ndim != 1:
            raise BagError(f'{where}: column {name!r} has shape {a.shape}; expected 1-D samples')
        if n is None:
            n, first = a.shape[0], name
        elif a.shape[0] != n:
            raise BagError(f'{where}: column {name!r} has {a.shape[0]} samples but {first!r} has '
                           f'{n}; expected channels of equal length')
        out[name] = a
    t = out['time_s']
    if n < 2:
        raise BagError(f'{where}: {n} sample(s); expected at least 2 to know the sample rate')
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise BagError(f'{where}: time_s is {t[bad[0]]!r} at row {bad[0] + 1}; expected finite '
                       'times in seconds')
    d = np.diff(t)
    bad = np.flatnonzero(d <= 0)
    if bad.size:
        i = int(bad[0])
        raise BagError(f'{where}: time_s is not increasing at row {i + 2}: {t[i + 1]!r} s after '
                       f'{t[i]!r} s; expected strictly increasing times')
    implied = (n - 1) / (t[-1] - t[0])
    if rate_hz is None:
        rate_hz = float(implied)
        # snap to an integer rate when the column says so (50 kHz DAQs)
        if abs(round(rate_hz) - rate_hz) <= RATE_RTOL * rate_hz:
            rate_hz = float(round(rate_hz))
    elif abs(implied - rate_hz) > RATE_RTOL * rate_hz:
        raise BagError(f'{where}: sample_rate_hz {rate_hz!r} disagrees with the time column '
                       f'({implied:.9g} Hz from {n} samples over {t[-1] - t[0]!r} s); expected '
                       f'them equal within {RATE_RTOL:g}')
    nan = {name: int(np.count_nonzero(np.isnan(a))) for name, a in out.items() if name != 'time_s'}
    nan = {k: v for k, v in nan.items() if v}
    if nan and warnings is not None:
        rows = np.zeros(n, dtype=bool)
        for name in nan:
            rows |= np.isnan(out[name])
        warnings.append(f'{where}: {int(rows.sum())} row(s) with NaN samples ('
                        + ', '.join(f'{k}: {v}' for k, v in nan.items())
                        + '); kept as NaN (the correction skips them)')
    unknown = [c for c in out if c not in KNOWN_COLUMNS]
    if unknown and warnings is not None:
        warnings.append(f'{where}: unknown column(s) {", ".join(unknown)} kept but not used')
    return out, rate_hz


# --------------------------------------------------------------------------- CSV
def _fmt_column(a: np.ndarray) -> list:
    # repr of a Python float is the shortest string that reads back to the same double.
    return list(map(repr, a.tolist()))


def format_column(a: np.ndarray):
    """A column as Python's repr of each value (the shortest string that reads back to the same double), as a
    pyarrow string array, formatted in C++: pyarrow casts to the same shortest digits but lays some out
    differently, and those are mended here: integers gain '.0', exponents two digits (1e-5 -> 1e-05), and
    what is left (fixed notation below 1e-4, exponents from 1e-4 to 1e16: a few in a pull) is repr'd."""
    import pyarrow as pa  # only where CSV is written
    import pyarrow.compute as pc
    v = np.ascontiguousarray(a, dtype=np.float64)
    sample = v.view(np.int64)[::max(1, v.size // 2048)]
    if v.size > 64 and np.unique(sample).size <= sample.size // 2:
        # a column of few distinct values (a command, a quantised encoder, zeros): each formatted once
        bits, inverse = np.unique(v.view(np.int64), return_inverse=True)   # by bits: -0.0 is not 0.0
        if bits.size <= v.size // 4:
            return format_column(bits.view(np.float64)).take(pa.array(inverse.astype(np.int32)))
    s = pc.cast(pa.array(v), pa.string())
    mag = np.abs(v)
    fin = np.isfinite(v)
    dot = pc.match_substring(s, '.').to_numpy(zero_copy_only=False)
    exp = pc.match_substring(s, 'e').to_numpy(zero_copy_only=False)
    sci = (mag < 1e-4) | (mag >= 1e16)        # where repr writes an exponent
    whole = ~dot & ~exp & fin & ~sci          # '12' -> '12.0'
    short = exp & fin & sci                   # '1e-5' -> '1e-05'
    other = fin & ~((dot & ~exp & ~sci) | whole | short)
    for mask, mend in ((whole, lambda x: pc.binary_join_element_wise(x, '.0', '')),
                       (short, lambda x: pc.replace_substring_regex(x, r'e([+-])(\d)$', r'e\10\2'))):
        if mask.any():
            m = pa.array(mask)
            s = pc.replace_with_mask(s, m, mend(pc.filter(s, m)))
    if other.any():
        s = pc.replace_with_mask(s, pa.array(other), pa.array(_fmt_column(v[other]), pa.string()))
    return s


def write_csv(path: Path, channels: Mapping[str, np.ndarray]) -> None:
    """One pull CSV: a header row, then a row per sample of repr'd floats (lossless). Formatted in C++ by
    pyarrow (format_column) when it is installed: the same bytes as the plain Python below."""
    names = list(channels)
    try:
        import pyarrow.compute as pc
    except ImportError:
        pc = None
    cols = {c: np.asarray(channels[c], dtype=np.float64) for c in names}
    n = len(cols[names[0]]) if names else 0
    if pc is None or n == 0:
        text = [_fmt_column(cols[c]) for c in names]
        with open(path, 'w', encoding='utf-8', newline='') as fh:
            fh.write(','.join(names) + '\n')
            fh.write('\n'.join(map(','.join, zip(*text))))
            fh.write('\n')
        return
    with open(path, 'wb') as fh:
        fh.write((','.join(names) + '\n').encode('utf-8'))
        for k in range(0, n, CSV_ROWS):   # 1M rows a time keeps pyarrow's 32-bit string offsets in range
            rows = pc.binary_join_element_wise(*[format_column(cols[c][k:k + CSV_ROWS]) for c in names], ',')
            rows = pc.binary_join_element_wise(rows, '', '\n')      # each row and its newline, end to end
            offsets = np.frombuffer(rows.buffers()[1], dtype=np.int32)[rows.offset:rows.offset + len(rows) + 1]
            fh.write(memoryview(rows.buffers()[2])[int(offsets[0]):int(offsets[-1])])


#: Rows formatted at once by write_csv.
CSV_ROWS = 1_000_000


# --------------------------------------------------------------------------- TDMS
def read_tdms(path: str | Path, mapping: Mapping[str, str] | None = None,
              sample_rate_hz: float | None = None) -> dict:
    """NI TDMS file -> {column: array}. mapping: DAQ column -> TDMS channel name (either
    'Channel' or 'Group/Channel'); unmapped columns are looked up by their own name. time_s
    absent: built from sample_rate_hz or the channels' wf_increment property."""
    try:
        import nptdms  # optional dependency
    except ImportError:
        raise BagError('reading TDMS needs npTDMS: pip install npTDMS (see requirements.txt)') \
            from None
    path = Path(path)
    try:
        with quiet():
            tdms = nptdms.TdmsFile.read(str(path))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot read TDMS file {str(path)!r}: {one_line(exc)}') from None
    by_name: dict = {}
    for group in tdms.groups():
        for ch in group.channels():
            by_name.setdefault(ch.name, ch)
            by_name[f'{group.name}/{ch.name}'] = ch
    if isinstance(mapping, (list, tuple)):
        mapping = parse_mapping(mapping)
    elif mapping is not None and not isinstance(mapping, Mapping):
        raise BagError(f'TDMS channel map {mapping!r} for {str(path)!r} is invalid; expected '
                       'a mapping {column: channel} or a list of COLUMN=CHANNEL')
    mapping = {str(k): str(v) for k, v in (mapping or {}).items()}
    bad = [k for k in mapping if k not in KNOWN_COLUMNS]
    if bad:
        raise BagError(f'--map column {bad[0]!r} is not a DAQ column; expected one of '
                       f'{", ".join(KNOWN_COLUMNS)}')
    out: dict = {}
    increment = None
    for col in CHANNELS:
        src = mapping.get(col, col)
        ch = by_name.get(src)
        if ch is None:
            if col in mapping:
                raise BagError(f'TDMS file {str(path)!r} has no channel {src!r} (mapped to '
                               f'{col!r}); channels: {", ".join(sorted(by_name))}')
            continue
        out[col] = np.asarray(ch[:], dtype=np.float64)
        inc = ch.properties.get('wf_increment')
        if inc and increment is None:
            increment = float(inc)
    if 'time_s' not in out:
        rate = sample_rate_hz or (1.0 / increment if increment else None)
        if rate is not None and abs(round(rate) - rate) <= RATE_RTOL * rate:
            rate = float(round(rate))
        if rate is None:
            raise BagError(f'TDMS file {str(path)!r} has no time_s channel and no wf_increment; '
                           'expected --map time_s=CHANNEL or --rate HZ')
        lengths = {len(v) for v in out.values()}
        n = max(lengths) if lengths else 0
        out = {'time_s': time_column(n, rate), **out}
    return out


def parse_mapping(items: Iterable[str]) -> dict:
    """['force_moving_n=Dev1/ai0', ...] -> {'force_moving_n': 'Dev1/ai0'}."""
    out = {}
    for item in items:
        if '=' not in item:
            raise BagError(f'--map {item!r} is invalid; expected COLUMN=TDMS_CHANNEL')
        k, v = item.split('=', 1)
        out[k.strip()] = v.strip()
    return out


# --------------------------------------------------------------------------- campaign
#: mapper(fn, items, names=..., progress=...) -> an object with .results (in item order, None for a failed
#: item) and .failed ([(name, one line)]): force_tester_common.engine.map_pulls, or None for a plain loop here.
Mapper = Callable[..., Any]


def is_file(path: Path) -> bool:
    """Whether path is a file; False, not OSError, for a name the file system refuses (longer than it allows: a
    campaign.yaml's file name is input, found by fuzzing)."""
    try:
        return path.is_file()
    except OSError:
        return False


def campaign_index(path: str | Path) -> tuple:
    """campaign.yaml of a campaign folder, validated, without reading the pulls:
    (folder, sample_rate_hz or None, rig file name or None, [(meta, campaign.yaml entry)])."""
    path = Path(path)
    if not path.is_dir():
        what = 'does not exist' if not path.exists() else 'is not a directory'
        raise BagError(f'campaign {str(path)!r} {what}; expected a folder with {CAMPAIGN_FILE}')
    cfile = path / CAMPAIGN_FILE
    if not cfile.is_file():
        raise BagError(f'campaign {str(path)!r} has no {CAMPAIGN_FILE}; expected a DAQ export '
                       'folder (an unfinished export never has one)')
    try:
        doc = yaml.safe_load(cfile.read_text(encoding='utf-8'))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'{str(cfile)!r} is not valid YAML: {one_line(exc)}') from None
    if not isinstance(doc, dict) or not isinstance(doc.get('pulls'), list) or not doc['pulls']:
        raise BagError(f'{str(cfile)!r} has no pulls list; expected a mapping with '
                       "'pulls: [{file: rec1.lvm}, ...]' (optional per pull: set, coupon_lbf, velocity_fps, "
                       'decel_g, start_ns, pull_id)')
    rate = doc.get('sample_rate_hz')
    if rate is not None and (not _is_real(rate) or rate <= 0):
        raise BagError(f'{str(cfile)!r}: sample_rate_hz {rate!r} is invalid; expected a '
                       'finite rate > 0 Hz')
    rate = None if rate is None else float(rate)
    rig = doc.get('rig')
    if rig is not None:
        if not isinstance(rig, str) or not is_file(path / rig):
            raise BagError(f'{str(cfile)!r}: rig {rig!r} is not a file in the campaign folder')
    entries = []
    seen = set()
    for i, entry in enumerate(doc['pulls']):
        meta = check_meta(entry, str(cfile), i)
        if meta['file'] in seen:
            raise BagError(f'{str(cfile)!r}: file {meta["file"]!r} is listed twice')
        seen.add(meta['file'])
        if not is_file(path / meta['file']):
            raise BagError(f'{str(cfile)!r}: pull #{i} file {meta["file"]!r} does not exist in '
                           f'{str(path)!r}')
        entries.append((meta, entry))
    return path, rate, rig, entries


def campaign_channels(path: str | Path) -> tuple:
    """(channel map or None, absent channels) of a campaign folder: campaign.yaml's ``channels:`` (a
    channel map YAML file in the folder) and ``absent:`` (with the map's own absent channels)."""
    path = Path(path)
    cfile = path / CAMPAIGN_FILE
    try:
        doc = yaml.safe_load(cfile.read_text(encoding='utf-8'))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'{str(cfile)!r} is not valid YAML: {one_line(exc)}') from None
    absent = list(check_absent(doc.get('absent'), str(cfile)))
    cmap = None
    if doc.get('channels') is not None:
        name = doc['channels']
        if not isinstance(name, str) or not is_file(path / name):
            raise BagError(f'{str(cfile)!r}: channels {name!r} is not a file in the campaign folder; expected '
                           'the channel map YAML')
        cmap = load_channel_map(path / name)
        absent += [c for c in cmap.absent if c not in absent]
    return cmap, tuple(c for c in CHANNELS if c in absent)


def files_index(files: Iterable, channel_map=None) -> tuple:
    """A campaign given as DAQ files and a channel map, with no campaign.yaml (``./ft discover lab/*.lvm
    --channels map.yaml``): (channel map or None, its absent channels, [(folder, meta)]), a pull per file in the
    order given, each with META_DEFAULTS. channel_map: a map YAML path, a ChannelMap or None. Each file must
    exist and be of a known format (one record each, checked when it is read); two files of one name are
    refused (a pull is named by its file)."""
    files = [Path(f) for f in files]
    if not files:
        raise BagError(f'no DAQ files given; expected one or more files of a known format ({", ".join(FORMATS)})')
    cmap = channel_map if channel_map is None or isinstance(channel_map, ChannelMap) \
        else load_channel_map(channel_map)
    out, seen = [], {}
    for i, f in enumerate(files):
        file_format(f)
        if not f.is_file():
            raise BagError(f'DAQ file {str(f)!r} does not exist' + (' (it is a folder)' if f.is_dir() else ''))
        if f.name in seen:
            raise BagError(f'two DAQ files are named {f.name!r} ({str(seen[f.name])!r} and {str(f)!r}); expected '
                           'one name per pull')
        seen[f.name] = f
        out.append((str(f.resolve().parent), check_meta({'file': f.name}, str(f), i)))
    return cmap, (cmap.absent if cmap is not None else ()), out


def read_pull(job: tuple) -> tuple:
    """One pull file, read and validated (the per-pull step of read_campaign, run on a worker).

    job: (file path, TDMS channel map or None, campaign.yaml's sample rate or None[, channel map or None
    [, absent channels]]). A file of a lab's format (LVM, MDF4, UFF), or any file when a channel map is
    given, goes through the channel map (daqfiles.apply_map) and must hold one record.
    Returns (channels, sample rate, warnings)."""
    fpath, mapping, rate = job[:3]
    cmap = job[3] if len(job) > 3 else None
    absent = tuple(job[4]) if len(job) > 4 else ()
    fpath = Path(fpath)
    suffix = file_format(fpath)
    warnings: list = []
    if cmap is not None or suffix not in ('.csv', '.tdms'):
        raw, absent = pull_from_file(fpath, cmap, rate, absent)
    else:
        raw = read_tdms(fpath, mapping, rate) if suffix == '.tdms' else read_csv(fpath)
    channels, prate = check_channels(raw, str(fpath), rate, warnings, absent)
    return channels, prate, warnings


def pull_from_file(fpath: Path, cmap: ChannelMap | None, rate: float | None = None, absent=()) -> tuple:
    """(channels in SI, absent channels) of a one-record DAQ file through a channel map."""
    records = read_records(fpath)
    if len(records) != 1:
        raise BagError(f'{str(fpath)!r} holds {len(records)} records; expected one per pull file (import the '
                       'file alone to make one pull of each)')
    if rate is not None and cmap is not None and cmap.sample_rate_hz is None and records[0].rate_hz is None:
        cmap = ChannelMap(cmap.path, cmap.specs, cmap.absent, rate)
    elif rate is not None and cmap is None and records[0].rate_hz is None:
        cmap = ChannelMap('campaign.yaml', {}, (), rate)
    raw, map_absent, _used = apply_map(records[0], cmap, str(fpath))
    return raw, tuple(c for c in CHANNELS if c in absent or c in map_absent)


def csv_columns(path: Path) -> set | None:
    """The column names in a CSV pull's header row (empty when unreadable: reading the pull says why);
    None for any other file (its columns are known once it is read)."""
    if Path(path).suffix.lower() != '.csv':
        return None
    try:
        with open(path, encoding='utf-8', newline='') as fh:
            return {h.strip() for h in fh.readline().strip().split(',') if h.strip()}
    except (OSError, UnicodeDecodeError):
        return set()


def check_rate(fpath, prate: float, rate: float | None) -> float:
    """The campaign's rate after a pull at ``prate``: the first pull's when none is known yet."""
    if rate is None:
        return prate
    if abs(prate - rate) > RATE_RTOL * rate:
        raise BagError(f'{str(fpath)!r}: sample rate {prate!r} Hz differs from {rate!r} Hz '
                       'of the earlier pulls; expected one rate per campaign')
    return rate


def map_pulls_in_order(fn: Callable, items: list, names: list, mapper: Mapper | None,
                       on_result: Callable[[int, Any], None], progress=None) -> list:
    """on_result(i, fn(item)) for each item that succeeds, in item order, keeping no result (through
    ``mapper``, else here). Returns the failed [(name, one line)]; here, only BagErrors are caught."""
    if mapper is not None:
        return list(mapper(fn, items, names=names, progress=progress, keep=False, on_result=on_result).failed)
    return map_here(fn, items, names=names, progress=progress, total=len(items), keep=False, on_result=on_result,
                    catch=BagError).failed


def _map(fn: Callable, items: list, names: list, mapper: Mapper | None, progress=None,
         skip: bool = False) -> tuple:
    """(results, failed): through ``mapper``, or here, where the first error is raised (with ``skip``,
    a BagError is recorded in failed instead)."""
    done = (mapper(fn, items, names=names, progress=progress) if mapper is not None else
            map_here(fn, items, names=names, progress=progress, total=len(items), catch=BagError if skip else ()))
    return done.results, list(done.failed)


def failed_line(failed: list) -> str:
    """'FILE: error' of the first failed pull, and how many more failed."""
    name, why = failed[0]
    more = f' (and {len(failed) - 1} more pull(s))' if len(failed) > 1 else ''
    return f'pull {name!r} failed: {why}{more}'


def read_campaign(path: str | Path, mapper: Mapper | None = None, skip_failed: bool = False,
                  progress: Callable[[int, int], None] | None = None,
                  channel_map: ChannelMap | None = None) -> Campaign:
    """Read and validate a campaign folder. Raises BagError; warnings in Campaign.warnings.

    mapper: reads the pull files in parallel (force_tester_common.engine.map_pulls). skip_failed: a pull
    file that fails to read is left out, named in Campaign.failed and in a warning, instead of failing
    the whole campaign (BagError when no pull is left). channel_map: replaces campaign.yaml's ``channels:``."""
    path, rate, rig, entries = campaign_index(path)
    cmap, absent = campaign_channels(path)
    if channel_map is not None:
        cmap = channel_map
        absent = tuple(c for c in CHANNELS if c in absent or c in channel_map.absent)
    jobs = [(path / meta['file'], entry.get('map'), rate, cmap, absent) for meta, entry in entries]
    names = [meta['file'] for meta, _ in entries]
    results, failed = _map(read_pull, jobs, names, mapper, progress, skip_failed)
    if failed and not skip_failed:
        raise BagError(f'campaign {str(path)!r}: {failed_line(failed)}')
    warnings: list = []
    pulls = []
    for (meta, _entry), (fpath, *_rest), res in zip(entries, jobs, results):
        if res is None:
            continue
        channels, prate, pull_warnings = res
        warnings.extend(pull_warnings)
        rate = check_rate(fpath, prate, rate)   # None: the first pull's rate, from its time column
        pulls.append(DaqPull(meta, channels))
    for name, why in failed:
        warnings.append(f'pull {name!r} skipped: {why}')
    if not pulls:
        raise BagError(f'campaign {str(path)!r}: every pull failed; {failed_line(failed)}')
    camp = Campaign(path, rate, pulls, rig, warnings, failed, absent)
    miss = camp.missing_optional()
    if miss:
        warnings.append(f'campaign {str(path)!r}: optional column(s) {", ".join(miss)} missing '
                        'in some pulls; their topics/fields stay empty and they cannot be '
                        'plotted or exported')
    return camp


def _atomic_dir(path: Path) -> Path:
    if path.exists():
        raise BagError(f'output {str(path)!r} exists already; expected a new directory name')
    if not path.parent.is_dir():
        raise BagError(f'parent directory {str(path.parent)!r} of output {str(path)!r} does '
                       'not exist')
    return Path(tempfile.mkdtemp(prefix=f'.{path.name}.partial-', dir=path.parent))


def write_pull(job: tuple) -> float:
    """Write one pull's CSV (the per-pull step of write_campaign, run on a worker). Returns its rate, or
    (rate, notes) when produce gave notes.

    job: (CSV path, channels or produce's argument, produce or None, rate or None, name for messages).
    produce(argument) -> channels, or (channels, notes), makes the pull where it is written (a simulation,
    or a pull read from a bag, for example)."""
    dest, data, produce, rate, where = job[:5]
    absent = job[5] if len(job) > 5 else ()
    channels, notes = produce(data) if produce is not None else data, None
    if isinstance(channels, tuple):   # produce gave (channels, notes): the notes go back with the rate
        channels, notes = channels
    chans, prate = check_channels(channels, where, rate, absent=absent)
    rate = prate if rate is None else rate
    n = len(chans['time_s'])
    ordered = {'time_s': time_column(n, rate)}
    ordered.update((c, chans[c]) for c in CHANNELS[1:] if c in chans)
    ordered.update((c, v) for c, v in chans.items() if c not in ordered)
    write_csv(Path(dest), ordered)
    return float(rate) if notes is None else (float(rate), notes)


def write_campaign(path: str | Path, pulls: Iterable, rig: str | os.PathLike | None = None,
                   sample_rate_hz: float | None = None, extra: Mapping | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   mapper: Mapper | None = None, produce: Callable | None = None,
                   absent: Iterable = (), notes: list | None = None, warnings: list | None = None) -> Path:
    """Write a campaign folder atomically (temp folder beside it, renamed when complete).

    pulls: (meta, channels) pairs (a list or any iterable, read once); meta: any of META_KEYS ('file' default
    pull_NNNN.csv, the others META_DEFAULTS); channels need the required columns. time_s is rewritten as k / rate
    (rate = sample_rate_hz, else the first pull's). rig: a rig YAML file copied into the folder.
    extra: {file name: bytes|str} written too (e.g. scores.json).
    mapper: formats and writes the CSV files in parallel (force_tester_common.engine.map_pulls; the
    slow part is formatting floats losslessly); the workers write into the new folder, so they must
    see it (the embedded cluster does; a cluster needs a shared file system). A pull that fails fails
    the whole write (BagError naming it), leaving nothing.
    produce: pulls are (meta, x) and each pull's channels are produce(x), computed where the pull is
    written (the campaign is never whole in this process); its rate is then its own, and every pull's
    must agree.
    absent: required channels the pulls do not have, written as campaign.yaml's ``absent:``.
    notes: when produce returns (channels, notes), each pull's notes are appended here, in pull order.
    While it is written the hidden folder holds a lock file (force_tester_common.core.partial): a writer killed
    midway leaves it behind, and the next write of ``path`` removes it, saying so in ``warnings`` (logged when
    None).
    """
    path = Path(path)
    absent = check_absent(list(absent), str(path))
    tell(clear_stale(path), warnings)   # what a writer that died left here
    tmp = _atomic_dir(path)
    mark = Marked(tmp).__enter__()      # until the rename: the next writer removes tmp only once we are gone
    try:
        entries: list = []
        names: list = []
        rate = sample_rate_hz
        used = set()
        items = iter(pulls)
        first = next(items, None)
        if first is None:
            raise BagError(f'no pulls to write to {str(path)!r}')
        if rate is None and produce is None:  # the first pull's rate, for all
            rate = check_channels(first[1], f'{str(path)}/{first[0].get("file", "pull_0001.csv")}', None,
                                  absent=absent)[1]

        def jobs():
            for i, (meta, data) in enumerate(itertools.chain([first], items)):
                meta = dict(meta)
                meta.setdefault('file', f'pull_{i + 1:04d}.csv')
                meta = check_meta(meta, str(path), i)
                if meta['file'] in used:
                    raise BagError(f'{str(path)!r}: file {meta["file"]!r} used by two pulls')
                used.add(meta['file'])
                if not meta['file'].lower().endswith('.csv'):   # a lab's rec1.lvm is written as rec1.csv
                    stem, dot, suffix = meta['file'].rpartition('.')
                    meta['file'] = (stem if dot and '.' + suffix.lower() in FORMATS else meta['file']) + '.csv'
                entry = {k: meta[k] for k in META_KEYS}
                for k in META_OPTIONAL:
                    if meta.get(k) is not None:
                        entry[k] = int(meta[k])
                entries.append(entry)
                names.append(meta['file'])
                yield tmp / meta['file'], data, produce, rate, f'{str(path)}/{meta["file"]}', absent

        if mapper is None:
            rates = map_here(write_pull, jobs(), progress=progress, total=len(pulls) if isinstance(pulls, Sized) else 0,
                             catch=()).results
        else:
            done = mapper(write_pull, jobs(), names=names, progress=progress,
                          total=len(pulls) if isinstance(pulls, Sized) else 0)
            if done.failed:
                raise BagError(f'{str(path)!r}: {failed_line(done.failed)}; nothing written')
            rates = done.results
        if notes is not None:
            notes.extend(r[1] for r in rates if isinstance(r, tuple))
        rates = [r[0] if isinstance(r, tuple) else r for r in rates]
        if rate is None:
            rate = rates[0]
            for name, r in zip(names, rates):
                if r != rate:
                    raise BagError(f'{str(path)}/{name}: sample rate {r!r} Hz differs from {rate!r} Hz '
                                   'of the first pull; expected one rate per campaign')
        doc: dict = {'format': FORMAT, 'sample_rate_hz': float(rate)}
        if absent:
            doc['absent'] = list(absent)
        if rig is not None:
            rig = Path(rig)
            if not rig.is_file():
                raise BagError(f'rig file {str(rig)!r} does not exist')
            shutil.copyfile(rig, tmp / rig.name)
            doc['rig'] = rig.name
        doc['pulls'] = entries
        for name, content in (extra or {}).items():
            mode = 'wb' if isinstance(content, bytes) else 'w'
            with open(tmp / name, mode) as fh:
                fh.write(content)
        # campaign.yaml last: a folder without it is never read as a campaign.
        (tmp / CAMPAIGN_FILE).write_text(yaml.safe_dump(doc, sort_keys=False), encoding='utf-8')
        os.chmod(tmp, 0o755)
        mark.unmark()
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        mark.__exit__()
    return path

