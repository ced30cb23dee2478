"""./ft monitor: a live terminal scoreboard (Textual) for a running graph or a bag played back.

Per pull: set, status, stationary / raw / m*a / filtered peaks in lbf and the three % differences,
each coloured against --threshold. Per set: the running mean and std over the OK pulls (thesis
Tables 8 and 9). A health line: from the monitor node's /monitor/health when it runs (blocks/s, gaps,
NaN, latency p50/p99, recorder counts); otherwise from the nodes' own /diagnostics heartbeats (the
correction's pairs and NaN samples, the recorder's counts, the validator's dropped blocks), which
costs the graph nothing (no block topic is subscribed). Node states: the last /diagnostics status of
each node, STALE when none came for STALE_S.

The arithmetic is ROS-free (force_correction.core.scoreboard, force_tester_common.core.health);
``MonitorModel`` takes the messages, ``ScoreboardApp`` draws it, ``RosFeed`` is the rclpy side.
"""
from __future__ import annotations

import math
import queue
import threading
import time

from force_correction.core.scoreboard import (
    DIFF_KINDS,
    DIFF_THRESHOLD_PCT,
    FAIR,
    GOOD,
    POOR,
    CounterRate,
    Scoreboard,
    fmt,
    grade,
)
from force_tester_common.core.channels import (
    ACCEL_TYPE,
    BLOCK_TYPES,
    CORRECTED_TYPE,
    DIAGNOSTICS_TOPIC,
    FORCE_TYPE,
    MONITOR_HEALTH_TOPIC,
    PULL_SCORE_TOPIC,
)
from force_tester_common.core.clock import NS_PER_S, stamp_to_ns
from force_tester_common.core.health import (
    LEVEL_ERROR,
    LEVEL_NAMES,
    LEVEL_OK,
    LEVEL_STALE,
    LEVEL_WARN,
    NodeStates,
    level_of,
)
from force_tester_common.core.units import n_to_lbf

REFRESH_S = 0.5
PULL_ROWS = 12        # the last pulls shown
COLOURS = {GOOD: 'green', FAIR: 'yellow', POOR: 'bold red'}
LEVEL_COLOURS = {LEVEL_OK: 'green', LEVEL_WARN: 'yellow', LEVEL_ERROR: 'bold red', LEVEL_STALE: 'magenta'}
PULL_COLUMNS = ('pull', 'set', 'status', 'stat lbf', 'raw lbf', 'm*a lbf +/- U (k=2)', 'MA lbf',
                'raw %', 'm*a %', 'MA %')
SET_COLUMNS = ('set', 'OK pulls', 'stat lbf', 'raw % mean+/-std', 'm*a % mean+/-std', 'MA % mean+/-std')
NODE_COLUMNS = ('node', 'state', 'message', 'age s')
# the health line shows the sample-block topics the correction reads and writes (the others are quiet;
# the monitor node watches /accel only while a Foxglove client does, so it may be missing)
HEALTH_TOPICS = (BLOCK_TYPES[FORCE_TYPE][0], BLOCK_TYPES[ACCEL_TYPE][0], CORRECTED_TYPE[1][0])


def add_arguments(p):
    p.add_argument('--threshold', type=float, default=DIFF_THRESHOLD_PCT, metavar='PCT',
                   help=f'peak difference up to PCT %% is green, up to twice it yellow, above red '
                        f'(default {DIFF_THRESHOLD_PCT:g})')
    p.add_argument('--exit-after', type=float, default=None, metavar='S',
                   help='quit after S seconds (for scripts; default: run until q or Ctrl-C)')


