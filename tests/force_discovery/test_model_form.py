"""Issue 38: the model-form lines of the budgets that are estimated from the data (budget.py), on synthetic records
whose answer is known: the free-decay mode's analysis variants (ringing.free_decay_variants, budget.mode_form_parts)."""
from __future__ import annotations

import math
import types

import numpy as np
import pytest

from force_discovery.core import budget as B
from force_discovery.core.force_model import WindowShift, delay_grid
from force_discovery.core.prep import Pull
from force_discovery.core.ringing import MODE_VARIANTS, free_decay_mode, free_decay_variants, matrix_pencil

DT = 1e-4


def _pull(ring: np.ndarray) -> Pull:
    """A pull whose a2 after the break (sample 1000) is ring and whose carriage is at rest (a3 = 0)."""
    n = 1000 + len(ring) + 100
    a2 = np.zeros(n)
    a2[1002:1002 + len(ring)] = ring
    z = np.zeros(n)
    return Pull('p', np.arange(n) * DT, DT, z, z, a2, z, z, z, z, None, 0, n, 100, 200, 1000, 1.0)


def _decay(modes, n: int = 400, seed: int = 0) -> np.ndarray:
    """Damped cosines [(f, zeta, amplitude)] sampled at DT, with a little noise."""
    t = np.arange(n) * DT
    y = sum(a * np.exp(-z * 2 * math.pi * f * t) * np.cos(2 * math.pi * f * math.sqrt(1 - z * z) * t)
            for f, z, a in modes)
    return y + 1e-4 * np.random.default_rng(seed).standard_normal(n)


def test_one_clean_mode_gives_every_variant_the_same_mode():
    p = _pull(_decay([(800.0, 0.012, 1.0)]))
    nominal = free_decay_mode(p)
    assert nominal is not None and abs(nominal[0] - 800.0) < 0.5 and abs(nominal[1] / 0.012 - 1) < 0.01
    variants = free_decay_variants(p, nominal)
    assert set(variants) == set(MODE_VARIANTS)
    for name, v in variants.items():
        assert v is not None, name
        assert abs(v[0] / nominal[0] - 1) < 1e-3 and abs(v[1] / nominal[1] - 1) < 0.02, (name, v, nominal)
    assert free_decay_variants(p, None) is None


def test_the_matrix_pencil_takes_only_the_leading_right_vectors(monkeypatch):
    """The modes of a 1500-sample decay are those of the full-SVD pencil (the right singular vectors of the
    Hankel matrix) to 1e-9, without a full SVD of that matrix (only pinv's small ones)."""
    y = _decay([(800.0, 0.012, 1.0), (2300.0, 0.03, 0.4)], n=1500, seed=3)
    L = len(y) // 2
    Vh = np.linalg.svd(np.lib.stride_tricks.sliding_window_view(y, L + 1), full_matrices=False)[2]
    V = Vh[:8].conj().T
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    reference = sorted(abs(np.log(z[z.imag > 0]).imag) / (2 * math.pi * DT))
    svd = np.linalg.svd

    def small_svd(a, *args, **kw):
        assert min(np.shape(a)) <= 8, np.shape(a)
        return svd(a, *args, **kw)
    monkeypatch.setattr(np.linalg, 'svd', small_svd)
    modes = matrix_pencil(y, DT)
    assert abs(modes[0][0] - 800.0) < 0.5 and abs(modes[1][0] - 2300.0) < 2.0
    found = sorted(f for f, _, _ in modes)
    assert len(found) == len(reference)
    assert max(abs(a / b - 1) for a, b in zip(found, reference)) < 1e-9, (found, reference)


