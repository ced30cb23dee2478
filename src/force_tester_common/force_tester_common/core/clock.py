"""The sample clock: every stamp in the workspace is an integer number of nanoseconds.

Sample k of a record (or block) whose first sample is stamped ``first_ns`` at ``rate_hz`` is
stamped ``first_ns + k * 1e9 / rate_hz``, computed exactly (floor) for an integer rate and
rounded to the nearest nanosecond otherwise. The sim, the DAQ importer, the bag tools, the
pairing and the scoring all call these functions, so a sample has one stamp wherever it goes.
"""
from __future__ import annotations

import numpy as np

NS_PER_S = 1_000_000_000


def _is_integer_rate(rate_hz: float) -> bool:
    return float(rate_hz) == int(rate_hz)


def sample_stamp_ns(first_ns: int, k: int, rate_hz: float) -> int:
    """Stamp of sample ``k`` counted from a sample stamped ``first_ns`` (Python ints)."""
    if _is_integer_rate(rate_hz):
        return int(first_ns) + (int(k) * NS_PER_S) // int(rate_hz)
    return int(first_ns) + round(int(k) * NS_PER_S / float(rate_hz))


def end_stamp_ns(first_ns: int, n: int, rate_hz: float) -> int:
    """The stamp just after the last of ``n`` samples: where the next contiguous record starts."""
    return sample_stamp_ns(first_ns, n, rate_hz)


def sample_stamps_ns(first_ns, k, rate_hz) -> np.ndarray:
    """Stamps of samples ``k`` after ``first_ns`` (int64). Every argument may be an array; they
    broadcast, so one call stamps many blocks of different rates."""
    first, k, rate = np.broadcast_arrays(np.asarray(first_ns, dtype=np.int64),
                                         np.asarray(k, dtype=np.int64),
                                         np.asarray(rate_hz, dtype=np.float64))
    out = np.empty(first.shape, dtype=np.int64)
    isint = rate == np.floor(rate)
    if isint.all():
        out[...] = first + (k * NS_PER_S) // rate.astype(np.int64)
        return out
    out[isint] = first[isint] + (k[isint] * NS_PER_S) // rate[isint].astype(np.int64)
    nr = ~isint
    out[nr] = first[nr] + np.round(k[nr] * (NS_PER_S / rate[nr])).astype(np.int64)
    return out


def record_stamps_ns(first_ns: int, n: int, rate_hz: float) -> np.ndarray:
    """Stamps of the ``n`` samples of one record or block: sample_stamps_ns's arithmetic for one
    scalar start and rate, without its broadcasting (a live node calls this once per block)."""
    k = np.arange(int(n), dtype=np.int64)
    if _is_integer_rate(rate_hz):
        rate = int(rate_hz)
        if NS_PER_S % rate == 0:    # a whole number of ns per sample (50 kHz: 20 us): no division
            return int(first_ns) + k * (NS_PER_S // rate)
        return int(first_ns) + (k * NS_PER_S) // rate
    return int(first_ns) + np.round(k * (NS_PER_S / float(rate_hz))).astype(np.int64)


def stamp_to_ns(sec: int, nanosec: int) -> int:
    """A ROS ``builtin_interfaces/Time`` (sec, nanosec) as integer nanoseconds."""
    return int(sec) * NS_PER_S + int(nanosec)


def ns_to_stamp(ns: int) -> tuple:
    """Integer nanoseconds as (sec, nanosec) of a ROS ``builtin_interfaces/Time``."""
    return divmod(int(ns), NS_PER_S)


def seconds_to_ns(seconds: float) -> int:
    """A duration in seconds as integer nanoseconds (rounded)."""
    return int(round(float(seconds) * NS_PER_S))
