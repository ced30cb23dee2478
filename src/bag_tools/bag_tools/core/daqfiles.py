"""DAQ files as labs write them: one reader per format, each giving the file's records; the campaign CSV written.

Formats (``FORMATS``): the campaign CSV, NI TDMS (npTDMS), NI LabVIEW ``.lvm`` text (lvm-read), ASAM
MDF4 ``.mf4`` (asammdf) and UFF 58 ``.uff``/``.unv`` (pyuff). Each reader gives the file's records
(``Record``: its channels by the file's own names, their units when the file says, its sample rate
when the file says); ``channel_map.apply_map`` turns one record into workspace channels in SI. The
libraries are imported lazily, only for their own format (asammdf alone takes about 2 s to import).
ROS-free.
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
from pathlib import Path
from time import monotonic
from typing import Mapping, NamedTuple

import numpy as np

from force_tester_common.core.channels import REQUIRED_CHANNELS

from .errors import BagError, one_line

#: suffix -> format name, the formats ``./ft bag import`` reads.
FORMATS = {'.csv': 'campaign CSV', '.tdms': 'NI TDMS', '.lvm': 'LabVIEW LVM', '.mf4': 'ASAM MDF4',
           '.mdf': 'ASAM MDF4', '.uff': 'UFF 58', '.unv': 'UFF 58'}
#: Rates within this relative tolerance of an integer are that integer (a 1e-5 s increment stored in binary).
RATE_SNAP = 1e-6
NOTHING_TO_CORRECT = 'there is nothing to correct (the correction needs force_moving_n and accel_axial_m_s2)'


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
    # the rate only from a time channel that is finite and strictly increasing; any other is the pull's time column
    # as it is, which the time checks refuse with its row (asammdf fills a corrupt block's samples from memory it
    # never wrote, so a rate from the two ends would be a guess and the samples imported as evenly spaced)
    if time is not None and time.size > 1 and np.all(np.isfinite(time)) and np.all(np.diff(time) > 0):
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


def read_tdms(path: Path) -> list:
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
    out = {name: _float_column(table.column(name)) for name in names}
    del table
    # pyarrow's allocator (mimalloc) keeps the pages of the parse (the file's bytes, its parsed blocks: ~40 MB for a
    # 17 MB pull) for its next allocation; a process reading one pull at a time (a discover worker) held them to the
    # end. The columns are numpy's own copies, so all of it is returned here (about 1.5 ms).
    pa.default_memory_pool().release_unused()
    return out


def _float_column(col) -> np.ndarray:
    """A float64 column of pyarrow's as numpy's own array (nulls NaN), read from its buffers: pyarrow's to_numpy
    imports pandas (~60 MB of a process's memory, ~0.5 s) for nothing here."""
    parts = []
    for c in col.chunks:
        if not len(c):
            continue
        valid, data = c.buffers()
        x = np.frombuffer(data, dtype=np.float64, count=len(c), offset=c.offset * 8)
        if c.null_count:
            bits = np.unpackbits(np.frombuffer(valid, dtype=np.uint8), count=c.offset + len(c), bitorder='little')
            x = np.where(bits[c.offset:].astype(bool), x, np.nan)
        parts.append(x)
    return np.concatenate(parts) if parts else np.zeros(0)


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


# --------------------------------------------------------------------------- the campaign CSV, written
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


READERS = {'.csv': read_csv_raw, '.tdms': read_tdms, '.lvm': read_lvm, '.mf4': read_mdf, '.mdf': read_mdf,
           '.uff': read_uff, '.unv': read_uff}


def read_records(path: str | Path) -> list:
    """The Records of a DAQ file of any known format."""
    path = Path(path)
    suffix = file_format(path)
    if not path.is_file():
        raise BagError(f'DAQ file {str(path)!r} does not exist')
    return READERS[suffix](path)
