"""The validator's pull bookkeeping across restarts and replays (core/tracking.py, no ROS)."""
from types import SimpleNamespace

import numpy as np
import pytest

from force_correction.core.pairing import BlockAligner
from force_correction.core.tracking import PullTracker

RATE, N, DT = 50_000.0, 50, 1_000_000
T0 = 10**18


def add(acc, pair):
    stat, moving = pair['force'], pair['corrected']
    acc.add_block(pair.stamp_ns, pair.sample_rate_hz, stat, moving, moving, moving)


class Stream:
    """Blocks of one run through a real BlockAligner into the tracker."""

    def __init__(self, tracker):
        self.aligner = BlockAligner(('corrected', 'force'))
        self.tracker = tracker
        self.ready, self.closed = [], []

    def push(self, k, t0, seq0, peak):
        t = np.arange(N) + k * N
        force = peak * np.exp(-((t - 250) / 60.0) ** 2)   # a pull of 10 blocks, peak at sample 250
        for channel, values in (('corrected', 1.1 * force), ('force', force)):
            pairs, events = self.aligner.push(channel, t0 + k * DT, seq0 + k, RATE, N, values)
            for e in events:
                if e.kind == 'new_run':
                    self.closed += self.tracker.new_run()
            for p in pairs:
                self.ready += self.tracker.pair(p)


def run_pull(tracker, stream, t0, seq0, peak, start_first=True, blocks=10):
    if start_first:
        stream.closed += tracker.start(t0, 1, 3)
    for k in range(blocks):
        stream.push(k, t0, seq0, peak)
        if k == 2 and not start_first:
            stream.closed += tracker.start(t0, 1, 3)
    if blocks == 10:
        stream.ready += tracker.end(t0 + 10 * DT, 1)[1]


def test_a_replay_is_scored_from_its_own_blocks_whichever_stream_starts_over_first():
    for start_first in (True, False):
        tracker = PullTracker(add)
        s = Stream(tracker)
        run_pull(tracker, s, T0, 0, 1000.0)
        run_pull(tracker, s, T0, 0, 2000.0, start_first=start_first)  # same stamps, other data
        assert [f.pull_id for f in s.ready] == [1, 1] and s.closed == []
        assert all(f.notes == () and not f.aborted for f in s.ready)
        peaks = [f.acc.score(0.1).stationary_peak_n for f in s.ready]
        assert np.allclose(peaks, [1000.0, 2000.0], rtol=1e-3), (start_first, peaks)
        assert s.ready[1].acc.n_samples == 10 * N


@pytest.mark.parametrize('start_first', [True, False])
def test_a_restart_mid_pull_closes_that_pull_unscored(start_first):
    tracker = PullTracker(add)
    s = Stream(tracker)
    run_pull(tracker, s, T0, 0, 1000.0, blocks=5)        # the source dies half-way
    run_pull(tracker, s, T0 + 60 * DT, 0, 1500.0, start_first=start_first)  # again: seq 0, later stamps
    assert [c.pull_id for c in s.closed] == [1] and 'started over' in s.closed[0].aborted
    assert s.closed[0].acc.n_samples == 5 * N                 # scored as aborted on what arrived
    assert len(s.ready) == 1 and s.ready[0].acc.n_samples == 10 * N and not s.ready[0].aborted


def test_an_ended_pull_whose_data_stops_is_scored_after_the_timeout():
    tracker = PullTracker(add, finish_timeout_s=1.0)
    s = Stream(tracker)
    tracker.start(T0, 1, 3)
    for k in range(8):
        s.push(k, T0, 0, 1000.0)
    assert tracker.end(T0 + 10 * DT, 1) == (True, [])
    assert tracker.tick(0.5) == []
    (f,) = tracker.tick(0.5)
    assert f.pull_id == 1 and f.acc.n_samples == 8 * N and not f.aborted
    assert f.notes[0][0] == 'incomplete' and 'before the END' in f.notes[0][1]
    assert tracker.end(T0, 99) == (False, [])


def test_a_pull_whose_source_stops_before_its_end_is_aborted_after_the_timeout():
    tracker = PullTracker(add, abort_timeout_s=2.0)
    s = Stream(tracker)
    tracker.start(T0, 1, 3)
    for k in range(4):
        s.push(k, T0, 0, 1000.0)
    assert tracker.tick(1.5) == []
    s.push(4, T0, 0, 1000.0)                 # data resets the clock
    assert tracker.tick(1.5) == []
    (f,) = tracker.tick(0.5)
    assert f.pull_id == 1 and 'no data and no END' in f.aborted and not tracker.open


