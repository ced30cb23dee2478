"""Unit and property tests of force_correction.core (no ROS needed)."""

import copy
import dataclasses
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from force_correction.core import (
    EVENT_KINDS,
    MAX_WINDOW,
    BlockAligner,
    CorrectionError,
    CorrectionParams,
    InertialCorrector,
    PullAccumulator,
    SetStatistics,
    correct_block,
    correct_signal,
    initial_state,
    score_pull,
)
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.correction import MASS_KG, WINDOW

ATOL = 1e-9


# ----------------------------------------------------------------------------- helpers
def naive_movmean(x, w):
    """MATLAB movmean(x, [w-1 0]) ignoring NaN (slow, obviously correct; math.fsum)."""
    out = np.empty(len(x))
    for i in range(len(x)):
        win = [v for v in x[max(0, i - w + 1):i + 1] if not math.isnan(v)]
        out[i] = math.fsum(win) / len(win) if win else math.nan
    return out


def stream(force, accel, params, sizes):
    """Feed force/accel in blocks of the given sizes (remaining samples in a last block)."""
    state = initial_state(params)
    outs, i = [], 0
    for s in list(sizes) + [len(force)]:
        j = min(len(force), i + s)
        blk, state = correct_block(force[i:j], accel[i:j], params, state)
        assert len(blk) == j - i
        outs.append(blk)
        i = j
    cat = {k: np.concatenate([getattr(b, k) for b in outs])
           for k in ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')}
    cat['nan_count'] = sum(b.nan_count for b in outs)
    return cat, state


def assert_same(a, b, atol=ATOL):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.array_equal(np.isnan(a), np.isnan(b))
    fin = ~np.isnan(a)
    if fin.any():
        assert np.max(np.abs(a[fin] - b[fin])) <= atol


def make_signal(seed, n, offset, scale, nan_frac=0.0):
    rng = np.random.default_rng(seed)
    force = offset + scale * np.cumsum(rng.standard_normal(n)) / 10 + scale * rng.standard_normal(n)
    accel = 50.0 * rng.standard_normal(n) + offset / 100.0
    if nan_frac:
        force[rng.random(n) < nan_frac] = np.nan
        accel[rng.random(n) < nan_frac / 2] = np.nan
    return force, accel


# ----------------------------------------------------------------------------- params
def test_params_defaults():
    p = CorrectionParams()
    assert (p.mass_kg, p.window) == (MASS_KG, WINDOW)  # the shared defaults
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.window = 3  # frozen


@pytest.mark.parametrize('kwargs, fragment', [
    (dict(window=0), 'window 0 is out of range; expected an integer in [1, 50000]'),
    (dict(window=MAX_WINDOW + 1), 'window 50001 is out of range; expected an integer in [1, 50000]'),
    (dict(window=-3), 'window -3 is out of range'),
    (dict(window=2.5), 'window 2.5 is not an integer'),
    (dict(window=True), 'window True is not an integer'),
    (dict(mass_kg=0.0), 'mass_kg 0.0 is out of range'),
    (dict(mass_kg=-1.0), 'mass_kg -1.0 is out of range'),
    (dict(mass_kg=float('nan')), 'mass_kg nan is out of range'),
    (dict(mass_kg=float('inf')), 'mass_kg inf is out of range'),
    (dict(mass_kg='1'), "mass_kg '1' is not a real number"),
])
def test_params_validation(kwargs, fragment):
    with pytest.raises(CorrectionError) as ei:
        CorrectionParams(**kwargs)
    assert fragment in str(ei.value)
    assert isinstance(ei.value, ValueError)


def test_params_integral_float_window_normalised():
    assert CorrectionParams(window=140.0).window == 140
    assert type(CorrectionParams(window=np.int64(7)).window) is int


# ----------------------------------------------------------------------------- streaming
def test_moving_average_hand_example():
    p = CorrectionParams(mass_kg=1.0, window=3)
    out = correct_signal([1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0, 0.0], p)
    np.testing.assert_array_equal(out.filtered_n, [1.0, 1.5, 2.0, 3.0])
    np.testing.assert_array_equal(out.corrected_n, [1.0, 2.0, 3.0, 4.0])


def test_inertial_term_hand_example():
    p = CorrectionParams(mass_kg=2.0, window=2)
    out = correct_signal([10.0, 20.0, 30.0], [1.0, -2.0, 5.0], p)
    np.testing.assert_array_equal(out.raw_n, [10.0, 20.0, 30.0])
    np.testing.assert_array_equal(out.inertial_n, [2.0, -4.0, 10.0])
    np.testing.assert_array_equal(out.corrected_n, [8.0, 24.0, 20.0])
    np.testing.assert_array_equal(out.filtered_n, [8.0, 16.0, 22.0])
    assert out.nan_count == 0


def test_window_one_is_identity():
    f, a = make_signal(1, 500, 1e3, 100.0)
    out = correct_signal(f, a, CorrectionParams(window=1))
    np.testing.assert_array_equal(out.filtered_n, out.corrected_n)


def test_batch_matches_naive_reference_long():
    f, a = make_signal(2, 3000, 5e3, 300.0)
    p = CorrectionParams(window=140)
    out = correct_signal(f, a, p)
    ref = naive_movmean(f - p.mass_kg * a, 140)
    assert_same(out.filtered_n, ref, atol=1e-9)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 1500), window=st.integers(1, 300),
       offset=st.sampled_from([0.0, 1e3, -2e3, 5e4, 1e5]), scale=st.floats(1e-3, 2e3),
       nan_frac=st.sampled_from([0.0, 0.0, 0.01, 0.3, 1.0]),
       sizes=st.lists(st.integers(0, 400) | st.sampled_from([0, 1]), max_size=40))
