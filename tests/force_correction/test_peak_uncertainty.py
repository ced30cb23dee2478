"""The corrected peak's expanded uncertainty (force_correction.core.peak_uncertainty): the budget follows its
inputs, the Monte Carlo agrees with the linear budget where that is valid, bad inputs are refused."""
import math
import re

import numpy as np
import pytest

from force_correction.core.errors import CorrectionError
from force_correction.core.params import CorrectionParams
from force_correction.core.peak_uncertainty import MC_SEED, PeakInputs, mc_normals, peak_uncertainty
from force_correction.core.streaming import correct_signal

RATE = 50_000.0


def pull(seed=0, noise=0.3):
    """A smooth 1000 N pulse on a quiet lead-in, a ringing m a, white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(20_000) / RATE
    tension = 1000.0 * np.exp(-0.5 * ((t - 0.3) / 0.004) ** 2)
    a = 300.0 * np.sin(2 * np.pi * 1000.0 * t) * (t > 0.29)
    force = tension + 1.152 * a + noise * rng.standard_normal(t.size)
    out = correct_signal(force, a, CorrectionParams(mass_kg=1.152))
    return out, tension


def test_linear_terms_match_the_monte_carlo():
    out, _ = pull(noise=0.0)
    inputs = PeakInputs(mass_rel=0.01, gain_rel=0.005)
    pu = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, inputs, draws=4000)
    lin = math.hypot(*(u for _, u in pu.components))
    assert pu.u_n == pytest.approx(lin, rel=0.1)   # the max moves a little with the ringing m a: MC >= linear
    assert pu.expanded_n == pytest.approx(2 * pu.u_n, rel=0.02)   # k u, plus a noise bias near 0 here
    i = int(np.argmax(out.corrected_n))   # sensitivity coefficients at the corrected peak
    assert dict(pu.components)['gain'] == pytest.approx(0.005 * (out.corrected_n[i] + out.inertial_n[i]))
    assert dict(pu.components)['mass'] == pytest.approx(0.01 * abs(out.inertial_n[i]))


def test_each_input_widens_it_and_noise_alone_is_small():
    out, _ = pull()
    base = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, PeakInputs())
    assert 0 < base.expanded_n < 3.0 and base.noise_n == pytest.approx(0.3, rel=0.2)
    for name in ('mass_rel', 'gain_rel', 'accel_sensitivity_rel'):
        wider = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, PeakInputs(**{name: 0.02}))
        assert wider.expanded_n > base.expanded_n + 0.5, name
    late = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, PeakInputs(accel_delay_s=2e-5))
    assert late.expanded_n > base.expanded_n


def test_covers_the_tension_over_noise_seeds():
    hits = 0
    for seed in range(40):
        out, tension = pull(seed, noise=2.0)
        pu = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, PeakInputs())
        hits += abs(pu.peak_n - tension.max()) <= pu.expanded_n
    assert hits >= 36   # about 95 % of 40


def test_the_moving_average_cut_is_measured():
    out, _ = pull()
    pu = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, RATE, PeakInputs())
    assert pu.ma_cut_n == pytest.approx(out.corrected_n.max() - np.nanmax(out.filtered_n))
    assert pu.filtered_expanded_n == pytest.approx(pu.expanded_n + abs(pu.ma_cut_n))


@pytest.mark.parametrize('kw', [{'mass_rel': -0.1}, {'gain_rel': float('nan')}, {'accel_delay_s': 1.0},
                                {'mass_rel': True}])
def test_bad_inputs_are_refused_with_the_value(kw):
    with pytest.raises(CorrectionError, match=list(kw)[0]):
        PeakInputs(**kw)


def test_peak_u_option_reads_four_numbers_or_names_the_value():
    from force_correction.offline.cli import peak_inputs_arg
    assert peak_inputs_arg('0.01,0.005,0.01,3e-6') == PeakInputs(0.01, 0.005, 0.01, 3e-6)
    assert peak_inputs_arg(None) == PeakInputs()
    for bad in ('0.01,abc', '0.01,0.02', '0.01,-0.1,0,0'):
        with pytest.raises(CorrectionError, match='-0.1' if '-' in bad else re.escape(repr(bad))):
            peak_inputs_arg(bad)


def test_the_draws_are_the_seeded_generators_in_order():
    """mc_normals (kept once a process) are MC_SEED's normals: 4 x draws for the inputs, then draws x width."""
    z, noise = mc_normals(400, 101)
    rng = np.random.default_rng(MC_SEED)
    assert np.array_equal(z, rng.standard_normal((4, 400)))
    assert np.array_equal(noise, rng.standard_normal((400, 101)))
    assert not z.flags.writeable and not noise.flags.writeable


