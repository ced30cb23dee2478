"""The live graph from outside: node processes started like `ros2 run`, and an rclpy node in this
process that collects what the graph publishes (scores, the recorder's progress)."""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

from force_tester_common.core.channels import DIAGNOSTICS_TOPIC, PULL_SCORE_TOPIC
from force_tester_common.core.scores import PULL_SCORE_FIELDS

from .paths import executable

SCORE_KEYS = ('pull_id', 'test_set', *PULL_SCORE_FIELDS, 'dropped_blocks')
STATUS_KEYS = ('status', 'detail')  # how far to trust a score, and why


def score_dict(msg) -> dict:
    """A PullScore message as a dict of SCORE_KEYS and STATUS_KEYS."""
    return {k: getattr(msg, k) for k in (*SCORE_KEYS, *STATUS_KEYS)}


def cpu_seconds(pid: int) -> float:
    """CPU seconds (user + system) a process has used so far, from /proc (its children not included)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def ros_param_args(params: dict) -> list:
    out = ['--ros-args']
    for k, v in params.items():
        if isinstance(v, bool):
            v = str(v).lower()
        out += ['-p', f'{k}:={v}']
    return out


class Graph:
    """Node processes started like `ros2 run`, each logging to its own file."""

    def __init__(self, log_dir: Path):
        self.log_dir = log_dir
        log_dir.mkdir(parents=True, exist_ok=True)
        self.procs = {}

    def start(self, package: str, name: str, params: dict | None = None, extra: list | None = None,
              key: str | None = None):
        """Start executable ``name``; ``key`` (default: name) names the process and its log, for a second
        instance of one executable."""
        exe = executable(package, name)
        key = key or name
        log = open(self.log_dir / f'{key}.log', 'a')  # a restarted node's log follows the first one's
        cmd = [str(exe), *(extra or []), *ros_param_args(params or {})]
        self.procs[key] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        return self.procs[key]

    def dead(self) -> list:
        return [n for n, p in self.procs.items() if p.poll() not in (None, 0)]

    def stop(self, timeout: float = 15.0) -> dict:
        for p in self.procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout
        codes = {}
        for name, p in self.procs.items():
            try:
                codes[name] = p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                codes[name] = p.wait()
        return codes

    def tail(self, name: str, n: int = 15) -> str:
        lines = (self.log_dir / f'{name}.log').read_text(errors='replace').splitlines()
        return '\n'.join(lines[-n:])


class ScoreCollector:
    """An rclpy node in this process that keeps every /pull_score message as a dict."""

    def __init__(self, also: tuple = ()):
        """also: more PullScore topics to keep (in ``also_scores[topic]``)."""
        import rclpy
        from force_tester_msgs.msg import PullScore
        from rclpy.executors import SingleThreadedExecutor

        from force_tester_common.ros import SCORE_QOS
        rclpy.init(args=['ft_demo'])
        self.node = rclpy.create_node('ft_demo')
        self.scores = []
        self.recorded = []  # (time, {key: value}) from the recorder's progress reports
        self.node.create_subscription(PullScore, PULL_SCORE_TOPIC, self._on_score, SCORE_QOS)
        self.also_scores = {topic: [] for topic in also}
        for topic, kept in self.also_scores.items():
            self.node.create_subscription(PullScore, topic, lambda msg, kept=kept: kept.append(score_dict(msg)),
                                          SCORE_QOS)
        from diagnostic_msgs.msg import DiagnosticArray

        from force_tester_common.ros import EVENT_QOS
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                      EVENT_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def spin_until(self, condition, timeout: float, poll_s: float = 0.05) -> bool:
        """Spin this node until condition() holds (True) or timeout seconds pass (condition() then)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            self.executor.spin_once(timeout_sec=poll_s)
        return condition()

    def wait_for_graph(self, subscribers: dict, timeout: float) -> bool:
        """Wait until each topic has the given number of subscribers (so no early block is lost)."""
        return self.spin_until(lambda: all(self.node.count_subscribers(t) >= n for t, n in subscribers.items()),
                               timeout)

    def _on_score(self, msg):
        self.scores.append(score_dict(msg))

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith('recorder:'):
                values = {kv.key: kv.value for kv in status.values}
                if 'messages' in values:
                    self.recorded.append((time.monotonic(), values))

    def wait_recorder_caught_up(self, quiet_s: float = 1.0, timeout: float = 30.0) -> bool:
        """Wait until the recorder has as many /force_corrected blocks as /force blocks (the
        correction node has caught up) and its message count has not changed for quiet_s (it
        has written everything published), at most timeout."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.1)
            if not self.recorded:
                continue
            now, values = time.monotonic(), self.recorded[-1][1]
            since = min(t for t, v in self.recorded if v['messages'] == values['messages'])
            if (values.get('/force_corrected') == values.get('/force')
                    and now - since >= quiet_s and now - self.recorded[-1][0] < quiet_s):
                return True
        return False

    def wait(self, n: int, timeout: float, alive=lambda: True, progress=None) -> bool:
        """Wait until n scores arrived on /pull_score and on every ``also`` topic."""
        deadline = time.monotonic() + timeout

        def short():
            return len(self.scores) < n or any(len(s) < n for s in self.also_scores.values())
        while short() and time.monotonic() < deadline and alive():
            before = len(self.scores)
            self.executor.spin_once(timeout_sec=0.1)
            if progress and len(self.scores) > before:
                progress(self.scores[-1])
        return not short()

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()
