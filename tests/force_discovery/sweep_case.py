"""bench_sweep's nominal base campaign and its way of adding a term, for the tests that hide one term on the
independent generator (test_beyond_gain_form, test_beyond_drive_form, test_beyond_sensor_window): the independent
generator (tests/independent/rig.py), seed 3900, twelve pulls on sets 2-4 at 20 kHz, its clean signals kept; a term
sized from them to STRENGTH x the channel's band over the loaded windows and put back on the channel's ADC steps."""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'benchmarks'))
import bench_sweep as S  # noqa: E402  the sweep's base campaign and its way of adding a term

SEED = 3900               # bench_sweep's nominal rig
STRENGTH = 3.0            # the term's rms over the loaded windows, in the channel's band


def base_case():
    """bench_sweep's nominal base campaign (its clean signals kept), from the benchmark's cache when made before."""
    return S.base_case('nominal', SEED, 12)


def with_term(base, channel: str, term: str, sign: float):
    """(the campaign with sign x STRENGTH x band of `term` on the recorded channel, as bench_sweep adds it; the
    coefficient)."""
    coef = S.coefficient(base, channel, term, STRENGTH, sign)
    return S.inject(base, channel, term, coef), coef