class MonitorModel:
    """What the scoreboard shows, fed with real messages (PullScore, DiagnosticArray, MonitorHealth)
    and their arrival time in ns."""

    def __init__(self, threshold_pct: float = DIFF_THRESHOLD_PCT):
        self.board = Scoreboard(threshold_pct)
        self.nodes = NodeStates()
        self.health = None            # (arrival ns, MonitorHealth)
        self.counters = {}            # status name -> {key: value} of the last report
        self.rates = {}               # (status name, key) -> CounterRate
        self.dropped_blocks = 0

    def on_score(self, msg, now_ns: int) -> None:
        self.board.add(msg, stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec))
        self.dropped_blocks = sum(r.dropped_blocks for r in self.board.rows())

    def on_diagnostics(self, msg, now_ns: int) -> None:
        for st in msg.status:
            values = [(kv.key, kv.value) for kv in st.values]
            self.nodes.add(st.name, st.hardware_id, level_of(st), st.message, values, now_ns)
            self.counters[st.name] = dict(values)
            for key, value in values:
                if key in ('pairs', 'messages') or key.startswith('/'):
                    try:
                        count = int(value)
                    except ValueError:
                        continue
                    self.rates.setdefault((st.name, key), CounterRate()).add(now_ns, count)

    def on_health(self, msg, now_ns: int) -> None:
        self.health = (now_ns, msg)

    def _counter(self, prefix: str, key: str):
        for name, values in self.counters.items():
            if name.startswith(prefix) and key in values:
                return name, values[key]
        return None, None

    def _rate(self, prefix: str, key: str) -> float:
        name, _ = self._counter(prefix, key)
        rate = self.rates.get((name, key))
        return rate.rate_hz if rate is not None else math.nan

    def health_line(self, now_ns: int) -> str:
        if self.health is not None and now_ns - self.health[0] < 3 * NS_PER_S:
            h = self.health[1]
            parts = []
            shown = sorted((t for t in h.topics if t.topic in HEALTH_TOPICS),
                           key=lambda t: HEALTH_TOPICS.index(t.topic))
            for t in shown:
                lat = ('latency n/a' if math.isnan(t.latency_p50_ms) else
                       f'latency {fmt(t.latency_p50_ms)}/{fmt(t.latency_p99_ms)} ms')
                rec = f', rec {t.recorded}' if t.recorded >= 0 else ''
                parts.append(f'{t.topic} {fmt(t.rate_hz, ".0f")}/s gaps {t.seq_gaps} NaN {t.nan_samples} {lat}{rec}')
            rec = f'recorder {h.recorder_messages} msgs' if h.recorder_messages >= 0 else 'no recorder'
            return 'health (monitor node): ' + ' | '.join(parts + [rec, f'{h.clients} Foxglove client(s)'])
        _, pairs = self._counter('correction:', 'pairs')
        _, nan = self._counter('correction:', 'nan_samples')
        _, events = self._counter('correction:', 'events')
        _, recorded = self._counter('recorder:', 'messages')
        _, force_rec = self._counter('recorder:', '/force')
        parts = [f"/force {fmt(self._rate('recorder:', '/force'), '.0f')}/s"
                 + (f' (rec {force_rec})' if force_rec is not None else ''),
                 f"/force_corrected {fmt(self._rate('correction:', 'pairs'), '.0f')}/s"
                 + (f' ({pairs} blocks)' if pairs is not None else ''),
                 f"gaps {self.dropped_blocks} (dropped blocks in scored pulls), stream events {events or 0}",
                 f'NaN {nan or 0}',
                 'latency n/a (needs the monitor node)',
                 f'recorder {recorded} msgs' if recorded is not None else 'no recorder']
        return 'health (node heartbeats): ' + ' | '.join(parts)


def _pct_cell(value: float, grade: str):
    from rich.text import Text
    return Text(fmt(value), style=COLOURS.get(grade, 'dim'), justify='right')


def _num(value: float):
    from rich.text import Text
    return Text(fmt(value), justify='right')


def _peak_cell(peak: float, u: float):
    """'750.0 +/- 6.0': a corrected peak and its expanded uncertainty (the peak alone while U is not known)."""
    from rich.text import Text
    return Text(fmt(peak) + ('' if u is None or math.isnan(u) else f' +/- {fmt(u)}'), justify='right')


