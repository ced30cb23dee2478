"""DAQ files as labs write them, and the channel map that turns their channels into ours.

Formats (``FORMATS``): the campaign CSV, NI TDMS (npTDMS), NI LabVIEW ``.lvm`` text (lvm-read), ASAM
MDF4 ``.mf4`` (asammdf) and UFF 58 ``.uff``/``.unv`` (pyuff). Each reader gives the file's records
(``Record``: its channels by the file's own names, their units when the file says, its sample rate
when the file says); ``apply_map`` turns one record into workspace channels in SI with a channel map.

A channel map (YAML; see the bag_tools README) says, per workspace channel, which file channel it is,
the file's unit, the sensitivity (``0.225 mV/N``) or scale (``4444 N/V``), an offset, the sign
convention (``tension`` or ``compression`` positive), which channels the rig does not have
(``absent``) and the sample rate when the file lacks it. The libraries are imported lazily, only for
their own format (asammdf alone takes about 2 s to import). ROS-free.
"""

from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import pickle
import select
import signal
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from time import monotonic
from typing import Mapping, NamedTuple

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

from .errors import BagError, one_line

#: suffix -> format name, the formats ``./ft bag import`` reads.
FORMATS = {'.csv': 'campaign CSV', '.tdms': 'NI TDMS', '.lvm': 'LabVIEW LVM', '.mf4': 'ASAM MDF4',
           '.mdf': 'ASAM MDF4', '.uff': 'UFF 58', '.unv': 'UFF 58'}
#: Sign conventions a channel map may name: the direction the file's positive values point.
SIGNS = {'tension': 1.0, 'compression': -1.0, 1: 1.0, -1: -1.0, '+1': 1.0, '-1': -1.0}
MAP_KEYS = ('source', 'unit', 'sensitivity', 'scale', 'offset', 'sign', 'range')
#: Rates within this relative tolerance of an integer are that integer (a 1e-5 s increment stored in binary).
RATE_SNAP = 1e-6
NOTHING_TO_CORRECT = 'there is nothing to correct (the correction needs force_moving_n and accel_axial_m_s2)'


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


def known_formats() -> str:
    return ', '.join(FORMATS)


def file_format(path: str | Path) -> str:
    """The suffix of a DAQ file ``./ft bag import`` reads; BagError listing the known ones otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise BagError(f'unknown DAQ file format {suffix or "(no suffix)"!r} of {Path(path).name!r}; known '
                       f'formats: {known_formats()}')
    return suffix


def snap_rate(rate: float) -> float:
    if not math.isfinite(rate):      # a corrupt time column: the checks after say what is wrong with it
        return float(rate)
    if abs(round(rate) - rate) <= RATE_SNAP * rate:
        return float(round(rate))
    return float(rate)


class Record(NamedTuple):
    """One record of a DAQ file: channels {file name: float64 array}, units {file name: unit or None},
    the file's sample rate (None when it gives none) and its time column (None when it has none)."""

    channels: dict
    units: dict
    rate_hz: float | None
    time: np.ndarray | None


# --------------------------------------------------------------------------- readers
def time_column(n: int, rate_hz: float) -> np.ndarray:
    """time_s = k / rate exactly (float64 division, as the sim does)."""
    return np.arange(n) / rate_hz


@contextlib.contextmanager
def quiet():
    """A library's own stderr kept off the user's terminal while it reads a file: its log lines (npTDMS warns of a
    short last segment on two lines), Python warnings and numpy's floating-point warnings (a value that
    overflows to inf on scaling). The command's one line says what matters; found by fuzzing."""
    loggers = [lg for name, lg in list(logging.Logger.manager.loggerDict.items())     # npTDMS: one a module
               if isinstance(lg, logging.Logger) and name.split('.')[0] in QUIET_LOGGERS]
    was = [lg.disabled for lg in loggers]
    for lg in loggers:
        lg.disabled = True
    try:
        with warnings.catch_warnings(), np.errstate(all='ignore'):
            warnings.simplefilter('ignore')
            yield
    finally:
        for lg, w in zip(loggers, was):
            lg.disabled = w


#: The loggers of the readers' libraries (quiet()).
QUIET_LOGGERS = ('nptdms', 'asammdf', 'pyuff', 'lvm_read')


def _missing(pip: str) -> BagError:
    return BagError(f'reading this format needs {pip}: pip install {pip} (see requirements.txt)')


