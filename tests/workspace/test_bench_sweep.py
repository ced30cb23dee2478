"""`./ft bench sweep` (benchmarks/bench_sweep.py): the sweep over the grammar's (channel, term) pairs on the
independent generator. Its core on made-up pulls and reports (fast), and one cell end to end (slow), so the bench
cannot rot."""
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'benchmarks'))

import bench_sweep as S  # noqa: E402
import independent_cases as IG  # noqa: E402

from force_discovery.core.beyond.grammar import SEARCHED, channel_band, channel_library, library  # noqa: E402
from force_tester_sim.core.params import load_rig  # noqa: E402


def test_the_sweep_reads_every_pair_of_the_grammar_and_refuses_a_bad_one():
    # every product term on every channel, those the grammar keeps off a channel too (the report lists them)
    assert S.all_pairs() == [(c, t) for c in SEARCHED for t in library()]
    assert set(S.all_pairs()) > {(c, t) for c in SEARCHED for t in channel_library(c)}
    assert ('force_moving', 'F_move') in S.all_pairs() and ('force_stationary', 'T*v') in S.all_pairs()
    assert S.chosen_pairs('motor_current:v') == [('motor_current', 'v')]
    assert S.chosen_pairs('force_moving') == [('force_moving', t) for t in library()]
    with pytest.raises(ValueError, match="--pairs 'force_moving:sin'"):
        S.chosen_pairs('force_moving:sin')
    for bad in (['--strengths', '0'], ['--signs', '*'], ['--rigs', 'lighter'], ['--clean-pulls', '2-3'],
                ['--pulls', '3']):
        with pytest.raises(SystemExit) as exc:
            S.parse_args(bad)
        assert exc.value.code == 2


def made_up_case():
    """One pull at 1 kHz: loaded from 0.40 s (taut) to 0.60 s (break); the signals made up, the rig the nominal."""
    t = np.arange(1000) / 1000.0
    x = np.clip(t - 0.3, 0, None)
    sig = {'F_move': 1000 * np.exp(-((t - 0.5) / 0.05) ** 2), 'F_stat': 900 * np.exp(-((t - 0.5) / 0.05) ** 2),
           'T': 950 * np.exp(-((t - 0.5) / 0.05) ** 2), 'a2': np.sin(40 * t), 'v': np.gradient(x, t), 'x': x,
           'i': np.zeros_like(t)}
    ch = {'time_s': t, 'force_moving_n': np.zeros_like(t), 'motor_current_a': np.ones_like(t)}
    entry = {'t_taut_s': 0.45, 't_break_s': 0.55, 'signals': {k: v.tolist() for k, v in sig.items()}}
    return IG.Case([({'file': 'p.csv'}, ch)], load_rig(), {'pulls': [entry]}, 1)


@pytest.mark.parametrize('channel, term, strength, sign', [('force_moving', 'v^2', 3.0, 1.0),
                                                           ('motor_current', 'x*t', 10.0, -1.0)])
def test_an_injected_term_has_the_asked_strength_on_the_loaded_window(channel, term, strength, sign):
    base = made_up_case()
    col = {'force_moving': 'force_moving_n', 'motor_current': 'motor_current_a'}[channel]
    before = base.campaign[0][1][col].copy()
    coef = S.coefficient(base, channel, term, strength, sign)
    assert np.sign(coef) == sign
    (_meta, ch), = S.inject(base, channel, term, coef)
    added = ch[col] - before
    t = ch['time_s']
    window = (t >= 0.45 - S.BEFORE_S) & (t <= 0.55 + S.AFTER_S)
    assert np.sqrt(np.mean(added[window] ** 2)) == pytest.approx(strength * channel_band(channel, base.rig))
    assert np.array_equal(base.campaign[0][1][col], before)                    # the base is not changed
    assert S.coefficient(base, channel, 'F_move', 1.0, 1.0) is not None
    zero = made_up_case()
    zero.truth['pulls'][0]['signals']['x'] = [0.0] * 1000
    assert S.coefficient(zero, channel, 'x', 1.0, 1.0) is None          # nothing to scale: not a cell