def make_app():
    from rich.text import Text
    from textual.app import App, ComposeResult
    from textual.widgets import DataTable, Static

    class ScoreboardApp(App):
        """The scoreboard. ``feed`` is a queue of (kind, message, arrival ns) from RosFeed (or a test)."""

        CSS = ('DataTable { height: auto; max-height: 16; } #sets { max-height: 8; } '
               '.title { text-style: bold; } #health { height: auto; }')
        BINDINGS = [('q', 'quit', 'quit')]

        def __init__(self, model: MonitorModel, feed: queue.SimpleQueue, exit_after: float | None = None,
                     status=None, done=None, linger_s: float = 3.0):
            """status() -> a line to show (what a driving command is doing); done() -> True once it
            has finished: the app then quits linger_s later."""
            super().__init__()
            self.model = model
            self.feed = feed
            self.exit_after = exit_after
            self.status, self.done, self.linger_s = status, done, linger_s
            self._quitting = False

        def compose(self) -> ComposeResult:
            yield Static(f'force tester scoreboard: % difference |F_stat - F| / F_stat at the peaks; green <= '
                         f'{self.model.board.threshold_pct:g} %, yellow <= {2 * self.model.board.threshold_pct:g} %, '
                         f'red above; q quits', id='title', classes='title')
            yield DataTable(id='pulls', show_cursor=False)
            yield Static('per set, OK pulls (thesis Tables 8-9): running mean +/- sample std', classes='title')
            yield DataTable(id='sets', show_cursor=False)
            yield Static('health: waiting for the graph', id='health')
            yield DataTable(id='nodes', show_cursor=False)
            yield Static('', id='status')

        def on_mount(self) -> None:
            for tid, cols in (('#pulls', PULL_COLUMNS), ('#sets', SET_COLUMNS), ('#nodes', NODE_COLUMNS)):
                self.query_one(tid, DataTable).add_columns(*cols)
            self.set_interval(REFRESH_S, self.refresh_view)
            if self.exit_after is not None:
                self.set_timer(self.exit_after, self.exit)

        def drain(self) -> int:
            handlers = {'score': self.model.on_score, 'diagnostics': self.model.on_diagnostics,
                        'health': self.model.on_health}
            n = 0
            while True:
                try:
                    kind, msg, now_ns = self.feed.get_nowait()
                except queue.Empty:
                    return n
                handlers[kind](msg, now_ns)
                n += 1

        def refresh_view(self) -> None:
            self.drain()
            if self.status is not None:
                self.query_one('#status', Static).update(self.status())
            if self.done is not None and not self._quitting and self.done():
                self._quitting = True
                self.set_timer(self.linger_s, self.exit)
            now = time.time_ns()
            board = self.model.board
            pulls = self.query_one('#pulls', DataTable)
            pulls.clear()
            for r in board.rows(last=PULL_ROWS):
                g = board.grades(r)
                status = Text(r.status, style='green' if r.status == 'OK' else 'yellow')
                pulls.add_row(str(r.pull_id), str(r.test_set), status, _num(r.stationary_lbf), _num(r.raw_lbf),
                              _peak_cell(r.corrected_lbf, r.corrected_u_lbf), _num(r.filtered_lbf),
                              *(_pct_cell(getattr(r, f'{k}_pct'), g[k]) for k in DIFF_KINDS))
            sets = self.query_one('#sets', DataTable)
            sets.clear()
            for s in board.sets():
                cells = []
                for k in DIFF_KINDS:
                    mean, std = getattr(s, f'{k}_mean_pct'), getattr(s, f'{k}_std_pct')
                    cells.append(Text(f'{fmt(mean)} +/- {fmt(std)}', justify='right',
                                      style=COLOURS.get(grade(mean, board.threshold_pct), 'dim')))
                sets.add_row(str(s.set_id), str(s.pulls), _num(n_to_lbf(s.mean_stationary_peak_n)), *cells)
            self.query_one('#health', Static).update(self.model.health_line(now))
            nodes = self.query_one('#nodes', DataTable)
            nodes.clear()
            for st in self.model.nodes.states(now):
                nodes.add_row(st.name, Text(LEVEL_NAMES.get(st.level, str(st.level)),
                                            style=LEVEL_COLOURS.get(st.level, '')),
                              st.message[:70], f'{st.age_s:.1f}')

    return ScoreboardApp


class RosFeed:
    """An rclpy node on its own thread: /pull_score, /diagnostics and /monitor/health go into ``queue``.
    Reliable subscriptions for scores (latched: a late start still gets them) and diagnostics; best
    effort for /monitor/health, which matches a publisher of either reliability."""

    def __init__(self, feed: queue.SimpleQueue):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from force_tester_msgs.msg import MonitorHealth, PullScore
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from force_tester_common.ros import EVENT_QOS, SCORE_QOS
        self.context = rclpy.Context()
        rclpy.init(args=['ft_monitor'], context=self.context)
        self.node = rclpy.create_node('ft_monitor', context=self.context)

        def put(kind):
            return lambda msg: feed.put((kind, msg, time.time_ns()))
        self.node.create_subscription(PullScore, PULL_SCORE_TOPIC, put('score'), SCORE_QOS)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, put('diagnostics'), EVENT_QOS)
        self.node.create_subscription(MonitorHealth, MONITOR_HEALTH_TOPIC, put('health'),
                                      QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, name='ft-monitor-ros', daemon=True)
        self.thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
        self.thread.join(timeout=2.0)


def run(args) -> int:
    feed = queue.SimpleQueue()
    ros = RosFeed(feed)
    try:
        app = make_app()(MonitorModel(args.threshold), feed, exit_after=args.exit_after)
        app.run()
    finally:
        ros.close()
    return 0