def read_lvm(path: Path) -> list:
    """LabVIEW Measurement File (text): one Record per segment. X_Value columns give time; Delta_X the
    rate; Y_Unit_Label the units; a Comment column is dropped."""
    try:
        import lvm_read  # imported only for its format
    except ImportError:
        raise _missing('lvm-read') from None
    try:
        with quiet():
            doc = lvm_read.read(str(path), read_from_pickle=False, dump_file=False)
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot read LVM file {str(path)!r}: {one_line(exc)}') from None
    records = []
    for s in range(int(doc.get('Segments', 0))):
        seg = doc[s]
        data = np.asarray(seg.get('data'), dtype=np.float64)
        names = list(seg.get('Channel names', []))
        if data.ndim != 2 or not names:
            raise BagError(f'LVM file {str(path)!r} segment {s + 1} has no data; expected a header with '
                           'X_Value and channel names, then rows of numbers')
        labels = seg.get('Y_Unit_Label') or []
        dx = [d for d in seg.get('Delta_X', []) if isinstance(d, float) and math.isfinite(d) and d > 0]
        chans, units, time, k = {}, {}, None, 0
        for i, name in enumerate(names):
            name = name.strip()
            if i >= data.shape[1] or name == 'Comment':
                continue
            if name == 'X_Value':
                if time is None and np.isfinite(data[:, i]).all():
                    time = data[:, i].copy()
                continue
            chans.setdefault(name, np.ascontiguousarray(data[:, i]))
            lab = labels[k].strip() if k < len(labels) else ''
            units.setdefault(name, lab or None)
            k += 1
        records.append(Record(chans, units, snap_rate(1.0 / dx[0]) if dx else None, time))
    if not records:
        raise BagError(f'LVM file {str(path)!r} has no data segment')
    return records


def read_mdf(path: Path) -> list:
    """ASAM MDF4: one Record; every non-master channel, its unit; the rate from its timestamps.

    asammdf parses in a forked child process: on some corrupt files its C code dies of a segmentation fault
    (found by fuzzing, docs/reliability.md), which here is a BagError, not the end of the command. The child
    keeps asammdf's log lines and its half-built objects' errors off the user's terminal; its answer comes back
    pickled through a pipe (the channels: a copy, as big as the file's samples)."""
    try:
        import asammdf  # noqa: F401 - imported only for its format, before the fork (2 s)
    except ImportError:
        raise _missing('asammdf') from None
    limit = MDF_LIMIT_S + path.stat().st_size / MDF_LIMIT_BYTES_PER_S
    receive, send = os.pipe()
    pid = os.fork()        # os.fork, not multiprocessing: a Dask worker is a daemonic process, which may not have one
    if pid == 0:           # the child: parse, answer, exit without running the parent's exit handlers
        try:
            os.close(receive)
            quiet_fd = os.open(os.devnull, os.O_WRONLY)     # asammdf prints (CHANNEL ARRAY ...) on some files
            os.dup2(quiet_fd, 1)
            os.dup2(quiet_fd, 2)
            with os.fdopen(send, 'wb') as fh:
                fh.write(pickle.dumps(_mdf_child(str(path)), protocol=pickle.HIGHEST_PROTOCOL))
        finally:
            os._exit(0)
    os.close(send)
    answer, deadline = bytearray(), monotonic() + limit
    with os.fdopen(receive, 'rb', buffering=0) as fh:
        while True:
            ready, _w, _x = select.select([fh], [], [], max(0.0, deadline - monotonic()))
            if not ready:          # asammdf loops or allocates without end on some corrupt files
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                raise BagError(f'cannot read MDF4 file {str(path)!r}: the MDF4 reader (asammdf) took over '
                               f'{limit:.0f} s on it and was stopped; expected a valid ASAM MDF4 file')
            chunk = fh.read(1 << 20)
            if not chunk:
                break
            answer += chunk
    _pid, status = os.waitpid(pid, 0)
    try:
        kind, *rest = pickle.loads(answer) if answer else ('died',)
    except Exception:  # noqa: BLE001 - a child killed while it wrote its answer
        kind, rest = 'died', []
    if kind == 'died':
        code = -os.WTERMSIG(status) if os.WIFSIGNALED(status) else os.WEXITSTATUS(status)
        raise BagError(f'cannot read MDF4 file {str(path)!r}: the MDF4 reader (asammdf) crashed on it (exit code '
                       f'{code}); expected a valid ASAM MDF4 file')
    if kind == 'error':
        raise BagError(f'cannot read MDF4 file {str(path)!r}: {rest[0]}')
    chans, units, time = rest
    rate = None
    if time is not None and time.size > 1 and time[-1] > time[0]:
        with np.errstate(all='ignore'):     # a subnormal span: an infinite rate, which the time checks refuse
            rate = snap_rate((time.size - 1) / (time[-1] - time[0]))
    return [Record(chans, units, rate, time)]


