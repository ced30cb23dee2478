"""validator node: scores the corrected force against the stationary cell, pull by pull.

Subscribes /force_corrected, /force (for the stationary cell) and /pull_event; publishes
/pull_score after each pull (eq 1 at the peaks for the raw, m*a-corrected and filtered signals,
RMS error over the loaded window) and /set_summary (per-set mean and standard deviation, like
thesis Tables 8 and 9; latched with depth 1, so a late joiner gets the current summary).

Every incoming message is checked before use; a bad one is counted, reported on /diagnostics and
dropped. A restarted or replayed stream (blocks or pull events) is a new run: pulls that straddle
it are closed unscored and reported, so no pull is scored from a mix of two runs
(core/tracking.py).
"""
from __future__ import annotations

from force_tester_msgs.msg import PullEvent, PullScore, SetSummary
from rclpy.node import Node

from force_tester_common.conversions import (
    BLOCK_TOPICS,
    CORRECTED_TOPIC,
    message_problem,
    ns_to_stamp,
    stamp_to_ns,
    to_array,
)
from force_tester_common.core import correction as C
from force_tester_common.core.blocks import event_problem, stamp_problem
from force_tester_common.core.channels import PULL_EVENT_TOPIC, PULL_SCORE_TOPIC, SET_SUMMARY_TOPIC
from force_tester_common.core.scores import PULL_SCORE_FIELDS, SET_SUMMARY_FIELDS
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import (
    BLOCK_QOS,
    ERROR,
    EVENT_QOS,
    OK,
    SCORE_QOS,
    SUMMARY_QOS,
    WARN,
    Diagnostics,
    guarded,
    main_for,
)

from .core.errors import CorrectionError
from .core.pairing import BlockAligner
from .core.scoring import PullAccumulator, SetStatistics
from .core.tracking import PullTracker

FORCE = next(t for t in BLOCK_TOPICS if t.topic == '/force')
USED_FIELDS = {'corrected': ('raw_n', 'corrected_n', 'filtered_n'), 'force': ('stationary_n',)}
TICK_S = 0.5

SPECS = [
    ParamSpec('loaded_fraction', C.LOADED_FRACTION, 'RMS window: samples where the stationary force exceeds '
                                                    'this fraction of its peak', C.LOADED_FRACTION_RANGE),
    ParamSpec('max_pending', C.VALIDATOR_MAX_PENDING, 'blocks a channel may wait for its partner before it is '
                                                      'dropped (the corrected stream lags the force stream)',
              C.MAX_PENDING_RANGE, read_only=True),
    ParamSpec('new_run_gap_s', C.NEW_RUN_GAP_S, 'a stamp jump forward by more than this starts a new run '
                                                '(a jump back or a sequence restart always does)',
              C.NEW_RUN_GAP_RANGE_S, read_only=True),
    ParamSpec('abort_timeout_s', C.ABORT_TIMEOUT_S, 'a started pull without data and without END for this long '
                                                    'is closed as aborted (the source stopped mid-pull)',
              C.ABORT_TIMEOUT_RANGE_S, read_only=True),
]


def check(values: dict) -> dict:
    lo, hi = C.LOADED_FRACTION_RANGE
    if not lo <= values['loaded_fraction'] <= hi:
        raise CorrectionError(f"loaded_fraction {values['loaded_fraction']} is out of range; expected [{lo}, {hi}]")
    return values


def add_pair(acc: PullAccumulator, pair) -> None:
    corrected, force = pair['corrected'], pair['force']
    acc.add_block(pair.stamp_ns, pair.sample_rate_hz, to_array(force.stationary_n),
                  to_array(corrected.raw_n), to_array(corrected.corrected_n), to_array(corrected.filtered_n))


class ValidatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__('validator', **kwargs)
        self.diag = Diagnostics(self, 'validator')
        self.params = NodeParams(self, SPECS, check)
        self.aligner = BlockAligner(('corrected', 'force'), max_pending=self.params.values['max_pending'],
                                    new_run_gap_s=self.params.values['new_run_gap_s'])
        self.tracker = PullTracker(add_pair, abort_timeout_s=self.params.values['abort_timeout_s'])
        self.stats = SetStatistics()
        self.counts = {'bad_messages': 0, 'runs': 0, 'closed_unscored': 0}
        self.score_pub = self.create_publisher(PullScore, PULL_SCORE_TOPIC, SCORE_QOS)
        self.summary_pub = self.create_publisher(SetSummary, SET_SUMMARY_TOPIC, SUMMARY_QOS)
        for channel, topic in (('corrected', CORRECTED_TOPIC), ('force', FORCE)):
            self.create_subscription(topic.msg_type, topic.topic, guarded(
                self.diag, topic.topic, lambda m, c=channel, t=topic: self._on_block(c, t, m)), BLOCK_QOS)
        self.create_subscription(PullEvent, PULL_EVENT_TOPIC, guarded(self.diag, PULL_EVENT_TOPIC, self._on_event),
                                 EVENT_QOS)
        self.create_timer(TICK_S, self._tick)

    def _bad(self, topic: str, problem: str) -> None:
        self.counts['bad_messages'] += 1
        self.diag.report(WARN, f'bad message on {topic} dropped: {problem}', key=('bad', topic, problem.split()[0]),
                         topic=topic,
                         bad_messages=self.counts['bad_messages'])

    def _closed(self, closed) -> None:
        for c in closed:
            self.counts['closed_unscored'] += 1
            self.diag.report(WARN, f'pull {c.pull_id} of set {c.set_id} closed unscored: {c.reason}',
                             pull_id=c.pull_id)

    def _on_event(self, msg: PullEvent):
        problem = stamp_problem(msg.header.stamp.sec, msg.header.stamp.nanosec) or event_problem(msg.event)
        if problem:
            self._bad(PULL_EVENT_TOPIC, problem)
            return
        stamp = stamp_to_ns(msg.header.stamp)
        if msg.event == PullEvent.START:
            self._closed(self.tracker.start(stamp, int(msg.pull_id), int(msg.test_set)))
            return
        try:
            known, ready = self.tracker.end(stamp, int(msg.pull_id))
        except CorrectionError as exc:   # an END not after its START
            self._bad(PULL_EVENT_TOPIC, f'END of pull {msg.pull_id}: {exc}')
            return
        if not known:
            self.diag.report(WARN, f'END of pull {msg.pull_id} without its START; pull not scored',
                             key='end_without_start')
        for acc in ready:
            self._score(acc)

    def _on_block(self, channel: str, topic, msg):
        problem = message_problem(msg, topic, USED_FIELDS[channel])
        if problem:
            self._bad(topic.topic, problem)
            return
        pairs, events = self.aligner.push(channel, stamp_to_ns(msg.header.stamp), msg.seq,
                                          msg.sample_rate_hz, len(getattr(msg, USED_FIELDS[channel][0])), msg)
        for event in events:
            self.diag.report(WARN, f'{event.kind} block on {event.channel}: {event.detail}',
                             key=(event.kind, event.channel))
            if event.kind == 'new_run':
                self.counts['runs'] += 1
                self._closed(self.tracker.new_run())
            elif event.kind in ('dropped', 'unmatched'):
                self.tracker.dropped()
        for pair in pairs:
            for acc in self.tracker.pair(pair):
                self._score(acc)

    def _tick(self):
        ready, aborted = self.tracker.tick(TICK_S)
        self._closed(aborted)
        for acc in ready:
            self.diag.report(WARN, f'pull {acc.pull_id}: data stopped before its END; scoring what arrived')
            self._score(acc)

    def _score(self, acc: PullAccumulator):
        try:
            s = acc.score(self.params.values['loaded_fraction'])
        except CorrectionError as exc:
            self.diag.report(ERROR, f'pull {acc.pull_id} of set {acc.set_id} not scored: {exc}')
            return
        self.stats.add(acc.set_id, s)
        msg = PullScore(pull_id=acc.pull_id, test_set=acc.set_id, dropped_blocks=s.dropped_blocks,
                        **{k: float(getattr(s, k)) for k in PULL_SCORE_FIELDS})
        msg.header.stamp = ns_to_stamp(acc.start_ns)
        self.score_pub.publish(msg)
        self.diag.report(OK, f'pull {acc.pull_id} (set {acc.set_id}): peak difference raw {s.raw_diff_pct:.1f} %, '
                             f'm*a {s.corrected_diff_pct:.1f} %, filtered {s.filtered_diff_pct:.1f} %')
        summary = self.stats.summary(acc.set_id)
        out = SetSummary(test_set=acc.set_id, **{f: getattr(summary, k) for f, k in SET_SUMMARY_FIELDS.items()})
        out.header.stamp = msg.header.stamp
        self.summary_pub.publish(out)


main = main_for(ValidatorNode)
