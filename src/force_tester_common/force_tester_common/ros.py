"""QoS profiles, diagnostics and the main() pattern shared by the force tester nodes."""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from typing import NamedTuple

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .core.channels import DIAGNOSTICS_TOPIC
from .core.clock import seconds_to_ns
from .core.health import HEARTBEAT_S, HOLD_S, hardware_id_of
from .node_params import ParameterError

# 10 s of 1 ms blocks: a receiver may stall that long without a block being overwritten.
BLOCK_QOS = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
EVENT_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# /pull_score: the history of scores is kept for late joiners (a monitor started after a pull still
# gets its score; `ros2 topic echo /pull_score --qos-durability transient_local --qos-depth 1000`).
SCORE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Latched, the newest message only (as /tf_static, /map): a late joiner that asks for one message
# (`ros2 topic echo --once`) gets the current one, not one of a backlog.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
SUMMARY_QOS = LATCHED_QOS        # a set summary is cumulative: the current one only, not a backlog
LATEST_SCORE_QOS = LATCHED_QOS   # /pull_score_latest: the newest score

# How a node process spins its nodes: $FT_EXECUTOR (make_executor). ./ft bench rigs compares them.
EXECUTOR_ENV = 'FT_EXECUTOR'
EXECUTORS = ('single', 'multi', 'events')
DEFAULT_EXECUTOR = 'events'

OK, WARN, ERROR = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR


def steady_timer(node, period_s: float, callback):
    """A housekeeping timer (heartbeat, topic discovery, flushing, ticks) on the steady clock, so it runs whatever
    the node's clock: with use_sim_time:=true and no /clock, a timer on the node's ROS clock never fires (no
    heartbeat went out and a recorder recorded nothing)."""
    return node.create_timer(period_s, callback, clock=Clock(clock_type=ClockType.STEADY_TIME))


