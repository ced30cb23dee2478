"""validator node: scores the corrected force against the stationary cell, pull by pull.

Subscribes /force_corrected, /force (for the stationary cell) and /pull_event; publishes
/pull_score after each pull (eq 1 at the peaks for the raw, m*a-corrected and filtered signals,
RMS error over the loaded window) and /set_summary (per-set mean and standard deviation, like
thesis Tables 8 and 9).
"""
from __future__ import annotations

from collections import deque

from force_tester_msgs.msg import PullEvent, PullScore, SetSummary
from rclpy.node import Node

from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, ns_to_stamp, stamp_to_ns, to_array
from force_tester_common.core import correction as C
from force_tester_common.core.channels import PULL_EVENT_TOPIC, PULL_SCORE_TOPIC, SET_SUMMARY_TOPIC
from force_tester_common.core.scores import PULL_SCORE_FIELDS, SET_SUMMARY_FIELDS
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import BLOCK_QOS, ERROR, EVENT_QOS, OK, SCORE_QOS, WARN, Diagnostics, main_for

from .core.errors import CorrectionError
from .core.pairing import BlockAligner
from .core.scoring import PullAccumulator, SetStatistics

FORCE = next(t for t in BLOCK_TOPICS if t.topic == '/force')
RECENT_PAIRS = 4000  # pairs kept to replay into a pull whose START event arrives late (4 s of 1 ms blocks)
FINISH_TIMEOUT_S = 5.0  # after END, score what arrived once no new data has come for this long

SPECS = [
    ParamSpec('loaded_fraction', C.LOADED_FRACTION, 'RMS window: samples where the stationary force exceeds '
                                                    'this fraction of its peak', C.LOADED_FRACTION_RANGE),
    ParamSpec('max_pending', C.VALIDATOR_MAX_PENDING, 'blocks a channel may wait for its partner before it is '
                                                      'dropped (the corrected stream lags the force stream)',
              C.MAX_PENDING_RANGE, read_only=True),
]


def check(values: dict) -> dict:
    lo, hi = C.LOADED_FRACTION_RANGE
    if not lo <= values['loaded_fraction'] <= hi:
        raise CorrectionError(f"loaded_fraction {values['loaded_fraction']} is out of range; expected [{lo}, {hi}]")
    return values


class ValidatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__('validator', **kwargs)
        self.diag = Diagnostics(self, 'validator')
        self.params = NodeParams(self, SPECS, check)
        self.aligner = BlockAligner(('corrected', 'force'), max_pending=self.params.values['max_pending'])
        self.recent = deque(maxlen=RECENT_PAIRS)
        self.pulls = {}  # pull_id -> PullAccumulator
        self.idle_s = {}  # pull_id -> seconds since END without the data reaching it
        self.stats = SetStatistics()
        self.score_pub = self.create_publisher(PullScore, PULL_SCORE_TOPIC, SCORE_QOS)
        self.summary_pub = self.create_publisher(SetSummary, SET_SUMMARY_TOPIC, SCORE_QOS)
        self.create_subscription(CORRECTED_TOPIC.msg_type, CORRECTED_TOPIC.topic,
                                 lambda m: self._on_block('corrected', m, len(m.raw_n)), BLOCK_QOS)
        self.create_subscription(FORCE.msg_type, FORCE.topic,
                                 lambda m: self._on_block('force', m, len(m.stationary_n)), BLOCK_QOS)
        self.create_subscription(PullEvent, PULL_EVENT_TOPIC, self._on_event, EVENT_QOS)
        self.create_timer(0.5, self._check_timeouts)

    def _on_event(self, msg: PullEvent):
        stamp = stamp_to_ns(msg.header.stamp)
        if msg.event == PullEvent.START:
            acc = PullAccumulator(stamp, set_id=int(msg.test_set), pull_id=int(msg.pull_id))
            for pair in self.recent:
                self._add(acc, pair)
            self.pulls[msg.pull_id] = acc
        elif msg.event == PullEvent.END:
            acc = self.pulls.get(msg.pull_id)
            if acc is None:
                self.diag.report(WARN, f'END of pull {msg.pull_id} without its START; pull not scored')
                return
            acc.finish(stamp)
            self.idle_s[msg.pull_id] = 0.0
            if self.recent and self.recent[-1].end_stamp_ns >= stamp:
                self._score(msg.pull_id)

    def _on_block(self, channel: str, msg, n: int):
        pairs, events = self.aligner.push(channel, stamp_to_ns(msg.header.stamp), msg.seq,
                                          msg.sample_rate_hz, n, msg)
        for event in events:
            self.diag.report(WARN, f'{event.kind} block on {event.channel}: {event.detail}',
                             key=(event.kind, event.channel))
            if event.kind in ('dropped', 'unmatched'):
                for acc in self.pulls.values():
                    acc.note_dropped()
        for pair in pairs:
            self.recent.append(pair)
            for pull_id, acc in list(self.pulls.items()):
                self._add(acc, pair)
                if pull_id in self.idle_s:
                    self.idle_s[pull_id] = 0.0  # data is still coming
                if acc.finished and pair.end_stamp_ns >= acc.end_ns:
                    self._score(pull_id)

    @staticmethod
    def _add(acc: PullAccumulator, pair):
        corrected, force = pair['corrected'], pair['force']
        acc.add_block(pair.stamp_ns, pair.sample_rate_hz, to_array(force.stationary_n),
                      to_array(corrected.raw_n), to_array(corrected.corrected_n), to_array(corrected.filtered_n))

    def _check_timeouts(self):
        for pull_id in list(self.idle_s):
            self.idle_s[pull_id] += 0.5
            if self.idle_s[pull_id] >= FINISH_TIMEOUT_S:
                self.diag.report(WARN, f'pull {pull_id}: data stopped before its END; scoring what arrived')
                self._score(pull_id)

    def _score(self, pull_id: int):
        acc = self.pulls.pop(pull_id)
        self.idle_s.pop(pull_id, None)
        try:
            s = acc.score(self.params.values['loaded_fraction'])
        except CorrectionError as exc:
            self.diag.report(ERROR, f'pull {pull_id} of set {acc.set_id} not scored: {exc}')
            return
        self.stats.add(acc.set_id, s)
        msg = PullScore(pull_id=pull_id, test_set=acc.set_id, dropped_blocks=s.dropped_blocks,
                        **{k: float(getattr(s, k)) for k in PULL_SCORE_FIELDS})
        msg.header.stamp = ns_to_stamp(acc.start_ns)
        self.score_pub.publish(msg)
        self.diag.report(OK, f'pull {pull_id} (set {acc.set_id}): peak difference raw {s.raw_diff_pct:.1f} %, '
                             f'm*a {s.corrected_diff_pct:.1f} %, filtered {s.filtered_diff_pct:.1f} %')
        summary = self.stats.summary(acc.set_id)
        out = SetSummary(test_set=acc.set_id, **{f: getattr(summary, k) for f, k in SET_SUMMARY_FIELDS.items()})
        out.header.stamp = msg.header.stamp
        self.summary_pub.publish(out)


main = main_for(ValidatorNode)
