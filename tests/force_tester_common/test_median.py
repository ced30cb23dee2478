"""events.median: np.median's value bit for bit (a zero's sign aside), on the records it is given and on orders
that defeat its bracket."""
import numpy as np
import pytest

from force_tester_common.core.events import deviations, median


def records():
    rng = np.random.default_rng(7)
    n = 100_000
    t = np.arange(n) / 50_000.0
    pull = np.where((t > 0.6) & (t < 0.8), 2000 * np.sin((t - 0.6) * np.pi / 0.2), 0.0) + rng.normal(0, 0.5, n)
    yield 'a pull with noise', pull
    yield 'odd length', pull[:-1]
    yield 'few distinct values (ADC steps)', np.round(pull / 3.0) * 3.0
    yield 'constant', np.full(n, 2.5)
    yield 'sorted', np.sort(rng.normal(size=n))
    yield 'reverse sorted', np.sort(rng.normal(size=n))[::-1].copy()
    yield 'short (np.median itself)', rng.normal(size=1001)
    # every sampled position (x[::n // 1024]) holds a large value: the bracket misses the median's rank
    odd = rng.normal(size=n)
    odd[::n // 1024] = 1e6 + np.arange(odd[::n // 1024].size)
    yield 'the sample all above the median', odd
    odd2 = -odd
    yield 'the sample all below the median', odd2
    yield 'deviations of a pull', deviations(pull)
    with_nan = pull.copy()
    with_nan[500] = np.nan
    yield 'a NaN (np.median: NaN)', with_nan
    with_inf = pull.copy()
    with_inf[:60_000] = np.inf
    yield 'infinite middle samples', with_inf
    yield 'integers', np.arange(n)[::-1] % 977


@pytest.mark.parametrize('name,x', list(records()), ids=[r[0] for r in records()])
def test_median_is_numpys_bit_for_bit(name, x):
    want, got = np.median(x), median(x)
    if np.isnan(want):
        assert np.isnan(got), (name, got)
        return
    # the same double; only a zero's sign may differ (which of -0.0 and 0.0 lands in the middle: equal values)
    assert got == want and (got.tobytes() == want.tobytes() or got == 0), (name, got, want)