def test_streamed_equals_one_pass_any_split(seed, n, window, offset, scale, nan_frac, sizes):
    f, a = make_signal(seed, n, offset, scale, nan_frac)
    p = CorrectionParams(mass_kg=1.152, window=window)
    ref = correct_signal(f, a, p)
    got, state = stream(f, a, p, sizes)
    for k in ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n'):
        assert_same(got[k], getattr(ref, k))
    assert got['nan_count'] == ref.nan_count == int(np.count_nonzero(np.isnan(ref.corrected_n)))
    assert state.samples_seen == n and state.nan_total == ref.nan_count
    # and the one-pass result is the right answer (independent, exactly-rounded reference)
    if n <= 400:
        naive = naive_movmean(ref.corrected_n, window)
        assert_same(ref.filtered_n, naive, atol=1e-9 * max(1.0, abs(offset) / 1e3))


def test_streamed_equals_one_pass_long_signal_many_blocks():
    f, a = make_signal(3, 120_000, 2e4, 1e3)
    p = CorrectionParams()
    ref = correct_signal(f, a, p)
    rng = np.random.default_rng(4)
    sizes = rng.choice([0, 1, 7, 50, 50, 50, 139, 140, 141, 999], size=4000)
    got, _ = stream(f, a, p, sizes)
    assert_same(got['filtered_n'], ref.filtered_n)
    # spot check the tail against an exactly rounded window mean
    c = ref.corrected_n
    for i in (139, 50_000, 119_999):
        exact = math.fsum(c[i - 139:i + 1]) / 140
        assert abs(ref.filtered_n[i] - exact) <= 1e-9


def test_nan_isolation():
    w = 20
    p = CorrectionParams(window=w)
    f, a = make_signal(5, 400, 1e3, 50.0)
    fbad = f.copy()
    fbad[100] = np.nan
    abad = a.copy()
    abad[250] = np.inf
    good = correct_signal(f, a, p)
    bad = correct_signal(fbad, abad, p)
    assert bad.nan_count == 2
    assert np.isnan(bad.corrected_n[100]) and np.isnan(bad.corrected_n[250])
    assert not np.isnan(bad.filtered_n).any()  # NaN ignored by the average
    # inside the affected windows: mean of the finite samples
    naive = naive_movmean(bad.corrected_n, w)
    assert_same(bad.filtered_n, naive)
    # once the NaN has left the window the output equals the NaN-free reference exactly
    np.testing.assert_array_equal(bad.filtered_n[:100], good.filtered_n[:100])
    np.testing.assert_array_equal(bad.filtered_n[100 + w:250], good.filtered_n[100 + w:250])
    np.testing.assert_array_equal(bad.filtered_n[250 + w:], good.filtered_n[250 + w:])
    assert not np.array_equal(bad.filtered_n[100:100 + w], good.filtered_n[100:100 + w])
    # streamed in 1-sample blocks: same
    got, state = stream(fbad, abad, p, [1] * 400)
    assert_same(got['filtered_n'], bad.filtered_n)
    assert state.nan_total == 2


