"""events.median: np.median's value bit for bit (a zero's sign aside), on the records it is given and on orders
that defeat its bracket."""
from contextlib import nullcontext

import numpy as np
import pytest

from force_tester_common.core.events import all_finite, deviations, median, nanmedian


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


def clustered(n_cluster: int) -> np.ndarray:
    """102,400 samples whose evenly spaced sample (every 100th) is 0..1023 and whose others sit in a cluster of
    n_cluster at 511.5 and the rest split below and above everything: the count below the sample's middle (512) then
    puts the median 100 sample ranks away from where it is (a narrow bracket around that guess misses it; the wide
    one around the middle holds it)."""
    n = 102_400
    x = np.empty(n)
    x[::100] = np.arange(1024.0)
    rest = n - 1024
    others = np.concatenate([np.full(n_cluster, 511.5), np.full((rest - n_cluster) // 2, -1000.0),
                             np.full(rest - n_cluster - (rest - n_cluster) // 2, 5000.0)])
    x[np.arange(n) % 100 != 0] = np.random.default_rng(5).permutation(others)
    return x


@pytest.mark.parametrize('name,x', [
    ('the narrow bracket misses, the wide one holds it', clustered(20_000)),
    ('the narrow bracket holds it', clustered(2_000)),
    ('a pull in time order', next(records())[1]),
    ('a record with a step: two levels of noise', np.concatenate([np.random.default_rng(9).normal(0, 1, 60_000),
                                                                  np.random.default_rng(10).normal(50, 9, 40_001)])),
])
def test_each_bracket_gives_numpys_median(name, x):
    """median's narrow bracket (placed by one count), its wide one and np.median: np.median's double, whichever
    holds the median's rank; finite=True (the caller's word that x has no NaN) gives the same."""
    want = np.median(x)
    assert median(x).tobytes() == want.tobytes() and median(x, finite=True).tobytes() == want.tobytes(), name


@pytest.mark.parametrize('x,want', [
    (np.arange(5.0), True), (np.array([1.0, np.nan]), False), (np.array([np.inf, 1.0]), False),
    (np.array([-np.inf, 1.0]), False), (np.array([np.inf, -np.inf]), False), (np.full(4, 1e308), True),
    (np.array([1e308, 1e308, -np.inf]), False), (np.empty(0), True), (np.array([np.nan, 1e308, 1e308]), False),
])
def test_all_finite_is_numpys_without_a_warning(x, want):
    """all_finite (one sum; np.isfinite only when the sum overflows): np.isfinite(x).all(), and no warning for the
    overflow or for inf + -inf."""
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        got = all_finite(x)
    assert got is want and want == bool(np.isfinite(x).all())