@pytest.mark.parametrize('dt', [1e-5, 2e-5, 1 / 48000])
def test_a_window_shift_by_many_delays_transforms_once_per_fraction_of_a_sample(monkeypatch, dt):
    """WindowShift.many (force_blocks' a2 at every grid delay) equals the shift one delay at a time to rounding,
    with one inverse transform per fraction of a sample on the grid (a delay's whole samples are a rotation)."""
    x = np.cumsum(np.random.default_rng(5).standard_normal(3000))
    p = types.SimpleNamespace(w0=300, w1=2700, dt=dt)
    grid = delay_grid(dt)
    shift = WindowShift(x, p)
    one_by_one = np.array([shift(d) for d in grid])
    irfft, rows = np.fft.irfft, []

    def counted(a, *args, **kw):
        rows.append(1 if np.ndim(a) == 1 else len(a))
        return irfft(a, *args, **kw)
    monkeypatch.setattr(np.fft, 'irfft', counted)
    many = shift.many(grid)
    fractions = len(np.unique(np.round((grid - np.floor(grid / dt + 1e-6) * dt) / dt, 6)))
    assert sum(rows) == fractions < len(grid), (rows, fractions, len(grid))
    assert np.max(np.abs(many - one_by_one)) < 1e-12 * np.max(np.abs(one_by_one))


def test_a_decay_that_is_not_one_linear_mode_spreads_the_variants():
    """An amplitude-dependent damping (the envelope decays faster once the ring is small, as a joint that slips
    at large amplitude would not): no single damped mode is the decay, and the later and shorter windows say so.
    The spread is the model-form line, far above a clean record's."""
    t = np.arange(400) * DT
    zeta = np.where(t < 0.01, 0.008, 0.02)
    env = np.exp(-np.cumsum(zeta * 2 * math.pi * 800.0 * DT))
    ring = env * np.cos(2 * math.pi * 800.0 * t) + 1e-4 * np.random.default_rng(1).standard_normal(len(t))

    def spread(p):
        m = free_decay_mode(p)
        parts = B.mode_form_parts({'mount_resonance': None}, [m, m], [free_decay_variants(p, m)] * 2)
        return parts['mount_resonance']['damping_ratio']['free_decay_analysis'] / m[1]
    clean, bent = spread(_pull(_decay([(800.0, 0.012, 1.0)]))), spread(_pull(ring))
    assert bent > 20 * clean and bent > 0.05, (bent, clean)


def test_mode_form_parts_is_the_rms_of_the_variants_medians_about_the_nominal():
    modes = [(500.0, 0.010, 1.0), (502.0, 0.012, 1.0), (501.0, 0.011, 1.0)]    # nominal medians 501, 0.011
    variants = [{'a': (503.0, 0.013), 'b': (500.0, 0.011)},
                {'a': (505.0, 0.015), 'b': None},                             # b found no mode on this pull
                {'a': (504.0, 0.014), 'b': (498.0, 0.009)}]                   # medians a: 504, 0.014; b: 499, 0.010
    parts = B.mode_form_parts({'mount_resonance': None}, modes, variants)['mount_resonance']
    assert parts['frequency_hz']['free_decay_analysis'] == pytest.approx(math.sqrt((3.0 ** 2 + 2.0 ** 2) / 2))
    assert parts['damping_ratio']['free_decay_analysis'] == pytest.approx(math.sqrt((0.003 ** 2 + 0.001 ** 2) / 2))
    assert B.mode_form_parts({}, modes, variants) == {}                              # no mount candidate
    assert B.mode_form_parts({'mount_resonance': None}, [None], [None]) == {}        # no mode


def test_the_mount_budget_names_the_line_and_widens_the_interval():
    """pull_to_pull_parts carries the line into the mount's budget beside the pull-to-pull one; honest() widens the
    interval by it (k = 2) and lists it by name, a model-form component (report.md groups it so)."""
    from force_discovery.core.candidate import Candidate, Evidence
    modes = [(500.0, 0.010, 1.0), (500.0, 0.010, 1.0)]
    variants = [{'a': (500.0, 0.011)}] * 2
    sys_ = B.pull_to_pull_parts({'mount_resonance': None}, modes, [], variants)['mount_resonance']
    assert sys_['damping_ratio'] == {'pull_to_pull': 0.0, 'free_decay_analysis': pytest.approx(0.001)}
    assert B.KIND['free_decay_analysis'] == 'model form'
    c = Candidate({'frequency_hz': 500.0, 'damping_ratio': 0.010}, {'frequency_hz': [499.9, 500.1],
                  'damping_ratio': [0.00999, 0.01001]}, 2, Evidence(0.5, 3.0, True, 0.5), 'ring')
    h = B.honest('mount_resonance', c, sys_, 0.0)
    assert h.uncertainty_budget['damping_ratio']['free_decay_analysis'] == pytest.approx(0.001)
    lo, hi = h.parameters_ci95['damping_ratio']
    assert hi - 0.010 >= 2 * 0.001 and lo <= 0.010 - 2 * 0.001