@pytest.mark.parametrize('hole', [None, 'after_peak', 'before_peak'])
def test_no_lag_reads_each_sample_as_the_interpolation_does(hole):
    """With no lag drawn the draws read F at their own samples; a lag so small that it moves no sample goes
    through the interpolation, and both give the same U to the last bit, a NaN next to the peak included."""
    out, _ = pull(seed=4)
    c, ma, fl = out.corrected_n.copy(), out.inertial_n.copy(), out.filtered_n
    i = int(np.argmax(c))
    if hole == 'after_peak':
        c[i + 3] = np.nan
    elif hole == 'before_peak':
        ma[i - 2] = np.nan
    base = dict(mass_rel=0.01, gain_rel=0.004, accel_sensitivity_rel=0.003)
    none = peak_uncertainty(c, ma, fl, RATE, PeakInputs(**base))
    tiny = peak_uncertainty(c, ma, fl, RATE, PeakInputs(**base, accel_delay_s=1e-300))
    assert (none.u_n, none.expanded_n, none.filtered_expanded_n, none.peak_n) == \
        (tiny.u_n, tiny.expanded_n, tiny.filtered_expanded_n, tiny.peak_n)
    assert none.u_n > 0


def quiet_noise_by_masks(c: np.ndarray, rate: float) -> float:
    """quiet_noise as it was written before it took the loudest sample from argmax and argmin: masks of the whole
    pull (the definition: the std of neighbouring differences over sqrt 2, before the first sample louder than
    QUIET_FRACTION of the largest |c|, at most QUIET_MAX_S of them)."""
    from force_correction.core.peak_uncertainty import QUIET_FRACTION, QUIET_MAX_S
    fin = np.isfinite(c)
    if not fin.any():
        return math.nan
    mag = np.abs(c)
    pk = float(np.max(mag[fin]))
    loud = fin & (mag > QUIET_FRACTION * pk)
    end = int(np.argmax(loud)) if loud.any() else len(c)
    q = c[max(0, end - int(QUIET_MAX_S * rate)):end]
    d = np.diff(q[np.isfinite(q)])
    return float(np.std(d) / math.sqrt(2.0)) if len(d) >= 8 else math.nan


def variants():
    out, _ = pull(seed=2)
    c = out.corrected_n
    yield 'a pull', c
    yield 'its loudest sample negative', -c
    yield 'a NaN in the lead-in', np.where(np.arange(c.size) == 14_000, np.nan, c)
    yield 'an infinity after the peak', np.where(np.arange(c.size) == 16_000, -np.inf, c)
    yield 'all zeros', np.zeros(5000)
    yield 'loud from the start', c[int(np.argmax(c)):]


@pytest.mark.parametrize('name,c', list(variants()), ids=[v[0] for v in variants()])
def test_quiet_noise_equals_the_masks_definition(name, c):
    from force_correction.core.peak_uncertainty import quiet_noise
    got, want = quiet_noise(c, RATE), quiet_noise_by_masks(c, RATE)
    assert (math.isnan(got) and math.isnan(want)) or got == want, (name, got, want)