def test_all_nan_window_gives_nan_then_recovers():
    p = CorrectionParams(mass_kg=1.0, window=3)
    out = correct_signal([np.nan, np.nan, 3.0, np.nan, np.nan, np.nan, 6.0], [0.0] * 7, p)
    assert_same(out.filtered_n, [np.nan, np.nan, 3.0, 3.0, 3.0, np.nan, 6.0])
    assert out.nan_count == 5


def test_state_is_immutable_and_copyable():
    p = CorrectionParams(window=5)
    f, a = make_signal(6, 30, 1e3, 10.0)
    _, s1 = correct_block(f[:10], a[:10], p, initial_state(p))
    s_copy = copy.deepcopy(s1)
    o1, s2 = correct_block(f[10:], a[10:], p, s1)
    o2, s3 = correct_block(f[10:], a[10:], p, s_copy)  # replay from the same state
    np.testing.assert_array_equal(o1.filtered_n, o2.filtered_n)
    assert s2 == s3 and s1 == s_copy
    assert s1.samples_seen == 10 and len(s1.tail) == 4
    with pytest.raises(ValueError):
        s1.tail[0] = 1.0  # read-only


def test_block_input_not_aliased():
    p = CorrectionParams(window=3)
    f = np.array([1.0, 2.0, 3.0])
    out = correct_signal(f, np.zeros(3), p)
    f[0] = 100.0
    assert out.raw_n[0] == 1.0


def test_errors_on_bad_inputs():
    p = CorrectionParams(window=3)
    with pytest.raises(CorrectionError, match='force has 3 samples but accel has 2'):
        correct_signal([1.0, 2.0, 3.0], [0.0, 0.0], p)
    with pytest.raises(CorrectionError, match='state window 3 does not match params window 4'):
        correct_block([1.0], [0.0], CorrectionParams(window=4), initial_state(p))
    with pytest.raises(CorrectionError, match=r'shape \(2, 2\)'):
        correct_signal(np.zeros((2, 2)), np.zeros((2, 2)), p)


def test_inertial_corrector_class():
    p = CorrectionParams(window=7)
    f, a = make_signal(7, 100, 1e3, 10.0)
    ref = correct_signal(f, a, p)
    c = InertialCorrector(p)
    out = np.concatenate([c.process(f[i:i + 13], a[i:i + 13]).filtered_n for i in range(0, 100, 13)])
    assert_same(out, ref.filtered_n)
    saved = c.state
    c.reset()
    assert c.state.samples_seen == 0
    np.testing.assert_array_equal(c.process(f[:5], a[:5]).filtered_n, ref.filtered_n[:5])
    c.state = saved
    assert c.state.samples_seen == 100
    with pytest.raises(CorrectionError):
        c.state = initial_state(CorrectionParams(window=8))


def test_core_does_not_import_rclpy():
    code = ('import sys, pkgutil, importlib, force_correction.core as c\n'
            'for m in pkgutil.iter_modules(c.__path__):\n'
            '    importlib.import_module("force_correction.core." + m.name)\n'
            'bad = [m for m in sys.modules if m.split(".")[0] in ("rclpy", "rosidl_runtime_py")]\n'
            'assert not bad, bad\n')
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                       env=None, timeout=60)
    assert r.returncode == 0, r.stderr


# ----------------------------------------------------------------------------- aligner
RATE = 50_000.0
N = 50
DT_NS = 1_000_000  # 50 samples at 50 kHz


def blocks_for(channel, k, t0=10**18, n=N, rate=RATE):
    return [(channel, t0 + i * DT_NS, i, rate, n, (channel, t0 + i * DT_NS)) for i in range(k)]