class Diagnostics:
    """Publishes diagnostic_msgs/DiagnosticArray on /diagnostics and mirrors it to the node's log.

    Status name ``"<node>: <what>"`` (diagnostic_updater's convention), hardware_id the node's namespace
    without its leading slash: the rig it serves, empty in the root namespace. Viewers show a row as
    ``"<hardware_id>: <name>"`` (Foxglove) or group by hardware_id (rqt_robot_monitor), so a row reads
    ``validator: pull scoring``, or ``rig_b: validator: pull scoring`` for the validator of rig_b.
    Besides the reports a node makes on events, a heartbeat every ``period_s`` (HEARTBEAT_S, 1 Hz; the
    recorder 2 Hz) repeats the node's state with ``counters()`` as key/values, so a viewer never marks a
    healthy node STALE.
    The heartbeat's level is the worst report of the last HOLD_S seconds (OK when there was none),
    or, for good, that of a report made with ``latch=True`` (a condition that lasts, like a stopped
    simulation). Its message is that report's, else the last OK report's.

    Reports given a ``key`` are throttled to one per ``interval_s`` per key; the next one that
    goes out says how many were held back, so a flood of bad blocks cannot stall the node.
    """

    def __init__(self, node, name: str, interval_s: float = 1.0, counters=None, period_s: float = HEARTBEAT_S):
        self._node = node
        self._name = f'{node.get_name()}: {name}'
        self._pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, EVENT_QOS)
        self._interval_ns = seconds_to_ns(interval_s)
        self._hold_ns = seconds_to_ns(HOLD_S)
        self._last = {}  # key -> (last report ns, reports held back since)
        self._counters = counters
        self._state = 'running'       # message of the last OK report
        self._problem = None          # (level, message, monotonic ns) of the worst recent report
        self._latched = None          # (level, message) of a lasting condition
        steady_timer(node, period_s, self.heartbeat)

    def report(self, level: int, message: str, log: bool = True, key=None, latch: bool = False,
               **values) -> None:
        now = time.monotonic_ns()
        if key is not None:
            last, held = self._last.get(key, (None, 0))
            if last is not None and now - last < self._interval_ns:
                self._last[key] = (last, held + 1)
                return
            self._last[key] = (now, 0)
            if held:
                message = f'{message} ({held} similar report(s) held back in the last second)'
                values['held_back'] = held
        if level == OK:
            self._state = message
        elif latch:
            if self._latched is None or level >= self._latched[0]:
                self._latched = (level, message)
        elif self._problem is None or level >= self._problem[0] or now - self._problem[2] >= self._hold_ns:
            self._problem = (level, message, now)
        if log:
            logger = self._node.get_logger()  # rclpy wants one severity per call site
            if level == OK:
                logger.info(message)
            elif level == WARN:
                logger.warning(message)
            else:
                logger.error(message)
        self._publish(level, message, values)

    def heartbeat(self) -> None:
        """Publish the node's current state with its counters (the timer calls this)."""
        level, message = OK, self._state
        if self._problem is not None and time.monotonic_ns() - self._problem[2] < self._hold_ns:
            level, message = self._problem[:2]
        if self._latched is not None and self._latched[0] >= level:
            level, message = self._latched
        self._publish(level, message, dict(self._counters()) if self._counters is not None else {})

    def _publish(self, level: int, message: str, values: dict) -> None:
        status = DiagnosticStatus(level=level, name=self._name, message=message,
                                  hardware_id=hardware_id_of(self._node.get_namespace()),
                                  values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(arr)


def _init(args):
    """rclpy.init(args=...), quiet when it fails: rcl logs "Failed to parse global arguments" before
    it raises, and the error (startup_failure) is the one line a node prints."""
    from rclpy.logging import LoggingSeverity, set_logger_level
    set_logger_level('rcl', LoggingSeverity.FATAL)
    try:
        ret = rclpy.init(args=args)
    finally:
        if not any('rcl:=' in str(a) for a in (sys.argv if args is None else args)):   # --log-level rcl:=...
            set_logger_level('rcl', LoggingSeverity.UNSET)
    return ret


@contextlib.contextmanager
def ros_init(args=None):
    """``with rclpy.init(args=...)``: Kilted's init() is a context manager; Jazzy's returns None."""
    ret = _init(args)
    if ret is not None:
        with ret:
            yield
        return
    try:
        yield
    finally:
        rclpy.try_shutdown()


def make_executor(kind: str | None = None, context=None):
    """The executor ``kind`` names (EXECUTORS; default: $FT_EXECUTOR, else DEFAULT_EXECUTOR)."""
    kind = kind or os.environ.get(EXECUTOR_ENV) or DEFAULT_EXECUTOR
    if kind not in EXECUTORS:
        raise ParameterError(f'executor {kind!r} (${EXECUTOR_ENV}) is unknown; expected one of {", ".join(EXECUTORS)}')
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    return (MultiThreadedExecutor if kind == 'multi' else SingleThreadedExecutor)(context=context)


SHUTDOWN_TIMEOUT_S = 5.0   # an executor's shutdown waits at most this long for callbacks in progress


def spin(executor, poll_s: float = 0.5, ok=rclpy.ok) -> None:
    """Spin until the context shuts down (Ctrl-C, SIGTERM, rclpy.shutdown()).

    The EventsExecutor of the Jazzy wheels (rclpy 7.1.6) is spun with spin_once(timeout): its
    spin() busy-waits on one core, runs no callback and ignores Ctrl-C
    (benchmarks/events_executor_spin.py reproduces it). spin_once returns after each callback or
    ``poll_s``; the loop ends when the context shuts down or on SIGINT/SIGTERM (in the main
    thread), within ``poll_s``. ok: the context's ok()."""
    if isinstance(executor, (SingleThreadedExecutor, MultiThreadedExecutor)):
        executor.spin()
        return
    # Ctrl-C and SIGTERM only ask the loop to stop: a KeyboardInterrupt raised inside a callback
    # that the EventsExecutor runs from C++ cannot propagate there, and aborts the process
    # (SIGABRT, "terminate called after throwing ... KeyboardInterrupt").
    stop = []
    handled = (signal.SIGINT, signal.SIGTERM) if threading.current_thread() is threading.main_thread() else ()
    previous = {sig: signal.signal(sig, lambda signum, _frame: stop.append(signum)) for sig in handled}
    try:
        while ok() and not stop:
            try:
                executor.spin_once(timeout_sec=poll_s)
            except Exception:
                # a callback that raced the shutdown (a heartbeat publishing on the closed context of a
                # node that shut itself down) is the end of spinning, not a crash
                if ok():
                    raise
                return
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def release(executor, nodes) -> None:
    """Take the nodes out of the executor and shut it down before destroying them: destroying a
    node's entities while an executor still holds them can crash or hang the process (rclpy
    issues #260 and #1644, the latter for the EventsExecutor)."""
    for node in nodes:
        try:
            executor.remove_node(node)
        except Exception:  # noqa: BLE001, S110 - the context may already be shut down
            pass
    try:
        executor.shutdown(timeout_sec=SHUTDOWN_TIMEOUT_S)
    except Exception:  # noqa: BLE001, S110 - idem
        pass
    for node in nodes:
        node.destroy_node()


class StartupFailure(NamedTuple):
    """How a node process that failed to start ends: its exit code and its one line."""

    code: int
    line: str


def startup_failure(exc: BaseException) -> StartupFailure:
    """The exit code and one line for an error raised while a node process starts: 2 for bad input
    (ParameterError, and the packages' own error types, which are ValueErrors), 1 for anything
    else (an I/O failure, rclpy refusing its --ros-args). The line quotes the error's message,
    on one line, with its type when that is not one of ours."""
    text = ' '.join(str(exc).split())
    if isinstance(exc, (ParameterError, ValueError, OSError)) and text:
        line = text
    else:
        line = f'{type(exc).__name__}: {text}' if text else type(exc).__name__
    return StartupFailure(2 if isinstance(exc, ValueError) else 1, line)


def _close(node) -> None:
    close = getattr(node, 'close', None)
    if close is not None:
        close()


def spin_nodes(*node_factories, args=None) -> int:
    """Create the nodes in one process, add them to one executor (make_executor) and spin until
    shut down. Any error while the process starts (rclpy.init refusing the --ros-args, an invalid
    parameter, a bag directory that cannot be made) ends it with one line on stderr and a non-zero
    exit (startup_failure). A node that stops itself for good sets ``failure`` (an exception) and
    shuts the context down: the process ends the same way."""
    prog = os.path.basename(sys.argv[0])
    started, failure = False, None
    try:
        with ros_init(args):
            ex = make_executor()
            nodes = []
            try:
                for factory in node_factories:
                    nodes.append(factory())
            except BaseException:
                for node in nodes:   # those made before the one that failed
                    _close(node)
                    node.destroy_node()
                raise
            started = True
            for node in nodes:
                ex.add_node(node)
            try:
                spin(ex)
            finally:
                for node in nodes:   # first what matters: a node's data (the recorder's bag) is closed
                    _close(node)
                release(ex, nodes)
            failure = next((n.failure for n in nodes if getattr(n, 'failure', None) is not None), None)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:  # noqa: BLE001 - while starting, whatever it is: one line
        if started:
            raise
        failure = exc
    if failure is None:
        return 0
    code, line = startup_failure(failure)
    print(f'{prog}: error: {line}', file=sys.stderr)
    return code


def main_for(node_factory):
    """A console-script main() for one node class."""
    def main(args=None):
        sys.exit(spin_nodes(node_factory, args=args))
    return main


def in_namespace(topic: str) -> str:
    """A graph topic's name as a node creates it: relative, so that it resolves in the node's
    namespace (``/force`` in the root namespace; ``/rig1/force`` under ``-r __ns:=/rig1``).
    /diagnostics and /parameter_events stay absolute: one for the whole machine, as ROS tools expect."""
    return topic.lstrip('/')


def guarded(diag: Diagnostics, topic: str, callback):
    """A subscription callback that never kills the node: an exception from ``callback`` (a
    message no check foresaw) is reported on /diagnostics, throttled, and the message dropped."""
    def run(msg):
        try:
            callback(msg)
        except Exception as exc:  # noqa: BLE001 - anything on a topic is input from outside
            diag.report(ERROR, f'message on {topic} dropped: {type(exc).__name__}: {exc}',
                        key=('exception', topic), topic=topic)
    return run


def qos_watch(diag: Diagnostics, topic: str) -> SubscriptionEventCallbacks:
    """Subscription event callbacks that report a publisher whose QoS cannot match ours (for
    example best effort on a reliable topic: DDS then delivers nothing from it) or whose type
    differs, instead of the silence DDS gives."""
    def incompatible_qos(info):
        diag.report(ERROR, f'a publisher on {topic} offers a QoS incompatible with this subscription '
                           f'(policy {info.last_policy_kind.name}, {info.total_count} so far); its messages are '
                           f'not received: publish with the QoS of the workspace (RELIABLE, KEEP_LAST)',
                    key=('qos', topic), topic=topic, policy=info.last_policy_kind.name)

    def incompatible_type(info):
        diag.report(ERROR, f'a publisher on {topic} has another message type ({info.total_count} so far); '
                           'its messages are not received', key=('type', topic), topic=topic)
    return SubscriptionEventCallbacks(incompatible_qos=incompatible_qos, incompatible_type=incompatible_type)