#: How long asammdf may take on an MDF4 file before it is stopped: this, plus the file's size at this rate (its
#: parse of a valid file runs at 100 MB/s and more; fuzzing found corrupt 6 kB files it never finished).
MDF_LIMIT_S = 30.0
MDF_LIMIT_BYTES_PER_S = 5e6


def _mdf_child(path: str) -> tuple:
    """read_mdf's child: ('ok', channels, units, the first channel's time) or ('error', one line)."""
    import faulthandler  # noqa: PLC0415

    import asammdf
    faulthandler.disable()     # a crash here is the parent's one line, not a dump of this child's stack
    logging.getLogger('asammdf').disabled = True
    sys.unraisablehook = lambda _unraisable: None     # a half-built MDF4's __del__ raises AttributeError
    try:
        with quiet():
            mdf = asammdf.MDF(path)
            chans, units, time = {}, {}, None
            try:
                for sig in mdf.iter_channels():
                    if sig.name in chans:
                        continue
                    chans[sig.name] = np.asarray(sig.samples, dtype=np.float64)
                    units[sig.name] = sig.unit or None
                    if time is None:
                        time = np.asarray(sig.timestamps, dtype=np.float64)
            finally:
                mdf.close()
        return 'ok', chans, units, time
    except Exception as exc:  # noqa: BLE001 - whatever asammdf raises is the file's fault
        return 'error', one_line(exc)


def read_uff(path: Path) -> list:
    """UFF 58 (universal file, function at nodes): one Record of every type-58 set, named by id1."""
    try:
        import pyuff  # imported only for its format
    except ImportError:
        raise _missing('pyuff') from None
    try:
        with quiet():
            sets = pyuff.UFF(str(path)).read_sets()
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot read UFF file {str(path)!r}: {one_line(exc)}') from None
    sets = [sets] if isinstance(sets, dict) else list(sets)
    chans, units, rate = {}, {}, None
    for s in sets:
        if s.get('type') != 58:
            continue
        name = str(s.get('id1', '')).strip() or f'{s.get("rsp_node")}{s.get("rsp_dir")}'
        chans.setdefault(name, np.real(np.asarray(s['data'])).astype(np.float64))
        units.setdefault(name, str(s.get('ordinate_axis_units_lab', '')).strip() or None)
        inc = float(s.get('abscissa_inc') or 0)
        if rate is None and inc > 0:
            rate = snap_rate(1.0 / inc)
    if not chans:
        raise BagError(f'UFF file {str(path)!r} has no dataset 58 (a function); expected time records')
    return [Record(chans, units, rate, None)]


def read_tdms_raw(path: Path) -> list:
    """NI TDMS: one Record; channels as 'Group/Channel' (and 'Channel'), unit_string, wf_increment."""
    try:
        import nptdms  # imported only for its format
    except ImportError:
        raise _missing('npTDMS') from None
    try:
        with quiet():
            tdms = nptdms.TdmsFile.read(str(path))
    except Exception as exc:  # noqa: BLE001
        raise BagError(f'cannot read TDMS file {str(path)!r}: {one_line(exc)}') from None
    chans, units, rate = {}, {}, None
    for group in tdms.groups():
        for ch in group.channels():
            a = np.asarray(ch[:], dtype=np.float64)
            u = ch.properties.get('unit_string') or None
            for name in (f'{group.name}/{ch.name}', ch.name):
                chans.setdefault(name, a)
                units.setdefault(name, u)
            inc = ch.properties.get('wf_increment')
            if inc and rate is None:
                rate = snap_rate(1.0 / float(inc))
    return [Record(chans, units, rate, None)]


