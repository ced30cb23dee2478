"""Events found from the data (force_tester_common.core.events): find_events decides the noise test by counting
where that decides it, and takes the exact median only near the threshold; its spans and baseline equal the
median-based definition on records of every kind (the definition written out here, as the module states it)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from force_tester_common.core.events import (
    EVENT_SNR,
    MAD_SD,
    below_snr,
    deviations,
    event_spans,
    event_width_s,
    find_events,
    robust_sd,
)

RATE = 50_000.0


def by_definition(x: np.ndarray) -> tuple:
    """(spans, baseline) as the module's docstring defines them, with both medians computed."""
    ok = np.isfinite(x)
    if x.size < 2 or not ok.any():
        return [], None
    base = np.median(x[ok])
    dev = np.abs(x - base)
    dev[~ok] = 0.0
    peak = dev.max()
    if not peak > 0 or peak < EVENT_SNR * (1.4826 * np.median(dev[ok])):
        return [], base
    return event_spans(x, RATE), base   # the spans past the noise test are those of the one code path


def record(seed: int, snr: float, n: int, nan_share: float, inf: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(n)
    x[n // 3: n // 3 + max(1, n // 50)] += snr * 1.4826 * 0.6745   # a pulse near EVENT_SNR noise deviations
    x[rng.random(n) < nan_share] = np.nan
    if inf:
        x[rng.integers(n)] = np.inf
    return x


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**31), snr=st.floats(0.0, 3 * EVENT_SNR), n=st.integers(2, 3000),
       nan_share=st.sampled_from([0.0, 0.0, 0.1]), inf=st.booleans())
def test_find_events_equals_the_median_definition(seed, snr, n, nan_share, inf):
    x = record(seed, snr, n, nan_share, inf)
    spans, base = find_events(x, RATE)
    want_spans, want_base = by_definition(x)
    if want_base is None:
        assert spans == [] and np.isnan(base)
        return
    assert base == want_base
    # the noise test itself, with both medians: an event only where the peak clears EVENT_SNR deviations
    ok = np.isfinite(x)
    dev = np.abs(x[ok] - want_base)
    noisy = not dev.max() > 0 or dev.max() < EVENT_SNR * (1.4826 * np.median(dev))
    assert (spans == []) if noisy else (spans == want_spans and spans)


@pytest.mark.parametrize('rel', [1 - 1e-3, 1 - 1e-7, 1.0, 1 + 1e-7, 1 + 1e-3])
@pytest.mark.parametrize('zeros', [3, 4])   # an even and an odd number of samples
def test_a_noise_level_on_the_threshold(rel, zeros):
    """Samples 0 (the median), +-a and one peak P, with a = rel P / (EVENT_SNR 1.4826): the deviations' median is
    a, on the threshold (where the counts cannot decide and the exact median does) or just off it."""
    peak = 1000.0
    a = rel * peak / (EVENT_SNR * 1.4826)
    x = np.array([-a] * 5 + [0.0] * zeros + [a] * 5 + [peak])
    spans, base = find_events(x, RATE)
    want_spans, want_base = by_definition(x)
    assert base == want_base == 0.0
    assert spans == want_spans
    if rel != 1.0:   # exactly on it, the rounding of the product decides
        assert (spans == []) == (rel > 1.0)


@pytest.mark.parametrize('lo, hi', [(0.5, 1.2), (0.9, 1.5), (0.2, 1.01)])
def test_a_middle_pair_across_the_threshold(lo, hi):
    """An even record whose deviations' middle pair lies on both sides of the threshold: their mean decides."""
    peak = 1000.0
    thr = peak / (EVENT_SNR * 1.4826)
    x = np.array([-hi * thr] * 6 + [0.0, 0.0] + [lo * thr] * 5 + [peak])   # median 0; dev's middle pair lo, hi
    spans, base = find_events(x, RATE)
    assert base == 0.0
    assert spans == by_definition(x)[0]
    assert (spans == []) == ((lo + hi) / 2 > 1.0)


def test_width_with_the_baseline_given_equals_its_own():
    x = record(3, 20.0, 5000, 0.0, False)
    spans, base = find_events(x, RATE)
    assert spans
    for span in spans:
        assert event_width_s(x, RATE, span, base) == event_width_s(x, RATE, span) > 0


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3, allow_nan=False), min_size=1, max_size=40),
       st.sampled_from([0.5, 1.0, 1.0 - 1e-9, 1.0 + 1e-9, 2.0]), st.booleans())
def test_below_snr_is_the_median_comparison(values, scale, or_equal):
    """below_snr decides peak < (<=) EVENT_SNR MAD_SD median(dev) as the formula does, at the threshold too (the
    peak set at the exact threshold times scale), from the deviations that robust_sd takes."""
    dev = deviations(np.array(values))
    exact = EVENT_SNR * (MAD_SD * np.median(dev))
    peak = exact * scale
    assert below_snr(dev, peak, or_equal) == bool(peak <= exact if or_equal else peak < exact), (peak, exact)
    assert robust_sd(np.array(values)) == MAD_SD * float(np.median(dev))


def test_deviations_leave_out_non_finite_samples():
    x = np.array([1.0, np.nan, 3.0, np.inf, 5.0])
    assert deviations(x).tolist() == [2.0, 0.0, 2.0] and deviations(np.array([np.nan])).size == 0
    assert robust_sd(np.array([np.nan])) == 0.0
