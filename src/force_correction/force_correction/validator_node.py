"""validator node: scores the corrected force against the stationary cell, pull by pull.

Subscribes /force_corrected, /force (for the stationary cell) and /pull_event; publishes
/pull_score after each pull (eq 1 at the peaks for the raw, m*a-corrected and filtered signals,
RMS error over the loaded window; latched, the last 1000), the same score on /pull_score_latest
(latched with depth 1: a late joiner asking for one score gets the newest) and /set_summary
(per-set mean and standard deviation, like thesis Tables 8 and 9; latched with depth 1, so a late
joiner gets the current summary).

Every incoming message is checked before use; a bad one is counted, reported on /diagnostics and
dropped. Each score has a status (PullScore.msg): a restarted or replayed source is a new run, and
a pull that straddles it is ABORTED, as is one whose source stops mid-pull (abort_timeout_s); a
restart of the correction alone leaves a gap and the pull is INCOMPLETE (so are pulls with lost
blocks); a change of the correction's parameters mid-pull (seen on /parameter_events) makes it
RECONFIGURED. No pull is scored from a mix of two runs (core/tracking.py). /set_summary covers
the OK pulls only.
"""
from __future__ import annotations

import math

from force_tester_msgs.msg import PullEvent, PullScore, SetSummary
from rcl_interfaces.msg import ParameterEvent
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
from force_tester_common.core.channels import (
    PULL_EVENT_TOPIC,
    PULL_SCORE_LATEST_TOPIC,
    PULL_SCORE_TOPIC,
    SET_SUMMARY_TOPIC,
)
from force_tester_common.core.ros_home import under_ros_home
from force_tester_common.core.scores import (
    PULL_ABORTED,
    PULL_OK,
    PULL_SCORE_FIELDS,
    PULL_STATUS_NAMES,
    SET_SUMMARY_FIELDS,
    pull_status,
)
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import (
    BLOCK_QOS,
    ERROR,
    EVENT_QOS,
    LATEST_SCORE_QOS,
    OK,
    SCORE_QOS,
    SUMMARY_QOS,
    WARN,
    Diagnostics,
    guarded,
    in_namespace,
    main_for,
    qos_watch,
    steady_timer,
)

from .core.errors import CorrectionError
from .core.pairing import BlockAligner
from .core.peak_uncertainty import PeakInputs
from .core.score_log import LoggedScore, ScoreLog
from .core.scoring import PullAccumulator, SetStatistics
from .core.tracking import Finished, PullTracker
from .correction_node import RESTARTING_PARAMETERS

FORCE = next(t for t in BLOCK_TOPICS if t.topic == '/force')
USED_FIELDS = {'corrected': ('raw_n', 'corrected_n', 'filtered_n', 'inertial_n'), 'force': ('stationary_n',)}
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
    ParamSpec('state_file', '', 'JSON-lines file the scores are appended to; a restarted validator republishes '
                                'them and its set summaries go on from them ("" = keep nothing; a relative path '
                                'is under $ROS_HOME, default ~/.ros)', read_only=True),
    ParamSpec('peak_uncertainty', True, 'give each corrected peak its expanded uncertainty (k = 2; false: the '
                                        'score without it, NaN, as before; ./ft bench rigs --peak-u compares)'),
    *(ParamSpec(f'peak_u_{k}', 0.0, f'standard uncertainty (k = 1) of {what}, for the expanded uncertainty of '
                                     'each corrected peak (0 = not stated; `./ft demo` passes the rig YAML\'s)',
                rng) for k, what, rng in (
        ('mass_rel', "m2, relative", C.PEAK_U_REL_RANGE),
        ('gain_rel', "the moving cell's gain (sensitivity), relative", C.PEAK_U_REL_RANGE),
        ('accel_sensitivity_rel', "the accelerometer's sensitivity, relative", C.PEAK_U_REL_RANGE),
        ('accel_delay_s', "the accelerometer's lag behind the force channel, s", C.PEAK_U_DELAY_RANGE_S))),
    ParamSpec('correction_node', 'correction', 'name of the correction node whose parameter changes mark the '
                                               'pulls in progress RECONFIGURED (relative: in this node\'s '
                                               'namespace)', read_only=True),
]


def check(values: dict) -> dict:
    lo, hi = C.LOADED_FRACTION_RANGE
    if not lo <= values['loaded_fraction'] <= hi:
        raise CorrectionError(f"loaded_fraction {values['loaded_fraction']} is out of range; expected [{lo}, {hi}]")
    return values


def add_pair(acc: PullAccumulator, pair, inertial: bool = True) -> None:
    """One aligned pair into its pull; ``inertial``: keep m*a too (for the peak's uncertainty)."""
    corrected, force = pair['corrected'], pair['force']
    acc.add_block(pair.stamp_ns, pair.sample_rate_hz, to_array(force.stationary_n),
                  to_array(corrected.raw_n), to_array(corrected.corrected_n), to_array(corrected.filtered_n),
                  inertial=to_array(corrected.inertial_n) if inertial else None)