def test_an_injected_term_lands_on_the_channels_adc_steps():
    # the term acts before the DAQ: the record it makes is quantised as the channel is (a quantised record plus a
    # smooth term would flicker off its grid, and the quality screen would take each flicker for a spike)
    base = made_up_case()
    base.truth['daq'] = {'channels': {'force_moving_n': {'lsb_si': 0.25}}}
    coef = S.coefficient(base, 'force_moving', 't', 3.0, 1.0)
    (_meta, ch), = S.inject(base, 'force_moving', 't', coef)
    steps = ch['force_moving_n'] / 0.25
    assert np.allclose(steps, np.round(steps)) and np.ptp(steps) > 10
    assert np.abs(ch['force_moving_n'] - coef * np.arange(1000) / 1000.0).max() <= 0.125 + 1e-12


def test_an_injected_term_is_recorded_behind_the_channels_filter_at_its_sampling_instants():
    # the term acts before the DAQ: the record carries it through the channel's anti-alias filter and where the
    # channel is sampled (the pull's clock rate error, the channel's skew), as it carries the channel's own signal
    base = made_up_case()
    delta, skew = 1e-3, 5e-4
    base.truth['daq'] = {'filter': {'type': 'bessel', 'order': 8, 'fc_hz': 100.0},
                         'clock_offset_pull': {'p.csv': delta}, 'channels': {'force_moving_n': {'skew_s': skew}}}
    base.truth['pulls'][0]['file'] = 'p.csv'   # the truth's pull entries name their file, as the daq's keys do
    lag = IG.R.aa_group_delay('bessel', 8, 100.0)   # about 4 ms: the 100 Hz filter passes the 50 ms pulse whole
    coef = S.coefficient(base, 'force_moving', 'F_move', 3.0, 1.0)
    (_meta, ch), = S.inject(base, 'force_moving', 'F_move', coef)
    t = ch['time_s']
    at = t / (1 + delta) + skew - lag
    want = coef * 1000 * np.exp(-((at - 0.5) / 0.05) ** 2)
    assert np.abs(ch['force_moving_n'] - want).max() <= 0.01 * coef * 1000
    assert np.argmax(ch['force_moving_n']) == np.argmin(np.abs(at - 0.5)) > 502   # the peak comes late, by the lag
    window = (t >= 0.45 - S.BEFORE_S) & (t <= 0.55 + S.AFTER_S)
    assert np.sqrt(np.mean(ch['force_moving_n'][window] ** 2)) == pytest.approx(3.0 * channel_band('force_moving',
                                                                                                  base.rig))


def test_the_outcomes_are_told_apart():
    def report(terms, causes=()):
        return {'beyond_catalog': terms, 'causes': [{'name': c} for c in causes]}
    right = {'channel': 'motor_current', 'term': 'v', 'coefficient': 1.1, 'ci95': [0.9, 1.3]}
    got = S.outcome(report([right]), 'motor_current', 'v', 1.0)
    assert got['right'] and got['coef30'] and got['ci95'] and not got['catalog']
    got = S.outcome(report([{**right, 'coefficient': 1.5, 'ci95': [1.4, 1.6]}]), 'motor_current', 'v', 1.0)
    assert got['right'] and not got['coef30'] and not got['ci95']
    assert S.outcome(report([right]), 'motor_current', 'x', 1.0)['other']
    assert S.outcome(report([], ['effective_mass']), 'motor_current', 'x', 1.0)['catalog']
    assert S.outcome(report([], ['unexplained']), 'motor_current', 'x', 1.0)['nothing']
    inside = {**report([]), 'beyond_search': {'within_tolerance': [{'channel': 'motor_current', 'term': 'x'}]}}
    got = S.outcome(inside, 'motor_current', 'x', 1.0)
    assert got['nothing'] and got['in_band'] and not S.outcome(inside, 'motor_current', 'v', 1.0)['in_band']
    assert S.outcome({'beyond_catalog': {'not_available': 'too few'}, 'causes': []}, 'force_moving', 'v',
                     1.0)['nothing']
    listed = {**report([]), 'beyond_search': {'identifiability': [
        {'channel': 'force_moving', 'term': 'T^2', 'reason': "read as the stationary cell's own"}]}}
    got = S.outcome(listed, 'force_moving', 'T^2', 1.0)
    assert got['nothing'] and got['listed'] and not S.outcome(listed, 'force_stationary', 'T^2', 1.0)['listed']