def _bessel(x: np.ndarray, tau: float) -> np.ndarray:
    from scipy.signal import bessel, bilinear, lfilter
    b, a = bessel(2, 1.0 / tau, analog=True, norm='delay')
    return lfilter(*bilinear(b, a, fs=1.0 / DT), x)


def _loaded_pull(tau: float, form: str = 'bessel', m2: float = 1.2) -> Pull:
    """A pull whose moving cell reads T + m2 a2 exactly, its accelerometer a2 delayed by tau: through a 2-pole
    Bessel of that group delay (form 'bessel') or shifted ('shift'); a smooth load with a 1.2 kHz ring on it (the
    ringing the mass is fitted on)."""
    from force_tester_sim.core.shift import Shifter
    n = 4000
    t = np.arange(n) * DT
    T = 5000.0 * np.exp(-((t - 0.2) / 0.05) ** 2)
    a2 = 200.0 * np.exp(-((t - 0.2) / 0.05) ** 2) * (1 + np.sin(2 * math.pi * 1200.0 * t))
    fm = T + m2 * a2
    a2m = _bessel(a2, tau) if form == 'bessel' else Shifter(a2, DT)(-tau)
    z = np.zeros(n)
    return Pull('p', t, DT, fm, T, a2m, T, z, z, z, None, 600, 3400, 100, 800, 3000, float(T.max()))


def _mass_lines(p: Pull) -> tuple:
    """(the nominal fit's m2, the delay_form line of m2, of the delay) of one pull."""
    from force_discovery.core.force_model import TERMS, ForceModel, force_params
    f = ForceModel([p], 1.2).fit_delay(set(TERMS), [0])
    variants = {n: ForceModel([B.delay_form(p, f.delay_s, reference=n == B.DELAY_FORM_REFERENCE)], 1.2)
                for n in ('delay_form', B.DELAY_FORM_REFERENCE)}
    sys_ = B.force_systematics(ForceModel([p], 1.2), variants, [0], 1.2)
    return (force_params(f.coefficients, f.delay_s, 1.2)['effective_mass']['mass_kg'],
            sys_['effective_mass']['mass_kg']['delay_form'], sys_['accel_delay']['delay_s']['delay_form'])


def test_the_delay_form_line_spans_a_filter_shaped_delay():
    """The accelerometer's delay is a 2-pole Bessel (50 us of group delay): fitted as a shift, the mass takes up the
    filter's attenuation of the ring (2.8 % high here); the delay_form variant (the filter's attenuation on F_move
    and T) fits better than the shift seen through the same filter, so the line counts, and it spans the truth."""
    m_shift, line, line_d = _mass_lines(_loaded_pull(50e-6))
    assert abs(m_shift / 1.2 - 1) > 0.01, m_shift
    assert 0.7 * abs(m_shift - 1.2) < line < 1.5 * abs(m_shift - 1.2), (line, m_shift)
    assert line_d < 5e-6                          # the delay stays the delay: the filter's is taken back out