@settings(max_examples=100, deadline=None)
@given(order=st.lists(st.sampled_from(['force', 'accel', 'stat']), min_size=0, max_size=120))
def test_aligner_pairs_shuffled_arrival(order):
    chans = ('force', 'accel', 'stat')
    queues = {c: blocks_for(c, 40) for c in chans}
    arrival = []
    for c in order:  # hypothesis-chosen interleaving, then the rest round robin
        if queues[c]:
            arrival.append(queues[c].pop(0))
    while any(queues.values()):
        for c in chans:
            if queues[c]:
                arrival.append(queues[c].pop(0))
    al = BlockAligner(chans, max_pending=50)
    pairs, events = [], []
    for b in arrival:
        p, e = al.push(*b)
        pairs += p
        events += e
    assert events == []
    assert [p.stamp_ns for p in pairs] == [10**18 + i * DT_NS for i in range(40)]
    for i, p in enumerate(pairs):
        assert {c: p[c] for c in chans} == {c: (c, p.stamp_ns) for c in chans}
        assert p.continuous == (i > 0)
        assert p.n_samples == N and p.sample_rate_hz == RATE


def test_aligner_dropped_block():
    al = BlockAligner(('force', 'accel'))
    pairs, events = [], []
    for b in blocks_for('force', 6):
        p, e = al.push(*b)
        pairs += p
        events += e
    acc = blocks_for('accel', 6)
    del acc[2]  # lost upstream
    for b in acc:
        p, e = al.push(*b)
        pairs += p
        events += e
    assert [p.seqs['force'] for p in pairs] == [0, 1, 3, 4, 5]
    kinds = [(e.kind, e.channel, e.seq) for e in events]
    assert ('dropped', 'accel', 3) in kinds
    assert ('unmatched', 'force', 2) in kinds
    assert [p.continuous for p in pairs] == [False, True, False, True, True]
    assert any(e.kind == 'discontinuity' for e in events)
    dropped = next(e for e in events if e.kind == 'dropped')
    assert 'expected seq 2, got 3' in dropped.detail
    assert al.pending_count('force') == 0 and al.pending_count('accel') == 0


def test_aligner_max_pending():
    al = BlockAligner(('force', 'accel'), max_pending=5)
    events = []
    for b in blocks_for('force', 8):
        _, e = al.push(*b)
        events += e
    assert [e.seq for e in events if e.kind == 'unmatched'] == [0, 1, 2]
    assert al.pending_count('force') == 5
    p, e = al.push(*blocks_for('accel', 8)[7])
    assert len(p) == 1 and p[0].seqs == {'force': 7, 'accel': 7}
    assert sorted(x.seq for x in e if x.kind == 'unmatched') == [3, 4, 5, 6]


@pytest.mark.parametrize('how', ['replay', 'restart_seq_only', 'jump_forward'])
def test_aligner_starts_a_new_run_and_never_pairs_across_it(how):
    """A replayed bag (seq and stamps start over), a restarted source (seq starts over, stamps go
    on) or a long jump forward is a new run: reported, the old run's pending blocks dropped, and
    the new run paired from its first block on."""
    al = BlockAligner(('force', 'accel'), new_run_gap_s=1.0)
    first = [b for i in range(10) for b in (blocks_for('force', 10)[i], blocks_for('accel', 10)[i])]
    for b in first[:-3]:   # the old run's last force block and accel blocks 8-9 never come
        al.push(*b)
    assert al.pending_count('force') == 1   # force 8 waits for its partner
    t0 = {'replay': 10**18, 'restart_seq_only': 10**18 + 10 * DT_NS, 'jump_forward': 10**18 + 5 * NS_PER_S}[how]
    seq0 = 10 if how == 'jump_forward' else 0
    second = [(c, t, seq + seq0, r, n, (c, 'run 2', t)) for c, t, seq, r, n, _ in
              (b for i in range(10) for b in (blocks_for('force', 10, t0)[i], blocks_for('accel', 10, t0)[i]))]
    pairs, events = [], []
    for b in second:
        p, e = al.push(*b)
        pairs += p
        events += e
    runs = [e for e in events if e.kind == 'new_run']
    assert sorted(e.channel for e in runs) == ['accel', 'force'], events
    assert len(pairs) == 10 and all(p['force'][1] == p['accel'][1] == 'run 2' for p in pairs)
    assert pairs[0].continuous is False and all(p.continuous for p in pairs[1:])
    assert not any(e.kind == 'dropped' for e in events)
    if how != 'jump_forward':
        assert 'pending block(s) of the old run discarded' in runs[0].detail


