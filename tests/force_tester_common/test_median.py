"""events.median: np.median's value bit for bit (a zero's sign aside), on the records it is given and on orders
that defeat its bracket."""
from contextlib import nullcontext

import numpy as np
import pytest

from force_tester_common.core.events import deviations, median, nanmedian


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


def short_records():
    rng = np.random.default_rng(11)
    for n in (1, 2, 3, 4, 7, 8, 560, 561, 4095):
        yield f'{n} normals', rng.normal(size=n)
        yield f'{n} signed zeros', rng.choice([-0.0, 0.0], size=n)
        yield f'{n} zeros, ones and infinities', rng.choice([-0.0, 0.0, 1.0, -1.0, np.inf, -np.inf], size=n)
        yield f'{n} ADC steps', np.round(rng.normal(size=n) * 3) * 0.1


@pytest.mark.parametrize('name,x', list(short_records()), ids=[r[0] for r in short_records()])
def test_short_median_is_numpys_to_the_bit(name, x):
    """A record shorter than the bracketed path takes: np.median's value to the bit, a zero's sign included."""
    with np.errstate(invalid='ignore'):    # -inf and inf in the middle: NaN, as np.median gives
        want, got = np.median(x), median(x)
    assert type(got) is type(want) and got.tobytes() == want.tobytes(), (name, got, want)


@pytest.mark.parametrize('name,x', [('short', np.array([3.0, np.nan, -1.0, 2.0])), ('all NaN', np.full(5, np.nan)),
                                    ('long, no NaN', np.random.default_rng(3).normal(size=9000)),
                                    ('short, no NaN', np.array([-0.0, -0.0, 1.0, -2.0]))])
def test_nanmedian_is_numpys(name, x):
    with np.errstate(invalid='ignore'), pytest.warns(RuntimeWarning) if np.isnan(x).all() else nullcontext():
        want = np.nanmedian(x)
    with np.errstate(invalid='ignore'), pytest.warns(RuntimeWarning) if np.isnan(x).all() else nullcontext():
        got = nanmedian(x)
    assert (np.isnan(want) and np.isnan(got)) or (got == want and (got.tobytes() == want.tobytes() or got == 0)), \
        (name, got, want)