def test_the_delay_form_line_is_zero_for_a_shift_or_a_lead():
    """A shift-shaped delay fits better as a shift: the line is 0, the mass's interval as it was; a lead (a DAQ's
    skew) is a shift, and the variant is the pull itself."""
    m_shift, line, _ = _mass_lines(_loaded_pull(50e-6, 'shift'))
    assert abs(m_shift / 1.2 - 1) < 1e-3 and line == 0.0, (m_shift, line)
    p = _loaded_pull(50e-6)
    assert B.delay_form(p, -3e-6) is p and B.delay_form(p, 0.0, reference=True) is p


def test_bessel_attenuation_takes_the_delay_back_out():
    """Below the filter's corner the attenuated channel is the channel (no delay left); at 4 kHz with 50 us it is
    attenuated as the 2-pole Bessel is (|H| = 3 / |3 + 3 s tau + (s tau)^2|)."""
    t = np.arange(20000) * 1e-5
    for f, tol in ((50.0, 1e-3), (4000.0, None)):
        x = np.sin(2 * math.pi * f * t)
        y = B.bessel_attenuation(x, 1e-5, 50e-6)[5000:15000]
        if tol is not None:
            assert np.max(np.abs(y - x[5000:15000])) < tol
        else:
            s = 2j * math.pi * f * 50e-6
            assert np.std(y) / np.std(x[5000:15000]) == pytest.approx(abs(3 / (3 + 3 * s + s * s)), rel=1e-2)


def test_report_md_names_every_model_form_line():
    """report.md's budget table groups the components by kind; below it each model-form line is named with its u."""
    from force_discovery.core.markdown import budget_lines
    r = {'uncertainty_budget': {'mount_resonance': {'damping_ratio': {
            'statistical': 1e-5, 'pull_to_pull': 2e-5, 'free_decay_analysis': 3e-5, 'combined': 3.7e-5}},
         'effective_mass': {'mass_kg': {'statistical': 1e-3, 'delay_form': 4e-3, 'tension_timing': 5e-4,
                                        'combined': 4.2e-3}}},
         'candidates': {'mount_resonance': {'parameters': {'damping_ratio': 0.012},
                                            'parameters_ci95': {'damping_ratio': [0.0119, 0.0121]}},
                        'effective_mass': {'parameters': {'mass_kg': 1.2},
                                           'parameters_ci95': {'mass_kg': [1.19, 1.21]}}}}
    text = '\n'.join(budget_lines(r))
    assert '- mount_resonance.damping_ratio: free_decay_analysis 3e-05' in text
    assert '- effective_mass.mass_kg: delay_form 0.004, tension_timing 0.0005' in text


def _driven_pull(hold_after_stop: float, f_c: float = 200.0) -> tuple:
    """(pull, rig): the nominal rig's carriage at rest, moving at 2 m/s with dry friction f_c, then at rest again
    while the drive still pushes hold_after_stop against the stuck contact (a dry contact at rest holds any force up
    to f_c); the current is the force balance's exactly."""
    import yaml

    from force_tester_sim.core.params import NOMINAL_YAML, rig_from_dict
    rig = rig_from_dict(yaml.safe_load(NOMINAL_YAML.read_text()))
    d = rig.drive
    n = 6000
    t = np.arange(n) * DT
    v = np.interp(t, [0.0, 0.1, 0.15, 0.4, 0.45, 0.6], [0.0, 0.0, 2.0, 2.0, 0.0, 0.0])
    a = np.gradient(v, DT)
    fm = 50.0 * (v > 0)
    drive = d.reflected_mass_kg * a + d.viscous_damping_n_s_per_m * v + fm + f_c * (v > 0.01) \
        + hold_after_stop * (t > 0.45)
    z = np.zeros(n)
    return Pull('p', t, DT, fm, z, z, z, np.cumsum(v) * DT, v, a, drive / d.force_per_amp_n_per_a,
                0, n, 900, 1500, 4000, 1.0), rig