def test_noise_peaks_are_every_columns_max():
    """noise_peaks computes only the columns that can hold a draw's peak: the same doubles as the max over all of
    them, on rows sharp and flat (a flat row: every column can), and None for a row that is not finite."""
    from force_correction.core.peak_uncertainty import noise_extremes, noise_peaks
    z = mc_normals(400, 101)[1]
    least, most = noise_extremes(400, 101)
    assert np.array_equal(least, z.min(axis=0)) and np.array_equal(most, z.max(axis=0))
    j = np.arange(101)
    for row, sigma in ((1000.0 - 40.0 * np.abs(j - 50), 0.7), (1000.0 - 40.0 * np.abs(j - 3), 5.0),
                       (np.full(101, 3.0), 1.0), (1000.0 - 0.01 * (j - 70) ** 2, 2.0), (np.sin(j / 4.0), 1e-3)):
        want = (row[None, :] + sigma * z).max(axis=1)
        got = noise_peaks(row, sigma, z)
        assert got.tobytes() == want.tobytes()
    assert noise_peaks(np.where(j == 7, np.nan, 1.0), 1.0, z) is None


def peak_u_by_every_draw(c, ma, fl, inputs):
    """peak_uncertainty's expanded U and noise as written before the noise-only draws were cut to their columns:
    every draw over the whole window, NaN masks of the whole pull."""
    fin = np.isfinite(c) & np.isfinite(ma)
    i = int(np.flatnonzero(fin)[np.argmax(c[fin])])
    noise = quiet_noise_by_masks(c, RATE)
    sigma = 0.0 if math.isnan(noise) else noise
    h = int(round(1e-3 * RATE))
    lo, hi = max(i - h, 0), min(i + h + 1, len(c))
    f_w, ma_w = c[lo:hi] + ma[lo:hi], ma[lo:hi]
    ok = np.isfinite(f_w) & np.isfinite(ma_w)
    z, z_noise = mc_normals(400, hi - lo)
    fv = np.where(ok, f_w, np.nan)
    f_shift = (fv + 0.0 * fv[np.minimum(np.arange(1, hi - lo + 1), hi - lo - 1)])[None, :]
    drawn = f_shift * (1 + inputs.gain_rel * z[1])[:, None] - \
        ma_w[None, :] * ((1 + inputs.mass_rel * z[0]) * (1 + inputs.accel_sensitivity_rel * z[2]))[:, None]
    if sigma > 0:
        drawn = drawn + sigma * z_noise
    u = float(np.std(np.nanmax(np.where(ok[None, :], drawn, np.nan), axis=1), ddof=1))
    near = int(np.count_nonzero(ok & (c[lo:hi] >= c[i] - 3.0 * sigma))) if sigma > 0 else 1
    big = 2.0 * u + (sigma * math.sqrt(2.0 * math.log(near)) if near > 1 else 0.0)
    cut = c[i] - float(np.nanmax(fl))
    return big, big + abs(cut), noise


@pytest.mark.parametrize('seed,noise,inputs,hole', [
    (0, 0.3, PeakInputs(), None), (1, 2.0, PeakInputs(), None), (2, 0.01, PeakInputs(), None),
    (3, 0.3, PeakInputs(), 'ma'), (4, 0.3, PeakInputs(), 'c'),
    (5, 0.3, PeakInputs(mass_rel=0.01, gain_rel=0.004), None), (6, 0.0, PeakInputs(), None)])
def test_peak_uncertainty_equals_every_draw(seed, noise, inputs, hole):
    """U, the filtered peak's U and the noise to the last bit against every draw over the whole window (the
    noise-only path cuts the columns; a NaN near the peak, inputs or no noise take the general one)."""
    out, _ = pull(seed, noise)
    c, ma, fl = out.corrected_n.copy(), out.inertial_n.copy(), out.filtered_n
    i = int(np.argmax(c))
    if hole == 'ma':
        ma[i + 5] = np.nan
    elif hole == 'c':
        c[i - 4] = np.nan
    pu = peak_uncertainty(c, ma, fl, RATE, inputs)
    got = (pu.expanded_n, pu.filtered_expanded_n, pu.noise_n)
    want = peak_u_by_every_draw(c, ma, fl, inputs)
    assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(got, want)), (got, want)
    assert peak_uncertainty(c, ma, fl, RATE, inputs, filtered_peak=float(np.nanmax(fl))) == pu
