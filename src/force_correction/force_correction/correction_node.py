"""correction node: /force + /accel blocks -> /force_corrected (raw, m*a, corrected, filtered).

Every incoming block is checked (stamp, rate, array lengths) before use; a bad one is counted,
reported on /diagnostics and dropped. Blocks of the two channels are paired by stamp (and checked
by sequence number) before the ROS-free core corrects them; a dropped, unmatched or late block is
reported on /diagnostics and the filter restarts after the gap, so the two channels are never
silently misaligned. A restarted or replayed stream is a new run: reported, and corrected from its
first block. Only a change of mass, window or extension restarts the filter.
"""
from __future__ import annotations

from rclpy.node import Node

from force_tester_common.conversions import (
    BLOCK_TOPICS,
    CORRECTED_TOPIC,
    fill_block,
    message_problem,
    stamp_to_ns,
    to_array,
)
from force_tester_common.core import correction as C
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import BLOCK_QOS, OK, WARN, Diagnostics, guarded, in_namespace, main_for, qos_watch

from .core.extension import Extension, ForcePrefilter, load_filters
from .core.pairing import BlockAligner
from .core.params import CorrectionParams
from .core.short_events import ShortEventMonitor, advice
from .core.streaming import InertialCorrector

SPECS = [
    ParamSpec('mass_kg', C.MASS_KG, 'mass between the moving cell and the accelerometer, m2 (thesis eq 24)',
              C.MASS_RANGE_KG),
    ParamSpec('window', C.WINDOW, 'moving-average length N in samples (thesis eq 25; 2.8 ms at 50 kHz)',
              C.WINDOW_RANGE),
    ParamSpec('extension_file', '', 'extension.yaml of ./ft discover: its correction: section (mass, cell gain, '
                                    'accelerometer delay, AC coupling, mains hum) is undone before m*a ("" = none)'),
    ParamSpec('max_pending', C.MAX_PENDING, 'blocks a channel may wait for its partner before it is dropped',
              C.MAX_PENDING_RANGE, read_only=True),
    ParamSpec('new_run_gap_s', C.NEW_RUN_GAP_S, 'a stamp jump forward by more than this starts a new run '
                                                '(a jump back or a sequence restart always does)',
              C.NEW_RUN_GAP_RANGE_S, read_only=True),
]
USED_FIELDS = {'force': ('moving_n',), 'accel': ('axial_m_s2',)}
RESTARTING_PARAMETERS = ('mass_kg', 'window', 'extension_file')   # a change of these restarts the filter

TOPICS = {t.topic: t for t in BLOCK_TOPICS}


def config_from(values: dict):
    ext = Extension.from_yaml(values['extension_file']) if values['extension_file'] else Extension()
    mass = ext.mass_kg if ext.mass_kg is not None else values['mass_kg']
    return CorrectionParams(mass_kg=mass, window=values['window']), ext


class CorrectionNode(Node):
    def __init__(self, **kwargs):
        super().__init__('correction', **kwargs)
        self.diag = Diagnostics(self, 'inertial correction', counters=lambda: self.counts)
        self.params = NodeParams(self, SPECS, config_from, on_change=self._reconfigure)
        self.corrector = self.extension = self.prefilters = None
        self._reconfigure(self.params.config)
        self.aligner = BlockAligner(('force', 'accel'), max_pending=self.params.values['max_pending'],
                                    new_run_gap_s=self.params.values['new_run_gap_s'])
        self.pub = self.create_publisher(CORRECTED_TOPIC.msg_type, in_namespace(CORRECTED_TOPIC.topic), BLOCK_QOS)
        for channel, topic in (('force', TOPICS['/force']), ('accel', TOPICS['/accel'])):
            self.create_subscription(topic.msg_type, in_namespace(topic.topic), guarded(
                self.diag, topic.topic, lambda m, c=channel, t=topic: self._on_block(c, t, m)), BLOCK_QOS,
                event_callbacks=qos_watch(self.diag, topic.topic))
        self.seq = 0
        self.counts = {'pairs': 0, 'nan_samples': 0, 'events': 0, 'bad_messages': 0, 'runs': 0,
                       'short_events': 0}

    def _reconfigure(self, config):
        params, ext = config
        self.corrector = InertialCorrector(params)
        self.extension = ext
        load_filters(ext)
        self.prefilters = {}  # sample rate -> ForcePrefilter
        self.monitors = {}    # sample rate -> ShortEventMonitor
        self.diag.report(OK, f'(re)started: m = {params.mass_kg:g} kg, N = {params.window}, '
                             f'extension: {ext.describe()}')
        if ext.not_applied:   # an extension term the correction cannot undo: the corrected force is off by it
            self.diag.report(WARN, ext.not_applied_warning())

    def _prefilter(self, rate_hz: float) -> ForcePrefilter:
        if rate_hz not in self.prefilters:
            self.prefilters[rate_hz] = ForcePrefilter(self.extension, rate_hz)
        return self.prefilters[rate_hz]

    def _on_block(self, channel: str, topic, msg):
        problem = message_problem(msg, topic, USED_FIELDS[channel])
        if problem:
            self.counts['bad_messages'] += 1
            self.diag.report(WARN, f'bad block on {topic.topic} dropped: {problem}',
                             key=('bad', topic.topic, problem.split()[0]),
                             topic=topic.topic, bad_messages=self.counts['bad_messages'])
            return
        n = len(getattr(msg, USED_FIELDS[channel][0]))
        pairs, events = self.aligner.push(channel, stamp_to_ns(msg.header.stamp), msg.seq,
                                          msg.sample_rate_hz, n, msg)
        for event in events:
            self.counts['events'] += 1
            if event.kind == 'new_run':
                self.counts['runs'] += 1
            self.diag.report(WARN, f'{event.kind} block on {event.channel}: {event.detail}',
                             key=(event.kind, event.channel), channel=event.channel, seq=event.seq,
                             stamp_ns=event.stamp_ns)
        for pair in pairs:
            self._correct(pair)

    def _correct(self, pair):
        force, accel = pair['force'], pair['accel']
        prefilter = self._prefilter(pair.sample_rate_hz)
        rate = pair.sample_rate_hz
        monitor = self.monitors.get(rate)
        if monitor is None:
            monitor = self.monitors[rate] = ShortEventMonitor(self.corrector.params.window, rate)
        if not pair.continuous:
            self.corrector.reset()
            prefilter.reset()
            monitor.reset()
        raw = to_array(force.moving_n)
        out = self.corrector.process(prefilter.process(raw), to_array(accel.axial_m_s2))
        for event in monitor.add(raw, out.corrected_n):   # impacts narrower than a few windows
            self.counts['short_events'] += 1
            self.diag.report(WARN, f'{event.line(rate)}; {advice(self.extension != Extension())}',
                             key='short_event', loss_pct=round(100 * event.loss, 1),
                             bandwidth_window=event.bandwidth_window)
        if out.nan_count:
            self.counts['nan_samples'] += out.nan_count
            self.diag.report(WARN, f'{out.nan_count} NaN sample(s) in the block stamped {pair.stamp_ns} ns; '
                                   'their corrected values are NaN, the filter skips them', key='nan')
        msg = fill_block(CORRECTED_TOPIC.msg_type(), pair.stamp_ns, force.sample_rate_hz, self.seq,
                         {'raw_n': raw, 'inertial_n': out.inertial_n,
                          'corrected_n': out.corrected_n, 'filtered_n': out.filtered_n})
        msg.header.frame_id = force.header.frame_id
        self.pub.publish(msg)
        self.seq += 1
        self.counts['pairs'] += 1


main = main_for(CorrectionNode)
