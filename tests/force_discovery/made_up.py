"""Made-up moving-cell campaigns for the unit tests of the search beyond the catalog (test_beyond's and
test_beyond_selection's catalog-cause checks): one pull's signals, and the search's per-pull statistics of a list
of pulls."""
from __future__ import annotations

import numpy as np

from force_discovery.core.beyond import SearchSettings, beyond_part


def made_up_signals(k: int, n: int, rng: np.random.Generator) -> dict:
    """Pull k's grammar signals: a speed hump 10 % faster per pull, a2 its derivative plus a 35 Hz ring, a 2 kN
    load pulse on F_move and T, noise on F_stat (drawn from rng), x the integral of v, t from 0.6 s."""
    t = np.linspace(0.0, 0.2, n)
    v = 3.0 * np.sin(np.pi * t / 0.2) * (1 + 0.1 * k)
    a2 = np.gradient(v, t) + 40.0 * np.sin(2 * np.pi * 35.0 * t + k)
    pulse = 2000.0 * np.exp(-((t - 0.1) / 0.01) ** 2)
    return {'F_move': pulse, 'F_stat': rng.normal(0, 1, n), 'T': pulse, 'a2': a2, 'v': v,
            'x': np.cumsum(v) * (t[1] - t[0]), 't': t + 0.6}


def search_statistics(parts: list) -> tuple:
    """([beyond_part of each pull], SearchSettings) with the signals' scales taken from the first pull's
    force_moving series."""
    sig0 = parts[0]['force_moving'].signals
    settings = SearchSettings({s: float(np.sqrt(np.mean(sig0[s] ** 2))) for s in sig0}, {})
    return [beyond_part(p, settings) for p in parts], settings
