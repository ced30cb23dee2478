"""The search's per-pull sufficient statistics: one pull's library columns as normal equations per channel
(ChannelStats), so the search holds a Gram matrix per pull and never the samples (memory flat in the pulls).
ROS-free."""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Dict, NamedTuple, Optional, Tuple

import numpy as np

from force_tester_sim.core.extra_terms import SIGNALS, SIN, parse_term, term_name

from ..prep import like_a3
from .grammar import FREE_PHASE_BLIND, SIN_FACTORS, channel_library
from .series import ChannelSeries, Through
from .spectrum import SearchSettings


class Column(NamedTuple):
    """An extra column c beside the library's columns X, against the residual y: c.c, X'c and c.y."""

    cc: float
    cx: np.ndarray
    cy: float


class ChannelStats(NamedTuple):
    """One channel of one pull: the normal equations of its library columns X (the product columns, then each
    sinusoid's cos and sin pair) against its residual y."""

    names: Tuple[str, ...]              # the product terms, then the sinusoids
    gram: np.ndarray                    # X'X
    xy: np.ndarray                      # X'y
    yy: float                           # y.y: the squared residual with no term
    n: int                              # samples
    catalog: Optional[Column]           # the catalog columns C (C'C, X'C, C'y: the Coulomb step on the current, the
                                        # gain's and m2's forms F_move and a2 on the moving cell), or None
    causes: Dict[str, Column]           # each named force-model cause's contribution (priority.cause_check)
    systematic: Dict[str, np.ndarray]   # X'z of the residual's change z with each rig constant one u off (and, with
                                        # catalog columns C, C'z last)
    window_ss: Optional[np.ndarray] = None   # a sensor's product columns' sums of squares over the analysis window
    n_window: int = 0                         # and its samples (selection: a sensor's terms are judged there)
    own: Optional[Tuple[np.ndarray, np.ndarray]] = None   # (X'X, X'y) with the columns in the sensor's own reading
                                                          # of its reference's signals (ChannelSeries.own)
    window_raw_ss: Optional[np.ndarray] = None   # on a channel formed through a filter (series.Through), the product
                                                 # columns' sums of squares over the window before it: a term's whole


@dataclass(frozen=True)
class BeyondPart:
    """One pull's ChannelStats per channel."""

    stats: Dict[str, ChannelStats]


def columns(channel: str, sig: Dict[str, np.ndarray], scales: Dict[str, float], f_hz: Optional[float]):
    """(names, scaled product columns, sinusoid factor columns: [(name, cos, sin)]) of one channel's library."""
    names = channel_library(channel)
    scaled = {s: np.asarray(sig[s], float) / scales[s] for s in SIGNALS}
    powers = {(s, 1): v for s, v in scaled.items()}
    X = np.empty((len(scaled['t']), len(names)), order='F')   # column by column: each column contiguous
    for k, term in enumerate(names):   # each column one product of cached powers (the library has degree <= 3)
        factors = []
        for s, e in parse_term(term).items():
            for q in range(2, e + 1):   # by products: x ** 3 is C's pow() per element, 500x slower than x * x * x
                if (s, q) not in powers:
                    powers[(s, q)] = powers[(s, q - 1)] * scaled[s]
            factors.append(powers[(s, e)])
        X[:, k] = functools.reduce(np.multiply, factors)
    blind = set(FREE_PHASE_BLIND.get(channel, ()))
    sins = []
    if f_hz is not None:
        ph = 2 * np.pi * f_hz * sig['t']
        for fac in SIN_FACTORS:
            if fac in blind:
                continue
            m = scaled[fac] if fac else np.ones_like(ph)
            sins.append((term_name({fac: 1, SIN: 1}) if fac else SIN, m * np.cos(ph), m * np.sin(ph)))
    return list(names), X, sins


