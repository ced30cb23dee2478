"""The checks every node runs on incoming blocks and pull events before use."""
import math

import pytest

from force_tester_common.core.blocks import MAX_BLOCK_SAMPLES, block_problem, event_problem, stamp_problem

GOOD = {'moving_n': 50, 'stationary_n': 50}


@pytest.mark.parametrize('rate', [0.0, -50_000.0, math.nan, math.inf, -math.inf, 1e12])
def test_bad_rates_are_named(rate):
    problem = block_problem(rate, GOOD, ['moving_n'])
    assert problem and 'sample_rate_hz' in problem and repr(rate) in problem


@pytest.mark.parametrize('lengths, required, words', [
    ({'moving_n': 50, 'stationary_n': 49}, ['moving_n'], ['ragged', '49', '50']),
    ({'moving_n': 0, 'stationary_n': 50}, ['moving_n'], ['moving_n', 'empty']),
    ({'moving_n': 0, 'stationary_n': 0}, ['stationary_n'], ['stationary_n', 'empty']),
    ({'moving_n': MAX_BLOCK_SAMPLES + 1, 'stationary_n': MAX_BLOCK_SAMPLES + 1}, ['moving_n'],
     [str(MAX_BLOCK_SAMPLES + 1), 'at most']),
])
def test_bad_array_lengths_are_named(lengths, required, words):
    problem = block_problem(50_000.0, lengths, required)
    assert problem is not None
    for w in words:
        assert w in problem, problem


def test_good_blocks_pass_including_optional_empty_fields():
    assert block_problem(50_000.0, GOOD, ['moving_n', 'stationary_n']) is None
    assert block_problem(50_000.0, {'moving_n': 50, 'stationary_n': 0}, ['moving_n']) is None


def test_events_and_stamps():
    assert event_problem(0) is None and event_problem(1) is None
    assert '7' in event_problem(7) and 'START' in event_problem(7)
    assert stamp_problem(1, 999_999_999) is None
    assert '1000000000' in stamp_problem(1, 1_000_000_000)
    assert stamp_problem(-1, 0) is not None


def test_pull_status_precedence_and_detail():
    from force_tester_common.core.scores import (
        PULL_ABORTED,
        PULL_INCOMPLETE,
        PULL_OK,
        PULL_RECONFIGURED,
        pull_status,
    )
    assert pull_status(0) == (PULL_OK, '')
    assert pull_status(3) == (PULL_INCOMPLETE, '3 block(s) missing')
    assert pull_status(0, [('reconfigured', 'window')]) == (PULL_RECONFIGURED, 'window')
    code, detail = pull_status(2, [('reconfigured', 'window'), ('incomplete', 'gap')])
    assert code == PULL_INCOMPLETE and detail == '2 block(s) missing; window; gap'
    assert pull_status(0, [('aborted', 'stopped')], aborted=True) == (PULL_ABORTED, 'stopped')


@pytest.mark.parametrize('rate', [50_000.0, 48_000.0, 12_345.678, 1.5, 3.0, 1e6, 1e9])
def test_record_stamps_equal_the_broadcast_sample_clock(rate):
    """record_stamps_ns (one block, the per-block fast path) stamps exactly as sample_stamps_ns."""
    import numpy as np

    from force_tester_common.core.clock import record_stamps_ns, sample_stamps_ns
    for first in (0, 123_456_789, 1_795_477_056_761_810_612):
        for n in (0, 1, 50, 500, 5000):
            got = record_stamps_ns(first, n, rate)
            assert got.dtype == np.int64
            assert np.array_equal(got, sample_stamps_ns(first, np.arange(n), rate)), (rate, first, n)