def test_the_current_zero_is_the_rest_before_the_carriage_first_moves():
    """After a stop a dry contact holds whatever force the drive still applies (the velocity loop's integrator keeps
    a current against it): that rest is not the current's zero. The friction is the moving residual less the rest
    before the launch; with no rest before the launch, every rest sample is the zero (as before)."""
    from force_discovery.core.friction import friction_row, rest_level
    p, rig = _driven_pull(-30.0)
    moving, rest = friction_row(p, rig)[:2]
    assert moving - rest == pytest.approx(200.0, abs=1.0), (moving, rest)
    p0, _ = _driven_pull(0.0)
    assert np.subtract(*friction_row(p0, rig)[:2]) == pytest.approx(200.0, abs=1.0)
    rho = np.r_[np.full(50, 5.0), np.full(10, 9.0), np.full(200, -30.0)]
    sg = np.r_[np.zeros(50), np.ones(10), np.zeros(200)]
    assert rest_level(rho, sg) == -30.0                          # fewer than MIN_REST_SAMPLES before: every rest sample


@pytest.mark.slow
def test_the_filter_delay_is_the_filter_form_s_own_fixed_point():
    """A 2-pole Bessel of 150 us: the filter form at the shift's delay still leaves the mass 1.7 % high (the shift
    falls short of the filter's group delay, so the variant's filter is too short); refitted at the delay it finds
    (filter_delay), the delay is its own refit's and the mass the truth's."""
    from force_discovery.core.force_model import TERMS, ForceModel, force_params

    def fitted(q):
        f = ForceModel([q], 1.2).fit_delay(set(TERMS), [0])
        return force_params(f.coefficients, f.delay_s, 1.2)['effective_mass']['mass_kg'], f.delay_s
    p = _loaded_pull(150e-6)
    d0, d = B.own_delay(p, 1.2), B.filter_delay(p, 1.2)
    m_once, _ = fitted(B.delay_form(p, d0))
    m, d_again = fitted(B.delay_form(p, d))
    assert abs(m_once / 1.2 - 1) > 0.01 and m == pytest.approx(1.2, rel=1e-3), (m_once, m)
    assert d_again == pytest.approx(d, abs=0.5e-6) and d > d0


def test_the_hum_budget_has_a_model_form_line_from_the_pre_pull_halves():
    """A steady hum gives both halves of the pre-pull record its amplitude (the line about 0); one whose amplitude
    grows from 2 N to 3 N gives each half its own (about 0.5 N off the whole record's median)."""
    from force_discovery.core.hum import hum_form_parts
    t = np.arange(20000) * DT
    rng = np.random.default_rng(3)

    def pres(grow):
        amp = 2.0 + grow * (t > t[-1] / 2)
        return [(t, amp * np.sin(2 * math.pi * 50.0 * t + k) + 0.01 * rng.standard_normal(len(t))) for k in range(3)]
    steady, growing = hum_form_parts(pres(0.0), 50.0), hum_form_parts(pres(1.0), 50.0)
    assert steady['amplitude_n']['pre_pull_window'] < 0.01
    assert 0.3 < growing['amplitude_n']['pre_pull_window'] < 0.7, growing
    assert B.KIND['pre_pull_window'] == 'model form' and hum_form_parts(pres(0.0)[:1], 50.0) == {}
    from force_discovery.core.candidate import Candidate, Evidence
    c = Candidate({'frequency_hz': 50.0, 'amplitude_n': 2.0},
                  {'frequency_hz': [49.99, 50.01], 'amplitude_n': [1.99, 2.01]}, 6,
                  Evidence(0.5, 3.0, True, 0.5), 'hum')
    h = B.honest('mains_hum', c, growing, 0.0)
    assert h.uncertainty_budget['amplitude_n']['pre_pull_window'] == growing['amplitude_n']['pre_pull_window']
    assert h.parameters_ci95['amplitude_n'][1] - 2.0 >= 2 * growing['amplitude_n']['pre_pull_window']