def read_csv(path: Path) -> dict:
    """One pull CSV -> {column: float64 array}. Header row, comma separated.

    pyarrow's multithreaded-capable C++ reader (correctly rounded, so bit for bit what float() gives)
    reads a well-formed file; anything it refuses (a short row, a word, spaces) is read again by numpy
    and row by row, which name the line and the value."""
    try:
        with open(path, 'rb') as fh:
            header = fh.readline().decode('utf-8')
            body_at = fh.tell()
            has_body = bool(fh.read(4096).strip())
    except (OSError, UnicodeDecodeError) as exc:
        raise BagError(f'cannot read {str(path)!r}: {one_line(exc)}') from None
    names = [h.strip() for h in header.strip().split(',')]
    if not header.strip() or any(not h for h in names):
        raise BagError(f'{str(path)!r}: header row {header.strip()!r} is invalid; expected '
                       f'comma-separated column names like {",".join(REQUIRED_CHANNELS)}')
    dup = sorted({h for h in names if names.count(h) > 1})
    if dup:
        raise BagError(f'{str(path)!r}: column {dup[0]!r} appears twice in the header')
    fast = _read_csv_arrow(path, names, body_at) if has_body else None
    if fast is not None:
        return fast
    try:
        with open(path, encoding='utf-8', newline='') as fh:
            fh.readline()
            body = fh.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise BagError(f'cannot read {str(path)!r}: {one_line(exc)}') from None
    if not body.strip():
        raise BagError(f'{str(path)!r} has a header but no data rows; expected one row per sample')
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=',', dtype=np.float64, ndmin=2)
    except ValueError:
        data = _read_csv_slow(path, body, len(names))
    if data.shape[1] != len(names):
        raise BagError(f'{str(path)!r}: rows have {data.shape[1]} values but the header names '
                       f'{len(names)} columns')
    return {name: np.ascontiguousarray(data[:, i]) for i, name in enumerate(names)}


#: What the fast reader reads as NaN (as float() and the slow reader do): empty fields and nan.
_NAN_FIELDS = ['', 'nan', 'NaN', 'NAN', '-nan', '+nan']


def _read_csv_arrow(path: Path, names: list, body_at: int) -> dict | None:
    """The columns by pyarrow.csv, or None when pyarrow is missing or refuses the file."""
    try:
        import pyarrow as pa  # ~0.1 s to import: only where CSV is read
        import pyarrow.csv as pcsv
    except ImportError:
        return None
    try:
        with open(path, 'rb') as fh:
            fh.seek(body_at)
            table = pcsv.read_csv(fh, read_options=pcsv.ReadOptions(column_names=names, use_threads=False),
                                  parse_options=pcsv.ParseOptions(delimiter=','),
                                  convert_options=pcsv.ConvertOptions(
                                      column_types={n: pa.float64() for n in names}, null_values=_NAN_FIELDS,
                                      strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowException, OSError, ValueError):
        return None
    if table.num_rows == 0:
        return None
    out = {}
    for name in names:
        col = table.column(name)
        a = col.to_numpy() if col.null_count == 0 else col.fill_null(np.nan).to_numpy()
        out[name] = np.ascontiguousarray(a, dtype=np.float64)
    return out


def _read_csv_slow(path: Path, body: str, ncol: int) -> np.ndarray:
    """Row by row: empty fields become NaN; anything else unparsable is an error."""
    rows = []
    for lineno, line in enumerate(body.splitlines(), start=2):
        if not line.strip():
            continue
        parts = line.split(',')
        if len(parts) != ncol:
            raise BagError(f'{str(path)!r} line {lineno} has {len(parts)} values; expected '
                           f'{ncol} (one per header column)')
        row = []
        for p in parts:
            p = p.strip()
            try:
                row.append(float(p) if p else math.nan)
            except ValueError:
                raise BagError(f'{str(path)!r} line {lineno}: value {p!r} is not a number') \
                    from None
        rows.append(row)
    return np.asarray(rows, dtype=np.float64).reshape(-1, ncol)


def read_csv_raw(path: Path) -> list:
    chans = read_csv(path)
    time = chans.pop('time_s', None)
    return [Record(chans, {}, None, time)]


READERS = {'.csv': read_csv_raw, '.tdms': read_tdms_raw, '.lvm': read_lvm, '.mf4': read_mdf, '.mdf': read_mdf,
           '.uff': read_uff, '.unv': read_uff}


def read_records(path: str | Path) -> list:
    """The Records of a DAQ file of any known format."""
    path = Path(path)
    suffix = file_format(path)
    if not path.is_file():
        raise BagError(f'DAQ file {str(path)!r} does not exist')
    return READERS[suffix](path)


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


def apply_map(record: Record, cmap: ChannelMap | None, where: str) -> tuple:
    """(channels in SI with time_s, absent channels, [(channel, source, file unit, how)]) of one record."""
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
    return out, tuple(c for c in absent if c not in out), used


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
    dims = {c: (unit(rec.units.get(c)) or (None,))[0] for c in names}
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
