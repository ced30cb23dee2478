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

from .channel_map import ChannelMap, Mapped, apply_map, check_absent, load_channel_map, pairs_map
from .daqfiles import (
    FORMATS,
    NOTHING_TO_CORRECT,
    RATE_SNAP,
    file_format,
    read_csv,
    read_records,
    snap_rate,
    time_column,
    write_csv,
)
from .errors import BagError, one_line
from .sources import CAMPAIGN_FILE

FORMAT = 'force_tester_daq/1'
#: Columns written by `correct` into a campaign (optional extras, also accepted on reading).
CORRECTED_COLUMNS = tuple(f for f in CORRECTED_FIELDS if f != 'raw_n')
KNOWN_COLUMNS = CHANNELS + CORRECTED_COLUMNS
#: Relative tolerance between campaign.yaml's sample_rate_hz and the rate of the time column (the same as an
#: integer rate's: daqfiles.RATE_SNAP).
RATE_RTOL = RATE_SNAP
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
        rate_hz = snap_rate(float(implied))   # an integer rate when the column says so (50 kHz DAQs)
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


class CampaignIndex(NamedTuple):
    """campaign.yaml read and checked, no pull read: the folder, its sample rate (None: the pulls' own), its rig
    file name (or None) and, per pull, (meta, campaign.yaml entry)."""

    folder: Path
    rate_hz: float | None
    rig: str | None
    entries: list


class CampaignChannels(NamedTuple):
    """A campaign's channel map (None: its files name their channels as ours) and the channels it does not have."""

    channel_map: ChannelMap | None
    absent: tuple


class FilesIndex(NamedTuple):
    """DAQ files given one by one: their channel map (or None), its absent channels, and per file (folder, meta)."""

    channel_map: ChannelMap | None
    absent: tuple
    entries: list


def campaign_index(path: str | Path) -> CampaignIndex:
    """campaign.yaml of a campaign folder, validated, without reading the pulls (``CampaignIndex``)."""
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
    return CampaignIndex(path, rate, rig, entries)


def campaign_channels(path: str | Path) -> CampaignChannels:
    """The channel map (or None) and the absent channels of a campaign folder: campaign.yaml's ``channels:`` (a
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
    return CampaignChannels(cmap, tuple(c for c in CHANNELS if c in absent))


def files_index(files: Iterable, channel_map=None) -> FilesIndex:
    """A campaign given as DAQ files and a channel map, with no campaign.yaml (``./ft discover lab/*.lvm
    --channels map.yaml``): a ``FilesIndex``, a pull per file in the
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
    return FilesIndex(cmap, (cmap.absent if cmap is not None else ()), out)


class PullJob(NamedTuple):
    """What read_pull reads: a pull's file, its ``map:`` of campaign.yaml (``--map``'s COLUMN=CHANNEL pairs, for a
    TDMS file) or None, campaign.yaml's sample rate or None, the campaign's channel map or None, and the channels
    the rig does not have."""

    path: Path
    pairs: Any = None
    rate: float | None = None
    channel_map: ChannelMap | None = None
    absent: tuple = ()


class PullRead(NamedTuple):
    """A pull read and validated: its channels, its sample rate and the warnings reading it gave."""

    channels: dict
    rate_hz: float
    warnings: list


def read_pull(job: PullJob) -> PullRead:
    """One pull file, read and validated (the per-pull step of read_campaign, run on a worker). A campaign
    CSV with no map is read as it is; any other file, or any file with a channel map or ``map:`` pairs, goes
    through the one channel-map path (channel_map.apply_map) and must hold one record."""
    fpath = Path(job.path)
    cmap, absent = job.channel_map, tuple(job.absent)
    suffix = file_format(fpath)
    warnings: list = []
    if cmap is None and job.pairs:
        cmap = pairs_map(job.pairs, where=f'{str(fpath)!r} map')
    if cmap is None and suffix == '.csv':
        raw = read_csv(fpath)
    else:
        raw, absent, _used = pull_from_file(fpath, cmap, job.rate, absent)
    channels, prate = check_channels(raw, str(fpath), job.rate, warnings, absent)
    return PullRead(channels, prate, warnings)


def pull_from_file(fpath: Path, cmap: ChannelMap | None, rate: float | None = None, absent=()) -> Mapped:
    """A one-record DAQ file through a channel map: its channels in SI and the absent channels (the map's and
    ``absent``)."""
    records = read_records(fpath)
    if len(records) != 1:
        raise BagError(f'{str(fpath)!r} holds {len(records)} records; expected one per pull file (import the '
                       'file alone to make one pull of each)')
    if rate is not None and cmap is not None and cmap.sample_rate_hz is None and records[0].rate_hz is None:
        cmap = ChannelMap(cmap.path, cmap.specs, cmap.absent, rate)
    elif rate is not None and cmap is None and records[0].rate_hz is None:
        cmap = ChannelMap('campaign.yaml', {}, (), rate)
    raw, map_absent, used = apply_map(records[0], cmap, str(fpath))
    return Mapped(raw, tuple(c for c in CHANNELS if c in absent or c in map_absent), used)


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
    jobs = [PullJob(path / meta['file'], entry.get('map'), rate, cmap, absent) for meta, entry in entries]
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


class Produced(NamedTuple):
    """What a write_campaign ``produce`` may return instead of bare channels: the channels and notes about them,
    which go back to the caller in pull order (write_campaign's ``notes``)."""

    channels: dict
    notes: Any


class WriteJob(NamedTuple):
    """One pull for write_pull: its CSV path, its channels (or produce's argument), produce or None, the
    campaign's rate or None (the pull's own), a name for messages, and the channels the campaign does not have."""

    dest: Path
    data: Any
    produce: Callable | None
    rate: float | None
    where: str
    absent: tuple = ()


class Written(NamedTuple):
    """A pull written: its sample rate, and produce's notes (None when it gave none)."""

    rate_hz: float
    notes: Any = None


def write_pull(job: WriteJob) -> Written:
    """Write one pull's CSV (the per-pull step of write_campaign, run on a worker). produce(data) -> channels
    or ``Produced`` makes the pull where it is written (a simulation, or a pull read from a bag, for example)."""
    out = job.produce(job.data) if job.produce is not None else job.data
    channels, notes = (out.channels, out.notes) if isinstance(out, Produced) else (out, None)
    chans, prate = check_channels(channels, job.where, job.rate, absent=job.absent)
    rate = prate if job.rate is None else job.rate
    n = len(chans['time_s'])
    ordered = {'time_s': time_column(n, rate)}
    ordered.update((c, chans[c]) for c in CHANNELS[1:] if c in chans)
    ordered.update((c, v) for c, v in chans.items() if c not in ordered)
    write_csv(Path(job.dest), ordered)
    return Written(float(rate), notes)


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
    notes: when produce returns ``Produced``, each pull's notes are appended here, in pull order.
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
                yield WriteJob(tmp / meta['file'], data, produce, rate, f'{str(path)}/{meta["file"]}', absent)

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
            notes.extend(r.notes for r in rates if r.notes is not None)
        rates = [r.rate_hz for r in rates]
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