def test_a_tie_the_report_lists_is_counted_apart_from_right_and_from_another_term():
    # issue 39's "another term" cells on the sensors: the named term is one the report says the true pair cannot be
    # told from, by the grammar (read_as) or by the data (a named term's near-tie group); counted as a tie, never right
    def report(named, entries):
        return {'beyond_catalog': [{'channel': c, 'term': t, 'coefficient': 1.0, 'ci95': [0.9, 1.1]} for c, t in named],
                'causes': [], 'beyond_search': {'identifiability': entries}}
    read = report([('force_moving', 'F_move*v')], [
        {'channel': 'accel_axial', 'term': 'F_move*v', 'reason': 'slack', 'read_as': 'force_moving:F_move*v'}])
    got = S.outcome(read, 'accel_axial', 'F_move*v', 1.0)
    assert got['tie'] and got['listed'] and not got['right'] and not got['other']
    assert S.outcome(read, 'accel_axial', 'F_stat*v', 1.0)['other']        # another pair's read_as is no tie
    group = [{'channel': 'force_stationary', 'term': 'F_stat^2', 'reason': 'a near-tie',
              'near_tie': ['force_moving:F_move^2', 'force_stationary:F_stat^2', 'force_moving:F_move*T']}]
    got = S.outcome(report([('force_moving', 'F_move^2')], group), 'force_stationary', 'F_stat^2', 1.0)
    assert got['tie'] and not got['right']
    assert S.outcome(report([('force_moving', 'T*v')], group), 'force_stationary', 'F_stat^2', 1.0)['other']
    # both at once: the true pair read as a member of the named term's group (accel T^2 -> the stationary cell's own)
    both = group + [{'channel': 'accel_axial', 'term': 'T^2', 'reason': 'slack',
                     'read_as': 'force_stationary:F_stat^2'}]
    assert S.outcome(report([('force_moving', 'F_move^2')], both), 'accel_axial', 'T^2', 1.0)['tie']
    assert S.outcome(report([('force_moving', 'F_move^2')], both), 'accel_axial', 'T*v', 1.0)['other']
    # the catalog cause the grammar reads a linear force as (read_as_cause): a tie; another catalog cause: catalog
    gain = [{'channel': 'force_stationary', 'term': 'T', 'reason': 'the gain', 'read_as_cause': 'moving_cell_gain'}]
    named = {**report([], gain), 'causes': [{'name': 'moving_cell_gain'}]}
    assert S.outcome(named, 'force_stationary', 'T', 1.0)['tie'] and not S.outcome(named, 'force_stationary', 'T',
                                                                                   1.0)['catalog']
    assert S.outcome({**named, 'causes': [{'name': 'effective_mass'}]}, 'force_stationary', 'T', 1.0)['catalog']
    assert S.outcome(named, 'force_stationary', 'T*v', 1.0)['catalog']     # not that pair's reading


def test_the_matrix_gives_the_right_share_of_the_cells_not_listed(capsys):
    row = dict.fromkeys(('n', *S.OUTCOMES, 'right_listed'), 0)
    a = {**row, 'n': 2, 'right': 1, 'other': 1, 'listed': 1}                       # the listed one named another
    b = {**row, 'n': 2, 'right': 2, 'listed': 1, 'right_listed': 1}                # the listed one found anyway
    S.print_matrix({('force_moving', 'T^2', 3.0): a, ('force_moving', 'v', 3.0): b}, [3.0])
    out = capsys.readouterr().out
    assert 'at 3x band, 4 cells: right 3 (75 %)' in out and 'listed 2 (50 %)' in out
    assert 'of the 2 cells whose pair the report does not list as unidentifiable: right 2 (100 %)' in out


@pytest.mark.slow
def test_one_cell_of_the_sweep_end_to_end(tmp_path, monkeypatch):
    # a viscous force seen in the motor current at 10x its band, on a 4-pull independent campaign made afresh
    monkeypatch.setenv(IG.CACHE_ENV, str(tmp_path / 'cache'))
    base = S.base_case('nominal', 3900, 4)
    assert len(base.campaign) == 4 and 'signals' in base.truth['pulls'][0]
    got, said = S.run_cell(base, 'motor_current', 'v', 10.0, 1.0, tmp_path / 'out')
    assert got['right'] and got['coef30'], said