@pytest.mark.parametrize('how', ['replay', 'restart_seq_only', 'jump_forward', 'one_channel'])
def test_a_new_run_is_one_event_not_also_a_discontinuity(how):
    """A new run is reported once, as new_run: its first pair is not continuous, and is not
    reported again as a discontinuity from the old run's last pair (each event is a warning of
    the nodes). 'one_channel': only the second channel starts over (the validator's view of a
    restarted correction)."""
    al = BlockAligner(('force', 'accel'), new_run_gap_s=1.0)
    for i in range(5):
        for c in ('force', 'accel'):
            al.push(*blocks_for(c, 5)[i])
    t0 = {'replay': 10**18, 'restart_seq_only': 10**18 + 5 * DT_NS, 'jump_forward': 10**18 + 5 * NS_PER_S,
          'one_channel': 10**18 + 5 * DT_NS}[how]
    seq0 = 5 if how == 'jump_forward' else 0
    pairs, events = [], []
    for i in range(5):
        for c in ('force', 'accel'):
            ch, t, seq, r, n, pay = blocks_for(c, 5, t0)[i]
            seq = seq + 5 if how == 'one_channel' and c == 'force' else seq + seq0
            p, e = al.push(ch, t, seq, r, n, pay)
            pairs += p
            events += e
    kinds = [e.kind for e in events]
    assert kinds == (['new_run'] if how == 'one_channel' else ['new_run', 'new_run']), events
    assert len(pairs) == 5 and pairs[0].continuous is False and all(p.continuous for p in pairs[1:])


def test_aligner_discards_a_duplicate_block():
    al = BlockAligner(('force', 'accel'))
    b = blocks_for('force', 1)[0]
    al.push(*b)
    p, e = al.push(*b)
    assert p == [] and [x.kind for x in e] == ['duplicate'] and al.pending_count('force') == 1


def test_aligner_rate_and_length_mismatch():
    al = BlockAligner(('force', 'accel'))
    al.push('force', 1000, 0, RATE, 50, 'f')
    p, e = al.push('accel', 1000, 0, 25_000.0, 50, 'a')
    assert p == [] and {x.kind for x in e} == {'rate_mismatch'} and '25000.0 Hz' in e[0].detail
    al.push('force', 2_001_000, 1, RATE, 50, 'f')
    p, e = al.push('accel', 2_001_000, 1, RATE, 49, 'a')
    assert p == [] and {x.kind for x in e} == {'length_mismatch'} and '49' in e[0].detail
    assert all(x.kind in EVENT_KINDS for x in e)


def test_aligner_rejects_bad_input():
    al = BlockAligner(('force', 'accel'))
    with pytest.raises(CorrectionError, match="channel 'x' is unknown"):
        al.push('x', 0, 0, RATE, 1, None)
    with pytest.raises(CorrectionError, match='stamp_ns 1.5 is not an int'):
        al.push('force', 1.5, 0, RATE, 1, None)


