"""The channel map: which channel of a lab's DAQ file is which workspace channel, and how it becomes SI.

A channel map (YAML; see the bag_tools README and docs/reference-channel-map.md) says, per workspace channel,
which file channel it is, the file's unit, the sensitivity (``0.225 mV/N``) or scale (``4444 N/V``), an offset,
the sign convention (``tension`` or ``compression`` positive), the sensor's rated range, which channels the rig
does not have (``absent``) and the sample rate when the file lacks it. ``apply_map`` turns one ``Record`` of any
reader (``daqfiles``) into workspace channels in SI; ``pairs_map`` makes the map of ``--map COLUMN=CHANNEL``
(a file's channels already in SI, renamed), so every file goes through this one path. ``skeleton_map`` writes a
map to fill in (``--init-map``). ROS-free.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping, NamedTuple

import numpy as np
import yaml

from force_tester_common.core.channels import (
    ABSENTABLE_CHANNELS,
    CHANNELS,
    CORE_CHANNELS,
    OPTIONAL_CHANNELS,
    REQUIRED_CHANNELS,
)
from force_tester_common.core.units import CHANNEL_DIMENSION, SI_UNIT, known_units, unit, unit_name

from .daqfiles import FORMATS, NOTHING_TO_CORRECT, RATE_SNAP, Record, read_records, snap_rate, time_column
from .errors import BagError, one_line

#: Sign conventions a channel map may name: the direction the file's positive values point.
SIGNS = {'tension': 1.0, 'compression': -1.0, 1: 1.0, -1: -1.0, '+1': 1.0, '-1': -1.0}
MAP_KEYS = ('source', 'unit', 'sensitivity', 'scale', 'offset', 'sign', 'range')


def check_absent(absent, where: str) -> tuple:
    """A validated ``absent:`` list: channels of ABSENTABLE_CHANNELS or OPTIONAL_CHANNELS, never a core one."""
    if absent is None:
        return ()
    if isinstance(absent, str) or not isinstance(absent, (list, tuple)):
        raise BagError(f'{where}: absent {absent!r} is invalid; expected a list of channels, some of '
                       f'{", ".join(ABSENTABLE_CHANNELS + OPTIONAL_CHANNELS)}')
    for c in absent:
        if c in CORE_CHANNELS:
            raise BagError(f'{where}: absent names {c!r}; {NOTHING_TO_CORRECT}')
        if c not in CHANNELS:
            raise BagError(f'{where}: absent channel {c!r} is not a workspace channel; expected some of '
                           f'{", ".join(ABSENTABLE_CHANNELS + OPTIONAL_CHANNELS)}')
    return tuple(c for c in CHANNELS if c in absent)


# --------------------------------------------------------------------------- the channel map
@dataclass(frozen=True)
class ChannelSpec:
    """One workspace channel of a channel map: si = sign * (file value - offset) * factor."""

    channel: str
    source: str
    unit: str | None
    factor: float | None     # None: the file's unit decides (see resolve)
    offset: float
    sign: float
    how: str                 # 'sensitivity 0.225 mV/N', 'scale 4444 N/V' or ''
    rated: float | None = None   # the sensor's rated range (+/-, SI): values beyond it are an overload


@dataclass
class ChannelMap:
    path: str
    specs: dict = field(default_factory=dict)      # channel -> ChannelSpec
    absent: tuple = ()
    sample_rate_hz: float | None = None


def _quantity(text, key: str, where: str) -> tuple:
    """'0.225 mV/N' -> (0.225, 'mV', 'N'); a bare number -> (x, None, None)."""
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return float(text), None, None
    parts = str(text).split(None, 1)
    try:
        value = float(parts[0])
    except (ValueError, IndexError):
        raise BagError(f'{where}: {key} {text!r} is not a number with a unit; expected e.g. '
                       "'0.225 mV/N'") from None
    if len(parts) == 1:
        return value, None, None
    ratio = parts[1].replace(' ', '').replace('(', '').replace(')', '')
    for i, ch in enumerate(ratio):
        if ch == '/' and unit(ratio[:i]) and unit(ratio[i + 1:]):
            return value, unit_name(ratio[:i]), unit_name(ratio[i + 1:])
    raise BagError(f'{where}: {key} unit {parts[1]!r} is not UNIT/UNIT of known units; known units: '
                   f'{known_units()}')


def _spec(channel: str, entry, where: str) -> ChannelSpec:
    if isinstance(entry, str):
        entry = {'source': entry}
    if not isinstance(entry, Mapping):
        raise BagError(f'{where}: {channel} is {entry!r}; expected a file channel name, '
                       f'absent, or a mapping with keys {", ".join(MAP_KEYS)}')
    bad = [k for k in entry if k not in MAP_KEYS]
    if bad:
        raise BagError(f'{where}: {channel} key {bad[0]!r} is not known; expected '
                       f'{", ".join(MAP_KEYS)}')
    src = entry.get('source', channel)
    if not isinstance(src, (str, int)) or isinstance(src, bool) or str(src) == '':
        raise BagError(f'{where}: {channel} source {src!r} is invalid; expected the name of '
                       "a channel in the file")
    dim = CHANNEL_DIMENSION[channel]
    u = entry.get('unit')
    if u is not None and unit(u) is None:
        raise BagError(f'{where}: {channel} unit {u!r} is not a unit I can convert; known: {known_units()}')
    u = None if u is None else unit_name(u)
    sign_text = entry.get('sign', 'tension')
    if isinstance(sign_text, bool) or not isinstance(sign_text, (str, int)) or sign_text not in SIGNS:
        raise BagError(f'{where}: {channel} sign {sign_text!r} is invalid; expected tension or '
                       'compression (the direction the file counts positive) or +1/-1')
    offset = entry.get('offset', 0.0)
    if isinstance(offset, bool) or not isinstance(offset, (int, float)) or not math.isfinite(offset):
        raise BagError(f'{where}: {channel} offset {offset!r} is invalid; expected a finite '
                       'number in the file unit')
    if 'sensitivity' in entry and 'scale' in entry:
        raise BagError(f'{where}: {channel} gives both sensitivity and scale; expected one')
    factor, how = None, ''
    for key in ('sensitivity', 'scale'):
        if key not in entry:
            continue
        value, num, den = _quantity(entry[key], key, f'{where}: {channel}')
        if not math.isfinite(value) or value == 0:
            raise BagError(f'{where}: {channel} {key} {entry[key]!r} is invalid; expected a '
                           'finite non-zero number')
        if u is None:
            raise BagError(f'{where}: {channel} has a {key} but no unit; expected unit: the unit '
                           "of the file's values (e.g. V)")
        ud, uf = unit(u)
        if num is None:      # bare number: a scale in SI per file unit, a sensitivity in file unit per SI
            si = value if key == 'scale' else 1.0 / value
        else:
            nd, nf = unit(num)
            dd, df = unit(den)
            want = (ud, dim) if key == 'sensitivity' else (dim, ud)
            if (nd, dd) != want:
                raise BagError(f'{where}: {channel} {key} {entry[key]!r} is in {num}/{den}; '
                               f'expected {SI_UNIT[want[0]]}/{SI_UNIT[want[1]]} or units of the same kind '
                               f'(the file unit is {u!r}, the channel is in {SI_UNIT[dim]})')
            si = value * nf / df
            si = 1.0 / si if key == 'sensitivity' else si
        factor, how = uf * si, f'{key} {entry[key]}'
    if factor is None and u is not None:
        ud, uf = unit(u)
        if ud != CHANNEL_DIMENSION[channel]:
            raise BagError(f'{where}: {channel} unit {u!r} ({ud}) cannot be converted to '
                           f'{SI_UNIT[dim]} without a sensitivity or scale; expected a {dim} unit or '
                           'sensitivity: e.g. 0.225 mV/N')
        factor = uf
    rated = _rated(entry['range'], channel, dim, u, factor, where) if 'range' in entry else None
    return ChannelSpec(channel, str(src), u, factor, float(offset),
                       SIGNS[sign_text], how, rated)


def _rated(text, channel: str, dim: str, file_unit: str | None, factor: float | None, where: str) -> float:
    """A sensor's rated range in SI: '50 g', '22 kN' (a unit of the channel's kind), '5 V' (the file's unit,
    converted as the values are) or a bare number (SI); +/- the value."""
    parts = str(text).split(None, 1) if not isinstance(text, (int, float)) or isinstance(text, bool) else [text]
    try:
        value = float(parts[0])
    except (TypeError, ValueError, IndexError):     # IndexError: an empty range ('')
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise BagError(f'{where}: {channel} range {text!r} is invalid; expected the sensor\'s rated range, a '
                       'number > 0 with a unit, e.g. 50 g or 22 kN')
    if len(parts) == 1:
        return value
    u = parts[1].strip()
    if unit(u) is None:
        raise BagError(f'{where}: {channel} range unit {u!r} is not a unit I can convert; known: {known_units()}')
    ud, uf = unit(u)
    if ud == dim:
        return value * uf
    if file_unit is not None and unit_name(u) == unit_name(file_unit) and factor is not None:
        return value * factor
    raise BagError(f'{where}: {channel} range {text!r} is in {u}; expected a unit of {dim} ({SI_UNIT[dim]}) or the '
                   f'file unit{" " + repr(file_unit) if file_unit else ""}')


def load_channel_map(source) -> ChannelMap:
    """A channel map from a YAML file path (or an already parsed mapping); BagError naming key and value."""
    if isinstance(source, Mapping):
        doc, where = source, 'channel map'
    else:
        where = f'channel map {Path(source).name}'
        try:
            doc = yaml.safe_load(Path(source).read_text(encoding='utf-8'))
        except OSError as exc:
            raise BagError(f'cannot read {where}: {one_line(exc)}') from None
        except UnicodeDecodeError as exc:
            raise BagError(f'{where} is not UTF-8 text ({one_line(exc)}); expected a YAML file') from None
        except yaml.YAMLError as exc:
            raise BagError(f'{where} is not valid YAML: {one_line(exc)}') from None
    if not isinstance(doc, Mapping) or not isinstance(doc.get('channels'), Mapping):
        raise BagError(f'{where} has no channels mapping; expected channels: {{force_moving_n: '
                       '{source: ..., unit: V, sensitivity: 0.225 mV/N}, ...}')
    bad = [k for k in doc if k not in ('channels', 'absent', 'sample_rate_hz')]
    if bad:
        raise BagError(f'{where}: key {bad[0]!r} is not known; expected channels, absent, sample_rate_hz')
    cmap = ChannelMap(where)
    absent = doc.get('absent') or []
    if not isinstance(absent, (str, list, tuple)):
        raise BagError(f'{where}: absent {absent!r} is invalid; expected a list of channels, some of '
                       f'{", ".join(ABSENTABLE_CHANNELS + OPTIONAL_CHANNELS)}')
    absent = [absent] if isinstance(absent, str) else list(absent)
    for channel, entry in doc['channels'].items():
        if channel not in CHANNELS or channel == 'time_s' and entry == 'absent':
            raise BagError(f'{where}: {channel} is not a workspace channel; expected one of '
                           f'{", ".join(CHANNELS)}')
        if entry == 'absent' or entry is None:
            absent.append(channel)
            continue
        cmap.specs[channel] = _spec(channel, entry, where)
    cmap.absent = check_absent(absent, where)
    rate = doc.get('sample_rate_hz')
    if rate is not None:
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not math.isfinite(rate) or rate <= 0:
            raise BagError(f'{where}: sample_rate_hz {rate!r} is invalid; expected a finite rate > 0 Hz')
        cmap.sample_rate_hz = float(rate)
    return cmap


class Mapped(NamedTuple):
    """One record through a channel map: its channels in SI with time_s, the channels the rig does not have, and
    per channel used, (channel, file channel, file unit, how it was scaled) for ``--dry-run``."""

    channels: dict
    absent: tuple
    used: list


def pairs_map(pairs: Mapping[str, str] | Iterable[str] | None, rate: float | None = None,
              where: str = '--map') -> ChannelMap | None:
    """The channel map of ``--map COLUMN=CHANNEL`` pairs (a list of such strings, or {column: channel}): each
    named workspace channel read from that file channel, in the file's unit (SI when the file states none);
    ``time_s`` may be named too. None when there are no pairs and no rate."""
    if pairs is None or isinstance(pairs, (str, bytes)) or not isinstance(pairs, (Mapping, list, tuple)):
        if pairs is not None:
            raise BagError(f'{where} {pairs!r} is invalid; expected a mapping {{column: channel}} or a list of '
                           'COLUMN=CHANNEL')
        pairs = {}
    if not isinstance(pairs, Mapping):
        items = {}
        for item in pairs:
            if not isinstance(item, str) or '=' not in item:
                raise BagError(f'{where} {item!r} is invalid; expected COLUMN=CHANNEL')
            k, v = item.split('=', 1)
            items[k.strip()] = v.strip()
        pairs = items
    specs = {}
    for col, src in pairs.items():
        if col not in CHANNELS:
            raise BagError(f'{where} column {col!r} is not a DAQ column; expected one of {", ".join(CHANNELS)}')
        specs[col] = ChannelSpec(col, str(src), None, None, 0.0, 1.0, '')
    if not specs and rate is None:
        return None
    return ChannelMap(where, specs, (), None if rate is None else snap_rate(float(rate)))


def apply_map(record: Record, cmap: ChannelMap | None, where: str) -> Mapped:
    """One record of a DAQ file as workspace channels in SI (``Mapped``)."""
    out: dict = {}
    used: list = []
    specs = dict(cmap.specs) if cmap else {}
    absent = cmap.absent if cmap else ()
    names = ', '.join(sorted(record.channels)) or 'none'
    for ch in CHANNELS[1:]:
        spec = specs.get(ch)
        if spec is None:
            if ch in record.channels and ch not in absent:   # a column already named as ours, in SI
                out[ch] = record.channels[ch]
                used.append((ch, ch, record.units.get(ch), ''))
            continue
        if spec.source not in record.channels:
            raise BagError(f'{where}: channel map {ch}: source {spec.source!r} is not a channel of the file; '
                           f'its channels: {names}')
        raw = record.channels[spec.source]
        factor, u = spec.factor, spec.unit
        if factor is None:      # no unit in the map: the file's own unit, else SI already
            u = record.units.get(spec.source)
            if u and unit(u) is None:
                raise BagError(f'{where}: channel {spec.source!r} ({ch}) has unit {u!r}, not one I can '
                               f'convert; give unit: and a sensitivity or scale in the channel map; known units: '
                               f'{known_units()}')
            factor = 1.0
            if u:
                ud, factor = unit(u)
                if ud != CHANNEL_DIMENSION[ch]:
                    raise BagError(f'{where}: channel {spec.source!r} ({ch}) is in {u!r}, not a '
                                   f'{CHANNEL_DIMENSION[ch]} unit; give a sensitivity or scale in the channel map')
        with np.errstate(all='ignore'):     # a value that overflows is inf, as the file said in effect
            out[ch] = spec.sign * (raw - spec.offset) * factor if (spec.sign, spec.offset, factor) != (1.0, 0.0, 1.0) \
                else raw
        used.append((ch, spec.source, u, spec.how + (' compression positive' if spec.sign < 0 else '') +
                     (f', rated +/-{spec.rated:.6g} {SI_UNIT[CHANNEL_DIMENSION[ch]]}' if spec.rated else '')))
    for ch in CORE_CHANNELS[1:]:
        if ch not in out:
            raise BagError(f'{Path(where).name}: no {ch} channel; {NOTHING_TO_CORRECT}; file channels: {names}')
    file_rate = record.rate_hz
    map_rate = cmap.sample_rate_hz if cmap else None
    if file_rate and map_rate and abs(file_rate - map_rate) > RATE_SNAP * map_rate:
        raise BagError(f'{where}: channel map sample_rate_hz {map_rate!r} disagrees with the file\'s '
                       f'{file_rate!r} Hz; expected the map to give a rate only when the file lacks one')
    n = len(next(iter(out.values())))
    rate = file_rate or map_rate
    tspec = specs.get('time_s')
    if tspec is not None:
        if tspec.source not in record.channels:
            raise BagError(f'{where}: channel map time_s: source {tspec.source!r} is not a channel of the file; '
                           f'its channels: {names}')
        out = {'time_s': (record.channels[tspec.source] - tspec.offset) * (tspec.factor or 1.0), **out}
    elif rate:
        out = {'time_s': time_column(n, rate), **out}
    elif record.time is not None:
        out = {'time_s': record.time, **out}
    else:
        raise BagError(f'{where}: the file gives no sample rate and no time; expected sample_rate_hz in the '
                       'channel map (or --rate)')
    missing = [c for c in REQUIRED_CHANNELS if c not in out and c not in absent]
    if missing:
        raise BagError(f'{where}: required channel {missing[0]!r} is not in the file (its channels: {names}); '
                       "expected it in the channel map, or named absent (absent: [" + missing[0] + '])')
    return Mapped(out, tuple(c for c in absent if c not in out), used)


# --------------------------------------------------------------------------- a skeleton channel map (--init-map)
#: What a skeleton channel map leaves for the user to write: load_channel_map refuses it in one line until it is.
FILL_IN = 'FILL_IN'
#: The workspace channels a skeleton map guesses, in order: (channel, name fragments that suggest it).
GUESSED = (('force_moving_n', ('force', 'load', 'kraft', 'cell', 'hammer')), ('accel_axial_m_s2', ('acc',)),
           ('force_stationary_n', ('stat', 'reference')), ('encoder_position_m', ('enc', 'pos', 'disp')))
#: The physical unit a sensitivity placeholder is written in, per dimension.
SENSITIVITY_PER = {'force': 'N', 'acceleration': 'g', 'length': 'mm'}


def _scalar(text) -> str:
    """A YAML scalar for any text (JSON's double-quoted string is YAML)."""
    import json
    return json.dumps(str(text), ensure_ascii=False)


def skeleton_map(path: str | Path) -> str:
    """A channel map YAML for a DAQ file (``./ft bag import FILE --init-map MAP.yaml``): the file's channels with
    their units and ranges of values, its rate, duration and records, and a guess of which file channel is which
    workspace channel (by its unit, else its name, else its order), with comments saying what to fill in. What
    only the user knows (a sensitivity of a channel in volts, a unit the file does not state, a rate it lacks) is
    written FILL_IN, which load_channel_map refuses, so an unfilled map never imports."""
    path = Path(path)
    records = read_records(path)
    rec = records[0]
    names = list(rec.channels)
    if not names:
        raise BagError(f'DAQ file {str(path)!r} has no channels; expected at least a force and an acceleration')
    dims = {c: getattr(unit(rec.units.get(c)), 'dimension', None) for c in names}
    n = len(rec.channels[names[0]])
    rate = rec.rate_hz
    if rate is None and rec.time is not None and len(rec.time) > 1 and rec.time[-1] > rec.time[0]:
        rate = snap_rate((len(rec.time) - 1) / (rec.time[-1] - rec.time[0]))
    taken: dict = {}       # workspace channel -> (file channel, why)
    for ch, _hints in GUESSED:                      # 1: a file channel whose unit is of the channel's kind
        free = [c for c in names if c not in {s for s, _ in taken.values()} and dims[c] == CHANNEL_DIMENSION[ch]]
        if free:
            taken[ch] = (free[0], f'its unit {rec.units[free[0]]!r} measures {CHANNEL_DIMENSION[ch]}')
    raw = [c for c in names if dims[c] not in set(CHANNEL_DIMENSION.values()) - {'voltage'}]
    for ch, hints in GUESSED:                       # 2: a channel in volts (or no known unit) named like it
        if ch in taken:
            continue
        free = [c for c in raw if c not in {s for s, _ in taken.values()} and any(h in c.lower() for h in hints)]
        if free:
            taken[ch] = (free[0], 'guessed from its name: check')
    for ch in CORE_CHANNELS[1:][::-1]:              # 3: the core channels from what is left, in order
        if ch in taken:
            continue
        free = [c for c in raw if c not in {s for s, _ in taken.values()}]
        if free:
            taken[ch] = (free[0], 'guessed from the order of the channels: check')
    duration = n / rate if rate else None
    lines = [f'# Channel map skeleton of {path.name} (./ft bag import {path.name} --init-map): which channel of the',
             '# file is which workspace channel, and how its values become SI (src/bag_tools/README.md, "DAQ files as',
             '# labs write them"). Fill in every FILL_IN (an unfilled map is refused), check every guess, then:',
             f'#   ./ft bag import {path.name} --channels THIS.yaml --dry-run',
             f'# file: {FORMATS[path.suffix.lower()]}, {len(records)} record(s) (a pull each); the first: {n} samples'
             + (f' at {rate:g} Hz, {duration:.6g} s' if rate else ', no sample rate in the file'),
             '# its channels (unit as the file states it; values min .. max):']
    for c in names:
        v = rec.channels[c]
        fin = v[np.isfinite(v)]
        span = f'{fin.min():.6g} .. {fin.max():.6g}' if fin.size else 'no finite value'
        lines.append(f'#   {_scalar(c)} [{rec.units.get(c) or "no unit"}] {span}')
    if rate and rec.rate_hz:
        lines.append(f'# sample_rate_hz: not needed, the file gives {rate:g} Hz')
    elif rate:
        lines.append(f'# sample_rate_hz: not needed, the file\'s time column gives {rate:g} Hz')
    else:
        lines.append(f'sample_rate_hz: {FILL_IN}     # the file gives no rate: the DAQ\'s sample rate, Hz')
    lines.append('channels:')
    for ch, _hints in GUESSED:
        if ch not in taken:
            continue
        src, why = taken[ch]
        dim = CHANNEL_DIMENSION[ch]
        fu = rec.units.get(src)
        lines += [f'  {ch}:                  # {why}', f'    source: {_scalar(src)}']
        if dims[src] == dim:
            lines.append(f'    unit: {_scalar(fu)}            # as the file states it: no sensitivity needed')
        else:
            u = unit_name(fu) if fu and unit(fu) else None
            lines.append(f'    unit: {_scalar(u or FILL_IN)}' + ('' if u else
                         f'            # the file states {fu!r}: the unit of its values (V, mV, mV/V, ...)'
                         if fu else '            # the file states none: the unit of its values (V, mV, ...)'))
            per = SENSITIVITY_PER.get(dim, SI_UNIT[dim])
            num = 'mV' if u in (None, 'V') else u
            lines.append(f'    sensitivity: {FILL_IN} {num}/{per}   # the sensor\'s, from its calibration sheet '
                         f'(or scale: {SI_UNIT[dim]} per {u or "file unit"})')
        lines += ['    sign: tension            # the direction the file counts positive: tension or compression',
                  f'    # range: {FILL_IN} {SENSITIVITY_PER.get(dim, SI_UNIT[dim])}'
                  '   # optional: the sensor\'s rated range (+/-); beyond it is an overload']
    absent = [c for c in ABSENTABLE_CHANNELS if c not in taken]
    left = [c for c in names if c not in {s for s, _ in taken.values()}]
    if left:
        lines.append('  # other channels of the file: map one to ' + ', '.join(OPTIONAL_CHANNELS) + ' if it is one')
        lines += [f'  #   {_scalar(c)} [{rec.units.get(c) or "no unit"}]' for c in left]
    if absent:
        lines.append(f'absent: [{", ".join(absent)}]   # the channels your rig does not have')
    missing = [c for c in CORE_CHANNELS[1:] if c not in taken]
    if missing:
        lines.append(f'# NOT FOUND in the file: {", ".join(missing)}: the correction and discover need both; map them '
                     'above')
    return '\n'.join(lines) + '\n'