def test_a_correction_restart_leaves_a_gap_and_a_reconfiguration_is_noted():
    tracker = PullTracker(add)
    s = Stream(tracker)
    tracker.start(T0, 1, 3)
    for k in range(4):
        s.push(k, T0, 0, 1000.0)
    tracker.reconfigured('window changed')
    tracker.correction_restarted()               # blocks 4-5 never corrected
    for k in range(6, 10):
        s.push(k, T0, 0, 1000.0)
    (f,) = tracker.end(T0 + 10 * DT, 1)[1]
    kinds = dict(f.notes)
    assert kinds['reconfigured'] == 'window changed'
    assert '2.0 ms from stamp' in kinds['incomplete'], f.notes


def test_the_score_log_round_trips_and_skips_a_line_cut_short(tmp_path):
    from force_correction.core.score_log import LoggedScore, ScoreLog
    tracker = PullTracker(add)
    s = Stream(tracker)
    run_pull(tracker, s, T0, 0, 1000.0)
    result = s.ready[0].acc.score(0.1)
    log = ScoreLog(tmp_path / 'state' / 'scores.jsonl')
    assert log.load() == ([], 0)
    written = [LoggedScore(1, 3, T0, 0, '', result), LoggedScore(2, 3, T0 + 10**9, 1, '2 block(s) missing', result)]
    for w in written:
        log.append(w)
    with log.path.open('a') as fh:
        fh.write('{"pull_id": 3, "set_id"')          # a crash mid-write
    assert log.load() == (written, 1)


def test_a_correction_restart_charges_each_pull_its_own_lost_blocks_and_a_lost_peak_is_not_scored():
    """Issue 41, Low: a correction restart mid-pull charged its whole gap to every open pull and scored the pull
    from what was left of it (stationary_peak_n 1.10, m*a 123.5 %). Here pull 2's START is in before the gap
    (the validator lags); the gap (blocks 4-6, the corrected stream's) holds pull 1's peak (block 5). Each lost
    /force block is charged to the pull whose window holds it, with the stationary force it carried
    (tracker.block_lost, as the validator calls it); pull 1 is then not scored (its peak fell in the gap), pull 2
    is, with 0 lost blocks."""
    from force_correction.core.errors import CorrectionError

    def add_messages(acc, pair):   # the payloads are the block messages, as the validator's
        stat, moving = pair['force'].stationary_n, pair['corrected'].stationary_n
        acc.add_block(pair.stamp_ns, pair.sample_rate_hz, stat, moving, moving, moving)
    tracker = PullTracker(add_messages)
    aligner = BlockAligner(('corrected', 'force'))
    ready = []

    def push(k, channels=('corrected', 'force')):
        t = np.arange(N) + (k % 10) * N
        force = 1000.0 * np.exp(-((t - 250) / 60.0) ** 2)   # each pull's peak at its block 5
        for channel in channels:
            # the payload as the validator's: the block message, whose stationary_n a lost /force block carries
            values = SimpleNamespace(stationary_n=1.1 * force if channel == 'corrected' else force)
            seq = k - 7 if channel == 'corrected' and k >= 7 else k   # the restarted correction counts from 0
            pairs, events = aligner.push(channel, T0 + k * DT, seq, RATE, N, values)
            for e in events:
                if e.kind == 'new_run':
                    tracker.correction_restarted()
                elif e.kind in ('dropped', 'unmatched'):
                    tracker.block_lost(e)
            for p in pairs:
                ready.extend(tracker.pair(p))
    tracker.start(T0, 1, 3)
    tracker.start(T0 + 10 * DT, 2, 3)
    for k in range(4):
        push(k)
    for k in range(4, 7):
        push(k, channels=('force',))          # the correction is down: these never pair
    for k in range(7, 10):
        push(k)
    ready += tracker.end(T0 + 10 * DT, 1)[1]
    for k in range(10, 20):
        push(k)
    ready += tracker.end(T0 + 20 * DT, 2)[1]
    pulls = {f.pull_id: f.acc for f in ready}
    assert (pulls[1].dropped_blocks, pulls[2].dropped_blocks) == (3, 0)
    with pytest.raises(CorrectionError, match='the stationary peak fell in the 3 lost block'):
        pulls[1].score(0.1)
    assert pulls[2].score(0.1).stationary_peak_n == pytest.approx(1000.0, rel=1e-3)
