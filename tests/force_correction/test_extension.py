"""The correctable part of an extension: streaming inverse filters on the moving-cell force."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from force_correction.core.errors import CorrectionError
from force_correction.core.extension import Extension, ForcePrefilter

FS = 50_000.0


def signal(n=20_000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    return 2000 * np.exp(-((t - 0.2) / 0.02) ** 2) + 30 * np.sin(2 * np.pi * 900 * t) + rng.normal(0, 0.3, n)


def test_gain_and_ac_coupling_are_undone_exactly():
    x = signal()
    tau, gain = 0.5, 1.04
    p = tau / (tau + 1 / FS)
    measured = lfilter([p, -p], [1, -p], gain * x)        # the sim's first-order high-pass of the gained force
    ext = Extension(moving_cell_gain=gain, ac_coupling_time_constant_s=tau)
    np.testing.assert_allclose(ForcePrefilter(ext, FS).process(measured), x, rtol=0, atol=1e-6)


def test_a_non_linear_cell_is_linearised_before_its_gain():
    """Issue 27: extension.yaml's F_move^2 and F_move^3 terms on the moving cell (measured = F + c2 F^2 + c3 F^3,
    then the gain) are undone sample by sample, whatever the block split."""
    x = signal()
    c2, c3, gain = 2e-5, -3e-9, 1.03
    measured = gain * (x + c2 * x ** 2 + c3 * x ** 3)
    # discover fits the terms on the gained force: gain F + c2' (gain F)^2 + c3' (gain F)^3
    ext = Extension(moving_cell_gain=gain, moving_cell_quadratic_per_n=c2 / gain,
                    moving_cell_cubic_per_n2=c3 / gain ** 2)
    one = ForcePrefilter(ext, FS).process(measured)
    np.testing.assert_allclose(one, x, rtol=0, atol=1e-6)
    pf = ForcePrefilter(ext, FS)
    split = np.concatenate([pf.process(measured[:777]), pf.process(measured[777:])])
    np.testing.assert_array_equal(split, one)
    with pytest.raises(CorrectionError, match='moving_cell_quadratic_per_n'):
        Extension(moving_cell_quadratic_per_n=0.5)


def test_delay_lines_the_force_up_with_a_lagging_accelerometer():
    x = signal()
    ext = Extension(accel_delay_s=3 / FS)                  # whole samples: exact
    y = ForcePrefilter(ext, FS).process(x)
    np.testing.assert_allclose(y[3:], x[:-3], rtol=0, atol=1e-12)
    half = ForcePrefilter(Extension(accel_delay_s=2.5 / FS), FS).process(x)
    np.testing.assert_allclose(half[3:], 0.5 * (x[1:-2] + x[:-3]), rtol=0, atol=1e-9)


def test_hum_is_learnt_unloaded_and_removed_without_touching_the_pull():
    n = 100_000
    t = np.arange(n) / FS
    hum = 5 * np.sin(2 * np.pi * 60 * t + 0.3)
    pulse = 3000 * np.exp(-((t - 1.5) / 0.005) ** 2)      # a 10 ms pull after 1.4 s of unloaded record
    y = ForcePrefilter(Extension(mains_hum_hz=60.0), FS).process(pulse + hum)
    late = slice(int(0.5 * FS), None)
    assert np.std((y - pulse)[late]) < 0.05 * np.std(hum)   # the line is gone, in and out of the pull
    assert abs(y.max() - pulse.max()) < 0.001 * pulse.max()  # the pull's peak is kept (a notch would cut it)


@settings(max_examples=40, deadline=None)
@given(cuts=st.lists(st.integers(0, 4000), max_size=8), delay=st.floats(0, 2e-4), gain=st.floats(0.9, 1.1),
       tau=st.one_of(st.none(), st.floats(0.01, 5)), hum=st.one_of(st.none(), st.sampled_from([50.0, 60.0])))
def test_any_block_split_equals_one_pass(cuts, delay, gain, tau, hum):
    x = signal(4000, seed=1)
    x[123] = np.nan
    ext = Extension(moving_cell_gain=gain, accel_delay_s=delay, ac_coupling_time_constant_s=tau, mains_hum_hz=hum)
    whole = ForcePrefilter(ext, FS).process(x)
    pf = ForcePrefilter(ext, FS)
    bounds = [0, *sorted(cuts), len(x)]
    parts = np.concatenate([pf.process(x[a:b]) for a, b in zip(bounds[:-1], bounds[1:])])
    np.testing.assert_allclose(parts, whole, rtol=0, atol=1e-9, equal_nan=True)
    assert np.isnan(whole[123]) and np.isfinite(np.delete(whole, 123)).all()


def test_bad_extensions_are_refused_with_the_value(tmp_path):
    with pytest.raises(CorrectionError, match='-1.0'):
        Extension(accel_delay_s=-1.0)
    with pytest.raises(CorrectionError, match="'speed'"):
        Extension.from_dict({'speed': 3})
    f = tmp_path / 'ext.yaml'
    f.write_text('departures: []\n')
    assert Extension.from_yaml(f) == Extension()
    f.write_text('correction: [1, 2]\n')
    with pytest.raises(CorrectionError, match='correction'):
        Extension.from_yaml(f)


def test_terms_the_correction_cannot_undo_are_named_not_ignored(tmp_path):
    f = tmp_path / 'ext.yaml'
    f.write_text('correction: {moving_cell_quadratic_per_n: 1.0e-05}\n'
                 'extra_terms:\n'
                 '  - {channel: force_moving, term: F_move^2, coefficient: 1.0e-05}\n'
                 '  - {channel: force_moving, term: v, coefficient: 12.0}\n'
                 '  - {channel: accel_axial, term: t, coefficient: 2.5}\n'
                 '  - {channel: motor_current, term: v^2, coefficient: 0.1}\n')
    ext = Extension.from_yaml(f)
    # the polynomial is undone; the drag and the accelerometer's drift change the corrected force and are not;
    # the current's drag does not enter the corrected force at all
    assert ext.not_applied == ('force_moving: v', 'accel_axial: t')
    assert ext.moving_cell_quadratic_per_n == 1.0e-05
    assert 'not undone: force_moving: v, accel_axial: t' in ext.describe()
    f.write_text('correction: {}\nextra_terms: {channel: force_moving}\n')
    with pytest.raises(CorrectionError, match="'channel': 'force_moving'"):
        Extension.from_yaml(f)