def beyond_part(series: Dict[str, ChannelSeries], settings: SearchSettings) -> BeyondPart:
    """The pull's normal equations (ChannelStats) on each of its channels, with the settings' scales and lines."""
    out = {}
    for ch, cs in series.items():
        y, raw_w = cs.residual, None
        if cs.through is None:
            names, X, sins = columns(ch, cs.signals, settings.scales, settings.freq.get(ch))
            full = with_sins(X, sins)
            on_w = None if cs.window is None else columns(ch, cs.window, settings.scales, None)[1]
        else:   # the columns through the residual's filter (series.Through), at the samples searched
            names, X, sins = columns(ch, cs.through.signals, settings.scales, settings.freq.get(ch))
            raw_w = X[cs.through.window]
            full = through(X, sins, cs.through)
            del X   # the whole record's columns (100k samples x 40 on a 50 kHz pull): only the samples are kept
            on_w = full[np.searchsorted(cs.through.samples, cs.through.window)][:, :len(names)]
        cat = None if cs.catalog is None else np.asarray(cs.catalog, float).reshape(len(y), -1)
        z, causes = dict(cs.systematic), dict(cs.causes)
        if cs.nuisance is not None:   # the pull's own nuisance columns, fitted beside every term: profiled out
            Q = basis(np.asarray(cs.nuisance, float).reshape(len(y), -1))
            y, full = profiled(Q, y), profiled(Q, full)
            cat = None if cat is None else profiled(Q, cat)
            z, causes = ({c: profiled(Q, v) for c, v in d.items()} for d in (z, causes))
        catalog = None if cat is None else Column(cat.T @ cat, full.T @ cat, cat.T @ y)
        causes = {c: Column(float(v @ v), full.T @ v, float(v @ y)) for c, v in causes.items()}
        # X'z, then C'z with catalog columns C: a term's budget regresses z on those too when they are fitted beside
        # the term (the moving cell's gain and m2)
        systematic = {c: full.T @ v if cat is None else np.append(full.T @ v, cat.T @ v) for c, v in z.items()}
        own = None
        if cs.own is not None:
            _, X_o, sins_o = columns(ch, {**cs.signals, **cs.own}, settings.scales, settings.freq.get(ch))
            full_o = with_sins(X_o, sins_o)
            own = (full_o.T @ full_o, full_o.T @ y)
        out[ch] = ChannelStats(tuple(names + [n for n, _, _ in sins]), full.T @ full, full.T @ y, float(y @ y),
                               len(y), catalog, causes, systematic,
                               None if on_w is None else np.einsum('ij,ij->j', on_w, on_w),
                               0 if on_w is None else len(on_w), own,
                               None if raw_w is None else np.einsum('ij,ij->j', raw_w, raw_w))
    return BeyondPart(out)


def with_sins(X: np.ndarray, sins) -> np.ndarray:
    """The product columns X with each sinusoid's (cos, sin) pair after them (columns()' parts as one matrix)."""
    if not sins:
        return X
    full = np.empty((X.shape[0], X.shape[1] + 2 * len(sins)), order='F')
    full[:, :X.shape[1]] = X
    for i, (_, c, s) in enumerate(sins):
        full[:, X.shape[1] + 2 * i], full[:, X.shape[1] + 2 * i + 1] = c, s
    return full


def through(X: np.ndarray, sins, th: Through) -> np.ndarray:
    """The product columns X and the sinusoids' (cos, sin) pairs (columns()' parts, over the whole record) through
    the filter the channel's residual is formed through (series.Through: the motor current's like_a3), taken at the
    samples searched: with_sins' matrix there. The filter needs the whole record (the current's balance is filtered
    so; the samples searched span it: 0 to 99999 on the 50 kHz pulls of 2 s), but only the samples are kept, column
    by column: the filtered whole record (100k x 44 on such a pull, 35 MB) and with_sins' copy of X were held before,
    about the 80 MB `discover` on 100 pulls gained. One FFT call per column each way: a block of 8 columns through
    scipy's FFT along the first axis took 0.19 s a pull against 0.12 s column by column."""
    parts = [X[:, k] for k in range(X.shape[1])] + [v for _, c, s in sins for v in (c, s)]
    out = np.empty((len(th.samples), len(parts)), order='F')
    for k, v in enumerate(parts):
        out[:, k] = like_a3(v, th.dt)[th.samples]
    return out


def basis(N: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns N (the directions they span; a column of zeros spans none)."""
    U, s, _ = np.linalg.svd(N, full_matrices=False)
    return U[:, s > s[0] * max(N.shape) * np.finfo(float).eps] if len(s) and s[0] > 0 else U[:, :0]


def profiled(Q: np.ndarray, a: np.ndarray) -> np.ndarray:
    """a (a vector or columns) less its projection on the orthonormal columns Q (basis): what is left of it with
    the columns Q spans fitted beside, as a least squares on them leaves it."""
    return a - Q @ (Q.T @ a)