class ValidatorNode(Node):
    def __init__(self, **kwargs):
        super().__init__('validator', **kwargs)
        self.diag = Diagnostics(self, 'validator', counters=lambda: self.counts)
        self.params = NodeParams(self, SPECS, check)
        name = self.params.values['correction_node']
        self.correction_node = name if name.startswith('/') else f"{self.get_namespace().rstrip('/')}/{name}"
        self.aligner = BlockAligner(('corrected', 'force'), max_pending=self.params.values['max_pending'],
                                    new_run_gap_s=self.params.values['new_run_gap_s'])
        self.tracker = PullTracker(
            lambda acc, pair: add_pair(acc, pair, self.params.values['peak_uncertainty']),
            abort_timeout_s=self.params.values['abort_timeout_s'])
        self.stats = SetStatistics()
        self.counts = {'scores': 0, 'bad_messages': 0, 'runs': 0, 'aborted': 0}
        self._source_restarted = False   # a /force new run whose /force_corrected new run is still to come
        self.score_pub = self.create_publisher(PullScore, in_namespace(PULL_SCORE_TOPIC), SCORE_QOS)
        # the newest score alone, latched: what a late `ros2 topic echo ... --once` wants
        self.latest_pub = self.create_publisher(PullScore, in_namespace(PULL_SCORE_LATEST_TOPIC), LATEST_SCORE_QOS)
        self.summary_pub = self.create_publisher(SetSummary, in_namespace(SET_SUMMARY_TOPIC), SUMMARY_QOS)
        for channel, topic in (('corrected', CORRECTED_TOPIC), ('force', FORCE)):
            self.create_subscription(topic.msg_type, in_namespace(topic.topic), guarded(
                self.diag, topic.topic, lambda m, c=channel, t=topic: self._on_block(c, t, m)), BLOCK_QOS,
                event_callbacks=qos_watch(self.diag, topic.topic))
        self.create_subscription(PullEvent, in_namespace(PULL_EVENT_TOPIC),
                                 guarded(self.diag, PULL_EVENT_TOPIC, self._on_event),
                                 EVENT_QOS, event_callbacks=qos_watch(self.diag, PULL_EVENT_TOPIC))
        self.create_subscription(ParameterEvent, '/parameter_events',
                                 guarded(self.diag, '/parameter_events', self._on_parameters), EVENT_QOS)
        steady_timer(self, TICK_S, self._tick)
        state_file = self.params.values['state_file']
        self.log = ScoreLog(under_ros_home(state_file)) if state_file else None
        if self.log is not None:
            self.log.check_writable()
            self._restore()

    def _restore(self):
        try:
            scores, bad = self.log.load()
        except CorrectionError as exc:
            self.diag.report(ERROR, f'{exc}; starting without earlier scores')
            return
        for logged in scores:
            self._publish(logged, save=False)
        skipped = f'; {bad} unreadable line(s) skipped' if bad else ''
        self.diag.report(WARN if bad else OK, f'{len(scores)} earlier score(s) restored from {self.log.path}{skipped}')

    def peak_inputs(self) -> PeakInputs:
        v = self.params.values
        return PeakInputs(mass_rel=v['peak_u_mass_rel'], gain_rel=v['peak_u_gain_rel'],
                          accel_sensitivity_rel=v['peak_u_accel_sensitivity_rel'],
                          accel_delay_s=v['peak_u_accel_delay_s'])

    def _bad(self, topic: str, problem: str) -> None:
        self.counts['bad_messages'] += 1
        self.diag.report(WARN, f'bad message on {topic} dropped: {problem}', key=('bad', topic, problem.split()[0]),
                         topic=topic, bad_messages=self.counts['bad_messages'])

    def _finish(self, over) -> None:
        for f in over:
            self._score(f)

    def _on_parameters(self, msg: ParameterEvent):
        if msg.node != self.correction_node:
            return
        # changed only: a restarted correction declares its parameters anew (new_parameters), which
        # is a restart (the gap makes those pulls INCOMPLETE), not a change of configuration
        changed = [p for p in msg.changed_parameters if p.name in RESTARTING_PARAMETERS]
        if changed:
            self.tracker.reconfigured('the correction was reconfigured mid-pull (' + ', '.join(
                p.name for p in changed) + ')')

    def _on_event(self, msg: PullEvent):
        problem = stamp_problem(msg.header.stamp.sec, msg.header.stamp.nanosec) or event_problem(msg.event)
        if problem:
            self._bad(PULL_EVENT_TOPIC, problem)
            return
        stamp = stamp_to_ns(msg.header.stamp)
        if msg.event == PullEvent.START:
            self._finish(self.tracker.start(stamp, int(msg.pull_id), int(msg.test_set)))
            return
        try:
            known, ready = self.tracker.end(stamp, int(msg.pull_id))
        except CorrectionError as exc:   # an END not after its START
            self._bad(PULL_EVENT_TOPIC, f'END of pull {msg.pull_id}: {exc}')
            return
        if not known:
            self.diag.report(WARN, f'END of pull {msg.pull_id} without its START; pull not scored',
                             key='end_without_start')
        self._finish(ready)

    def _on_block(self, channel: str, topic, msg):
        problem = message_problem(msg, topic, USED_FIELDS[channel])
        if problem:
            self._bad(topic.topic, problem)
            return
        if channel == 'force':
            self.tracker.source_heard()
        pairs, events = self.aligner.push(channel, stamp_to_ns(msg.header.stamp), msg.seq,
                                          msg.sample_rate_hz, len(getattr(msg, USED_FIELDS[channel][0])), msg)
        for event in events:
            self.diag.report(WARN, f'{event.kind} block on {event.channel}: {event.detail}',
                             key=(event.kind, event.channel))
            if event.kind == 'new_run' and event.channel == 'force':   # the source started over
                self.counts['runs'] += 1
                self._source_restarted = True
                self._finish(self.tracker.new_run())
            elif event.kind == 'new_run':    # the corrected stream: part of that, or the correction alone
                if self._source_restarted:
                    self._source_restarted = False
                else:
                    self.tracker.correction_restarted()
            elif event.kind in ('dropped', 'unmatched'):
                self.tracker.block_lost(event)
        for pair in pairs:
            self._finish(self.tracker.pair(pair))

    def _tick(self):
        self._finish(self.tracker.tick(TICK_S))

    def _score(self, f: Finished):
        acc = f.acc
        notes = f.notes + ((('aborted', f.aborted),) if f.aborted else ())
        try:
            s = acc.score(self.params.values['loaded_fraction'], peak_inputs=self.peak_inputs())
        except CorrectionError as exc:   # no usable data: every pull still gets its message, with NaN
            status, detail = pull_status(acc.dropped_blocks, (*notes, ('incomplete', f'not scored: {exc}')),
                                         aborted=bool(f.aborted))
            msg = PullScore(pull_id=acc.pull_id, test_set=acc.set_id, dropped_blocks=acc.dropped_blocks,
                            status=status, detail=detail, **{k: math.nan for k in PULL_SCORE_FIELDS})
            msg.header.stamp = ns_to_stamp(acc.start_ns)
            self._send(msg)
            self.counts['scores'] += 1
            self.counts['aborted'] += status == PULL_ABORTED
            self.diag.report(ERROR, f'pull {acc.pull_id} (set {acc.set_id}) {PULL_STATUS_NAMES[status]}: '
                                    f'no usable data ({detail})', pull_id=acc.pull_id, status=status)
            return
        status, detail = pull_status(acc.dropped_blocks, notes, aborted=bool(f.aborted))
        self._publish(LoggedScore(acc.pull_id, acc.set_id, acc.start_ns, status, detail, s), save=True)

    def _send(self, msg: PullScore) -> None:
        self.score_pub.publish(msg)
        self.latest_pub.publish(msg)

    def _publish(self, logged: LoggedScore, save: bool):
        """Append one score to the log (save), then publish it (and, for an OK pull, its set's new summary)."""
        s, status = logged.result, logged.status
        msg = PullScore(pull_id=logged.pull_id, test_set=logged.set_id, dropped_blocks=s.dropped_blocks,
                        status=status, detail=logged.detail, **{k: float(getattr(s, k)) for k in PULL_SCORE_FIELDS})
        msg.header.stamp = ns_to_stamp(logged.start_ns)
        if save and self.log is not None:   # saved before it is announced: a kill cannot lose a published score
            try:
                self.log.append(logged)
            except OSError as exc:
                self.diag.report(ERROR, f'score of pull {logged.pull_id} not saved to {self.log.path}: {exc}',
                                 key='log')
        self._send(msg)
        self.counts['scores'] += 1
        if save:
            if status == PULL_ABORTED:
                self.counts['aborted'] += 1
            self.diag.report(OK if status == PULL_OK else WARN,
                             f'pull {logged.pull_id} (set {logged.set_id}) {PULL_STATUS_NAMES[status]}: peak '
                             f'difference raw {s.raw_diff_pct:.1f} %, m*a {s.corrected_diff_pct:.1f} %, filtered '
                             f'{s.filtered_diff_pct:.1f} %' + (f' ({logged.detail})' if logged.detail else ''),
                             pull_id=logged.pull_id, status=status)
        if status != PULL_OK:
            return
        self.stats.add(logged.set_id, s)
        summary = self.stats.summary(logged.set_id)
        out = SetSummary(test_set=logged.set_id, **{f: getattr(summary, k) for f, k in SET_SUMMARY_FIELDS.items()})
        out.header.stamp = msg.header.stamp
        self.summary_pub.publish(out)


main = main_for(ValidatorNode)
