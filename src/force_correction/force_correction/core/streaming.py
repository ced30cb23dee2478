"""Inertial correction (thesis eq 24) and trailing moving average (eq 25), streamable.

Functional API in the style of ``scipy.signal.lfilter(..., zi=...)``::

    state = initial_state(params)
    for force, accel in blocks:
        out, state = correct_block(force, accel, params, state)

For ANY split of a signal into blocks (empty and 1-sample blocks included) the concatenated
streamed output equals ``correct_signal`` on the whole signal *bit for bit*: the moving-average
sum of every output sample is computed from the samples of its own window only, in an order
fixed by the absolute sample index, never from a long running cumulative sum.

Window sums ("segmented prefix/suffix sums", van Herk / Gil-Werman style): the sample axis is
cut into segments of ``window`` samples aligned to absolute index 0. A full window ending at
sample i starts at s = i - window + 1 and covers a suffix of s's segment plus a prefix of i's
segment (or exactly one whole segment when s is a segment start). Prefix sums are a cumsum
restarted at each segment start, suffix sums a reversed cumsum restarted at each segment end,
so each sum adds at most ``window`` values: round-off is O(window * eps * |x|) and independent of
the run length and of the block split.

Moving average at the start of a run: the window shrinks to the samples seen so far (MATLAB
``movmean(x, [N-1 0])``). Non-finite samples (NaN/inf in force or accel) give a NaN corrected
sample, are counted in ``nan_count``, and are ignored by the moving average (mean of the finite
samples in the window; NaN only if the window holds none), so one bad sample affects at most
``window`` filtered outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from force_tester_common.core.events import all_finite

from .errors import CorrectionError
from .params import CorrectionParams

_EMPTY = np.empty(0, dtype=np.float64)
_EMPTY.setflags(write=False)


@dataclass(frozen=True)
class CorrectedBlock:
    """Output of one correction call; all arrays float64, same length.

    raw_n: moving-cell force as given, N.
    inertial_n: m2 * a2, N.
    corrected_n: raw_n - inertial_n (thesis eq 24), NaN where an input is non-finite.
    filtered_n: trailing moving average of corrected_n over ``window`` samples (eq 25).
    nan_count: number of non-finite corrected samples in this block.
    """

    raw_n: np.ndarray
    inertial_n: np.ndarray
    corrected_n: np.ndarray
    filtered_n: np.ndarray
    nan_count: int

    def __len__(self) -> int:
        return int(self.raw_n.shape[0])


@dataclass(frozen=True)
class CorrectionState:
    """Filter state between blocks (like scipy's ``zi``); immutable, cheap to copy.

    window: the window this state belongs to (checked against the params).
    tail: the last min(window - 1, samples_seen) corrected samples (read-only, NaN kept).
    samples_seen: samples processed since the start of the run.
    nan_total: non-finite corrected samples since the start of the run.
    """

    window: int
    tail: np.ndarray = field(default_factory=lambda: _EMPTY)
    samples_seen: int = 0
    nan_total: int = 0

    def __deepcopy__(self, memo):  # immutable: sharing is safe
        return self

    def __copy__(self):
        return self

    def __eq__(self, other):
        if not isinstance(other, CorrectionState):
            return NotImplemented
        return (self.window == other.window and self.samples_seen == other.samples_seen
                and self.nan_total == other.nan_total
                and np.array_equal(self.tail, other.tail, equal_nan=True))

    __hash__ = None


def initial_state(params: CorrectionParams) -> CorrectionState:
    """State at the start of a run (empty window)."""
    _check_params(params)
    return CorrectionState(window=params.window)


def _check_params(params) -> None:
    if not isinstance(params, CorrectionParams):
        raise CorrectionError(
            f"params {params!r} is not a CorrectionParams; expected CorrectionParams(...)")


def _as_1d(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1:
        if a.ndim == 0:
            a = a.reshape(1)
        else:
            raise CorrectionError(
                f"{name} has shape {a.shape}; expected a 1-D array of samples")
    return a


def _window_sums(v: np.ndarray, g0: int, w: int, first: int) -> np.ndarray:
    """Sums over trailing windows of ``v`` (finite; NaN already replaced by 0).

    v holds absolute samples [g0, g0 + len(v)); returns, for each absolute index i in
    [first, g0 + len(v)), the sum of v over [max(0, i - w + 1), i]. Requires the window of
    ``first`` to lie inside v (g0 <= max(0, first - w + 1)).
    """
    m = v.shape[0]
    pad = g0 % w                           # segments aligned to absolute index 0
    total = pad + m
    nseg = -(-total // w)
    buf = np.zeros(nseg * w, dtype=np.float64)
    buf[pad:total] = v
    prefix = np.cumsum(buf.reshape(nseg, w), axis=1).reshape(-1)
    # suffix sums: cumsum of each reversed segment, read back reversed
    suffix = np.cumsum(buf[::-1].reshape(nseg, w), axis=1).reshape(-1)[::-1].copy()
    # a window starting exactly at a segment start is that segment's prefix alone: add 0.0
    suffix[::w] = 0.0
    base = g0 - pad                        # absolute index of buf[0]
    end = g0 + m
    out = prefix[first - base:end - base].copy()
    # windows clamped at the start of the run begin at absolute 0 (a segment start): add 0
    lo = max(first, w - 1)
    if lo < end:
        out[lo - first:] += suffix[lo - (w - 1) - base:end - (w - 1) - base]
    return out


def correct_block(force_moving_n, accel_axial_m_s2, params: CorrectionParams,
                  state: CorrectionState):
    """Correct one block; returns ``(CorrectedBlock, new_state)``. ``state`` is not modified.

    force_moving_n: moving-cell force, N (tension positive).
    accel_axial_m_s2: axial acceleration of m2, m/s^2 (pull direction positive).
    """
    _check_params(params)
    if not isinstance(state, CorrectionState):
        raise CorrectionError(
            f"state {state!r} is not a CorrectionState; expected initial_state(params) or a "
            f"state returned by correct_block")
    w = params.window
    if state.window != w:
        raise CorrectionError(
            f"state window {state.window} does not match params window {w}; "
            f"expected a state from initial_state(params)")
    f = _as_1d(force_moving_n, 'force_moving_n')
    a = _as_1d(accel_axial_m_s2, 'accel_axial_m_s2')
    n = f.shape[0]
    if a.shape[0] != n:
        raise CorrectionError(
            f"force has {n} samples but accel has {a.shape[0]}; expected equal lengths")

    inertial = params.mass_kg * a
    corrected = f - inertial
    if n == 0:
        out = CorrectedBlock(f.copy(), inertial, corrected, _EMPTY.copy(), 0)
        return out, state

    nbad = 0
    if not all_finite(corrected):     # the usual block is finite: no mask of it
        bad = ~np.isfinite(corrected)
        nbad = int(np.count_nonzero(bad))
        corrected[bad] = np.nan

    tail = state.tail
    L = tail.shape[0]
    g0 = state.samples_seen - L
    ext = np.concatenate((tail, corrected)) if L else corrected
    if nbad or (L and np.isnan(tail).any()):
        ext_bad = np.isnan(ext)
        v = np.where(ext_bad, 0.0, ext)
    else:
        ext_bad = None
        v = ext
    first = state.samples_seen
    sums = _window_sums(v, g0, w, first)
    # samples in each window: min(i + 1, w)
    if first + n <= w:
        counts = np.arange(first + 1, first + n + 1, dtype=np.float64)
    elif first >= w - 1:
        counts = float(w)            # every window full: one count for all (the same quotients as an array of it)
    else:
        counts = np.minimum(np.arange(first + 1, first + n + 1, dtype=np.float64), float(w))
    if ext_bad is None:
        filtered = sums / counts
    else:
        cb = np.concatenate(([0], np.cumsum(ext_bad, dtype=np.int64)))
        i_loc = np.arange(first - g0, first - g0 + n)          # index of i in ext
        s_loc = np.maximum(i_loc - (w - 1), -g0)               # window start (clamped at 0)
        counts = counts - (cb[i_loc + 1] - cb[s_loc])
        with np.errstate(invalid='ignore', divide='ignore'):
            filtered = np.where(counts > 0, sums / np.maximum(counts, 1.0), np.nan)

    keep = min(w - 1, ext.shape[0])
    new_tail = ext[ext.shape[0] - keep:].copy() if keep else _EMPTY
    new_tail.setflags(write=False)
    new_state = CorrectionState(window=w, tail=new_tail,
                                samples_seen=state.samples_seen + n,
                                nan_total=state.nan_total + nbad)
    return CorrectedBlock(f.copy(), inertial, corrected, filtered, nbad), new_state


def correct_signal(force_moving_n, accel_axial_m_s2, params: CorrectionParams) -> CorrectedBlock:
    """One-pass (batch) correction of a whole run: the reference for the streamed version."""
    out, _ = correct_block(force_moving_n, accel_axial_m_s2, params, initial_state(params))
    return out


class InertialCorrector:
    """Stateful convenience wrapper around :func:`correct_block`."""

    def __init__(self, params: CorrectionParams | None = None):
        self._params = CorrectionParams() if params is None else params
        self._state = initial_state(self._params)

    @property
    def params(self) -> CorrectionParams:
        return self._params

    @property
    def state(self) -> CorrectionState:
        return self._state

    @state.setter
    def state(self, value: CorrectionState) -> None:
        if not isinstance(value, CorrectionState) or value.window != self._params.window:
            raise CorrectionError(
                f"state {value!r} does not fit params window {self._params.window}; "
                f"expected a CorrectionState with window {self._params.window}")
        self._state = value

    def reset(self) -> None:
        """Forget the window (e.g. after a gap in time); next output starts a new run."""
        self._state = initial_state(self._params)

    def process(self, force_moving_n, accel_axial_m_s2) -> CorrectedBlock:
        out, self._state = correct_block(force_moving_n, accel_axial_m_s2, self._params,
                                         self._state)
        return out