def test_the_friction_budget_has_an_operating_range_line():
    """Dry friction that is one constant at every load: both halves of the pulls give it (the line 0 under the
    pulls' own scatter). Friction that rises with the load (200 N on the first half of the pulls, 240 N on the
    second): the line is about half the difference; honest() lists it as a model-form line."""
    from functools import partial

    from force_discovery.core.friction import friction_stat
    rng = np.random.default_rng(7)
    steady = np.column_stack([200.0 + rng.normal(0, 0.5, 8), np.zeros(8), np.linspace(2.0, 4.0, 8)])
    rising = steady + np.column_stack([40.0 * (np.arange(8) >= 4), np.zeros(8), np.zeros(8)])
    assert B.friction_range(steady, False) < 0.5
    assert B.friction_range(rising, False) == pytest.approx(20.0, abs=1.5)
    rows_v = [{name: tuple(r) for name in B.DRIVE_VARIANTS} for r in rising]
    parts = B.friction_systematics(rising, rows_v, partial(friction_stat, joint=False))
    assert parts[B.OPERATING_RANGE] == B.friction_range(rising, False) and B.KIND[B.OPERATING_RANGE] == 'model form'


def test_a_term_beyond_the_catalog_gets_an_operating_range_line():
    """term_budget's model-form line: the coefficient on each half of the fitted pulls. One coefficient on every
    pull: the line 0. A coefficient of 1 on the first half's pulls and 2 on the second's: about 0.5."""
    from force_discovery.core.beyond.normal_equations import ChannelStats
    rng = np.random.default_rng(5)

    def stats(coef):
        x = rng.standard_normal(500)
        y = coef * x + 1e-3 * rng.standard_normal(500)
        return ChannelStats(('x',), np.array([[x @ x]]), np.array([x @ y]), float(y @ y), 500, None, {}, {})
    same = [stats(1.0) for _ in range(6)]
    b = B.term_budget(same, [0], 0, 1.0, (0.999, 1.001), 1.0, None)
    assert b.budget[B.OPERATING_RANGE] < 1e-3
    split = [stats(1.0) for _ in range(3)] + [stats(2.0) for _ in range(3)]
    b = B.term_budget(split, [0], 0, 1.5, (1.49, 1.51), 1.0, None)
    assert b.budget[B.OPERATING_RANGE] == pytest.approx(0.5, abs=0.01)
    assert b.ci95[1] - 1.5 >= 2 * 0.49 and B.KIND[B.OPERATING_RANGE] == 'model form'


def test_the_delay_search_solves_its_grid_of_fits_in_one_batch(monkeypatch):
    """fit_delay's sums of squares at the grid delays (grid_sse: one batched QR) are fit()'s, one least-squares
    solve each, to 1e-9 relative, for a ForceModel and for the ForceStats of the same pulls; the search itself
    calls the least-squares solver once (the refined delay's fit), not once per grid delay. The batch is bounded
    (GRID_BATCH_BYTES: all 51 delays of a 100-pull campaign's fitted pulls at once held 0.3 GB) and its size does not
    change the numbers beyond rounding (one design a batch: no zero rows padding it; 1e-12 relative)."""
    from force_discovery.core import force_model
    from force_discovery.core.force_model import TERMS, ForceModel
    from force_discovery.core.force_stats import ForceStats, force_blocks
    pulls = [_loaded_pull(30e-6, 'shift', m2=1.25), _loaded_pull(60e-6, 'shift', m2=1.15)]
    idx, terms = [0, 1], set(TERMS)
    hums = [np.zeros(len(p.t)) for p in pulls]
    lstsq, calls = np.linalg.lstsq, []

    def counted(*a, **kw):
        calls.append(1)
        return lstsq(*a, **kw)
    for fm_ in (ForceModel(pulls, 1.2, hums), ForceStats([force_blocks(p, h) for p, h in zip(pulls, hums)],
                                                         [DT, DT], 1.2, [1.0, 1.0])):
        grid = fm_.delay_grid()
        each = np.array([fm_.fit(terms, idx, d).sse for d in grid])
        batched = fm_.grid_sse(terms, idx, grid)
        assert np.max(np.abs(batched / each - 1)) < 1e-9, (batched, each)
        if isinstance(fm_, ForceModel):
            for size in (1, 1 << 40):
                monkeypatch.setattr(force_model, 'GRID_BATCH_BYTES', size)
                again = fm_.grid_sse(terms, idx, grid)
                assert np.max(np.abs(again / batched - 1)) < 1e-12, (size, again, batched)
        calls.clear()
        monkeypatch.setattr(np.linalg, 'lstsq', counted)
        fm_.fit_delay(terms, idx)
        monkeypatch.setattr(np.linalg, 'lstsq', lstsq)
        assert len(calls) == 1, len(calls)