def test_aligner_half_sample_tolerance():
    al = BlockAligner(('a',))
    p1, _ = al.push('a', 0, 0, RATE, 50, None)
    p2, _ = al.push('a', DT_NS + 9_000, 1, RATE, 50, None)   # within 10 us (half a sample)
    p3, e = al.push('a', 2 * DT_NS + 30_000, 2, RATE, 50, None)  # 21 us late
    assert [p.continuous for p in p1 + p2 + p3] == [False, True, False]
    assert e[0].kind == 'discontinuity'


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_aligner_never_misaligns(data):
    chans = ('force', 'accel')
    k = data.draw(st.integers(1, 60))
    streams = {}
    for c in chans:
        blocks = []
        for i in range(k):
            action = data.draw(st.sampled_from(['ok'] * 6 + ['drop', 'short', 'dup', 'shift']))
            stamp = 10**15 + i * DT_NS
            if action == 'drop':
                continue
            n = N - 1 if action == 'short' else N
            if action == 'shift':
                stamp += 7
            blocks.append((c, stamp, i, RATE, n, (c, stamp, n)))
            if action == 'dup':
                blocks.append((c, stamp, i, RATE, n, (c, stamp, n)))
        streams[c] = blocks
    al = BlockAligner(chans, max_pending=data.draw(st.integers(1, 10)))
    pairs = []
    while any(streams.values()):
        c = data.draw(st.sampled_from([c for c in chans if streams[c]]))
        p, e = al.push(*streams[c].pop(0))
        assert all(x.kind in EVENT_KINDS for x in e)
        pairs += p
    stamps = [p.stamp_ns for p in pairs]
    assert stamps == sorted(set(stamps))
    for p in pairs:
        assert p['force'][1] == p['accel'][1] == p.stamp_ns
        assert p['force'][2] == p['accel'][2] == p.n_samples
    for a, b in zip(pairs, pairs[1:]):
        if b.continuous:
            assert abs(b.stamp_ns - a.stamp_ns - DT_NS) <= 10_000 and a.n_samples == N


# ----------------------------------------------------------------------------- scoring
def hand_pull():
    n = 100
    s = np.zeros(n)
    s[20:60] = np.linspace(100.0, 1000.0, 40)   # loaded window: s > 100 N -> 39 samples
    raw = s * 1.2                               # peak 1200 -> 20 %
    cor = s - 50.0                              # peak 950 -> 5 %
    fil = s + 10.0                              # peak 1010 -> 1 %
    return s, raw, cor, fil


def test_score_pull_hand_example():
    s, raw, cor, fil = hand_pull()
    r = score_pull(s, raw, cor, fil)
    assert r.stationary_peak_n == 1000.0
    assert (r.raw_peak_n, r.corrected_peak_n, r.filtered_peak_n) == (1200.0, 950.0, 1010.0)
    assert r.raw_diff_pct == pytest.approx(20.0)
    assert r.corrected_diff_pct == pytest.approx(5.0)
    assert r.filtered_diff_pct == pytest.approx(1.0)
    assert r.n_loaded == 39
    assert r.corrected_rms_n == pytest.approx(50.0)
    assert r.filtered_rms_n == pytest.approx(10.0)
    loaded = s > 100.0
    assert r.raw_rms_n == pytest.approx(np.sqrt(np.mean((0.2 * s[loaded]) ** 2)))


def test_score_pull_ignores_nan_and_rejects_bad_peak():
    s, raw, cor, fil = hand_pull()
    raw = raw.copy()
    raw[10] = raw[40] = np.nan
    s2 = s.copy()
    s2[0] = np.nan
    r = score_pull(s2, raw, cor, fil)
    assert r.raw_diff_pct == pytest.approx(20.0) and math.isfinite(r.raw_rms_n)
    with pytest.raises(CorrectionError, match=r'stationary peak -5.0 N'):
        score_pull(np.full(5, -5.0), np.ones(5), np.ones(5), np.ones(5))
    with pytest.raises(CorrectionError, match='stationary peak nan'):
        score_pull(np.full(5, np.nan), np.ones(5), np.ones(5), np.ones(5))
    with pytest.raises(CorrectionError, match='raw has 4 samples but stationary has 5'):
        score_pull(np.ones(5), np.ones(4), np.ones(5), np.ones(5))


def test_score_pull_peaks_are_nanmax_with_and_without_nan():
    """A peak is the max over the finite samples: a NaN at the largest sample, everywhere, or nowhere."""
    s, raw, cor, fil = hand_pull()
    cor = cor.copy()
    cor[int(np.argmax(cor))] = np.nan            # the largest sample lost: the next largest is the peak
    fil = np.full_like(fil, np.nan)              # no filtered sample at all: no filtered peak
    r = score_pull(s, raw, cor, fil)
    assert r.raw_peak_n == np.nanmax(raw) and r.corrected_peak_n == np.nanmax(cor)
    assert r.corrected_peak_n < np.max(hand_pull()[2])
    assert math.isnan(r.filtered_peak_n)


def rms_by_masks(a: np.ndarray, s: np.ndarray, fraction: float) -> float:
    """score_pull's RMS as it was written before the loaded samples were taken by index: boolean masks, the NaN-free
    errors copied out, their mean square."""
    loaded = s > fraction * np.nanmax(s)
    err = a[loaded] - s[loaded]
    fin = err[~np.isnan(err)]
    return float(np.sqrt(np.mean(fin * fin))) if fin.size else math.nan


@pytest.mark.parametrize('hole', [None, 'nan_in_load', 'all_nan', 'inf'])
def test_score_pull_rms_and_u_equal_the_masks_definition(hole):
    """Each RMS to the last bit against the masks' computation; the peak's U is computed where a corrected sample is
    finite (its nanmax finite, or +inf with a finite one beside it) and not where none is."""
    rng = np.random.default_rng(3)
    t = np.arange(4000) / 1000.0
    s = 1000.0 * np.exp(-0.5 * ((t - 2.0) / 0.3) ** 2) + rng.normal(0, 1, t.size)
    raw, cor, fil = 1.2 * s + rng.normal(0, 2, t.size), 0.95 * s, 1.01 * s
    ma = 0.2 * s
    if hole == 'nan_in_load':
        raw[2000] = cor[1990:2010:3] = np.nan
    elif hole == 'all_nan':
        cor = np.full_like(cor, np.nan)
    elif hole == 'inf':
        cor[100] = np.inf
    r = score_pull(s, raw, cor, fil, inertial=ma, sample_rate_hz=1000.0)
    for name, a in (('raw', raw), ('corrected', cor), ('filtered', fil)):
        want, got = rms_by_masks(a, s, 0.1), getattr(r, f'{name}_rms_n')
        assert got == want or (math.isnan(got) and math.isnan(want)), (name, got, want)
    assert r.n_loaded == int(np.count_nonzero(s > 0.1 * s.max()))
    assert math.isnan(r.corrected_peak_u_n) == (hole == 'all_nan')


def test_pull_accumulator_splits_straddling_blocks():
    s, raw, cor, fil = hand_pull()
    rate = 1000.0                      # 1 ms per sample
    t0 = 5 * 10**18
    start = t0 + 15 * 10**6            # pull = samples 15 .. 64
    acc = PullAccumulator(start)
    for i in range(0, 100, 10):        # blocks of 10 straddle start (10..19) and end (60..69)
        acc.add_block(t0 + i * 10**6, rate, s[i:i + 10], raw[i:i + 10], cor[i:i + 10], fil[i:i + 10])
        if i == 60:
            acc.finish(t0 + 65 * 10**6)
    acc.note_dropped(2)
    a = acc.arrays()
    np.testing.assert_array_equal(a['stationary'], s[15:65])
    np.testing.assert_array_equal(a['time_ns'], t0 + np.arange(15, 65) * 10**6)
    r = acc.score()
    assert r.n_samples == 50 and r.dropped_blocks == 2
    assert r.raw_diff_pct == pytest.approx(20.0)
    with pytest.raises(CorrectionError, match='end_ns'):
        PullAccumulator(100, 50)


def test_set_statistics():
    stats = SetStatistics()
    base = score_pull(*hand_pull())
    from dataclasses import replace
    for d, peak in ((10.0, 1000.0), (20.0, 2000.0), (30.0, 3000.0)):
        stats.add(1, replace(base, raw_diff_pct=d, corrected_diff_pct=d / 10,
                             filtered_diff_pct=5.0, stationary_peak_n=peak))
    stats.add(2, base)
    s1 = stats.summary(1)
    assert s1.pulls == 3 and s1.mean_stationary_peak_n == pytest.approx(2000.0)
    assert s1.raw_mean_pct == pytest.approx(20.0) and s1.raw_std_pct == pytest.approx(10.0)
    assert s1.corrected_mean_pct == pytest.approx(2.0) and s1.corrected_std_pct == pytest.approx(1.0)
    assert s1.filtered_std_pct == 0.0
    s2 = stats.summary(2)
    assert s2.pulls == 1 and s2.raw_std_pct == 0.0 and s2.raw_mean_pct == pytest.approx(20.0)
    with pytest.raises(CorrectionError, match="set 9 has no scored pulls"):
        stats.summary(9)