def test_the_hum_fits_are_the_least_squares_sinusoid_without_a_design_matrix(monkeypatch):
    """The hum's amplitude and the pulls' own frequencies (hum.hum_form_parts) come from 3 x 3 normal equations:
    the same as least squares on the n x 3 design of sin, cos and 1 to 1e-12, and no lstsq call."""
    from force_discovery.core.hum import hum_frequencies, hum_per_pull
    n, f = 2400, 50.3
    t = np.arange(n) * DT
    r = 0.8 * np.sin(2 * math.pi * f * t + 0.7) + 0.3 + 0.05 * np.random.default_rng(2).standard_normal(n)
    z = np.zeros(n)
    p = Pull('p', t, DT, r, z, z, z, z, z, z, None, 0, n, n, n, n - 1, 1.0)
    i0 = int(0.02 / DT)
    A = np.column_stack([np.sin(2 * np.pi * f * t[i0:]), np.cos(2 * np.pi * f * t[i0:]), np.ones(n - i0)])
    c = np.linalg.lstsq(A, r[i0:], rcond=None)[0]

    def no_lstsq(*a, **kw):
        raise AssertionError('lstsq called')
    monkeypatch.setattr(np.linalg, 'lstsq', no_lstsq)
    amp, hum = hum_per_pull(p, f, 0.0)
    assert abs(amp / math.hypot(c[0], c[1]) - 1) < 1e-12, (amp, c)
    assert np.max(np.abs(hum - (c[0] * np.sin(2 * np.pi * f * t) + c[1] * np.cos(2 * np.pi * f * t)))) < 1e-12
    assert abs(hum_frequencies([(t, r)], 50.0)[0] - f) < 0.01


@pytest.mark.parametrize('dt', [2e-5, 4e-5])
def test_the_encoder_fit_is_scipys_savgol_filter_to_rounding(monkeypatch, dt):
    """as_encoder takes savgol_filter's kernel and end fits once and convolves with numpy: each derivative equals
    scipy's savgol_filter to rounding, ends included, without calling it again; a record with a NaN or shorter
    than the window is savgol_filter's own."""
    import scipy.signal as ss

    from force_discovery.core import prep
    n = 60000
    t = np.arange(n) * dt
    rng = np.random.default_rng(7)
    x = 2.0 * t ** 2 + 0.05 * np.sin(2 * np.pi * 30 * t) + 1e-6 * rng.standard_normal(n)
    win = prep.encoder_window(dt)
    want = [ss.savgol_filter(x, win, 3, deriv=k, delta=dt) for k in range(3)]
    for k in range(3):   # the kernels and end rows are made once (from savgol_filter's own end fits)
        prep.as_encoder(x[:2 * win], dt, k)
    calls = []
    real = ss.savgol_filter
    monkeypatch.setattr(ss, 'savgol_filter', lambda *a, **k: calls.append(1) or real(*a, **k))
    for k in range(3):
        got = prep.as_encoder(x, dt, k)
        assert np.max(np.abs(got - want[k])) <= 1e-10 * np.max(np.abs(want[k]))
    assert not calls
    holed = x.copy()
    holed[n // 2] = np.nan
    for rec in (holed, x[:win - 2]):
        if len(rec) < win:
            with pytest.raises(ValueError):
                prep.as_encoder(rec, dt, 1)
        else:
            assert np.array_equal(prep.as_encoder(rec, dt, 1), real(rec, win, 3, deriv=1, delta=dt), equal_nan=True)
    assert len(calls) == 2
