"""./ft demo: the live graph over DDS, one pull of each test set, recorded to an MCAP bag.

Starts the correction, validator and recorder nodes and then the sim node as separate
processes (exactly what `./ft run PKG EXE` starts), collects the validator's /pull_score
messages in this process, stops everything with SIGINT (the recorder then closes the bag) and
prints a per-set table.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from ft_cli import ROOT, executable

N_PER_LBF = 4.4482216152605
FPS_PER_M_S = 1 / 0.3048
SCORE_FIELDS = ('pull_id', 'test_set', 'stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
                'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'raw_rms_n', 'corrected_rms_n',
                'filtered_rms_n', 'dropped_blocks')


def add_arguments(p):
    p.add_argument('--sets', nargs='+', type=int, default=[1, 2, 3, 4, 5], metavar='SET',
                   help='test sets to run (thesis Table 4; default: 1 2 3 4 5)')
    p.add_argument('--pulls', type=int, default=1, help='pulls per set (default 1)')
    p.add_argument('--seed', type=int, default=0, help='seed of the scatter and the noise (default 0)')
    p.add_argument('--rate', type=float, default=1.0, help='sim pace, real-time factor (default 1.0)')
    p.add_argument('--rig', default='truth', metavar='RIG',
                   help="'truth' (default: the reference rig, which departs from the datasheet like the thesis's "
                        "real rig, with coupons at their measured levels), 'nominal' (the datasheet rig, coupons "
                        "at their rating) or a rig YAML file")
    p.add_argument('--out', default=str(ROOT / 'runs' / 'demo'),
                   help='output folder: bag/, scores.json, logs/ (default runs/demo; replaced)')
    p.add_argument('--timeout', type=float, default=120.0, help='give up after this many seconds')


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

    def start(self, package: str, name: str, params: dict | None = None, extra: list | None = None):
        exe = executable(package, name)
        log = open(self.log_dir / f'{name}.log', 'w')
        cmd = [str(exe), *(extra or []), *ros_param_args(params or {})]
        self.procs[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        return self.procs[name]

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

    def __init__(self):
        import rclpy
        from force_tester_common.ros import SCORE_QOS
        from force_tester_msgs.msg import PullScore
        from rclpy.executors import SingleThreadedExecutor
        rclpy.init(args=['ft_demo'])
        self.node = rclpy.create_node('ft_demo')
        self.scores = []
        self.recorded = []  # (time, {key: value}) from the recorder's progress reports
        self.node.create_subscription(PullScore, '/pull_score', self._on_score, SCORE_QOS)
        from diagnostic_msgs.msg import DiagnosticArray
        from force_tester_common.ros import EVENT_QOS
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      EVENT_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def wait_for_graph(self, subscribers: dict, timeout: float) -> bool:
        """Wait until each topic has the given number of subscribers (so no early block is lost)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(self.node.count_subscribers(t) >= n for t, n in subscribers.items()):
                return True
            self.executor.spin_once(timeout_sec=0.05)
        return False

    def _on_score(self, msg):
        self.scores.append({k: getattr(msg, k) for k in SCORE_FIELDS})

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
        deadline = time.monotonic() + timeout
        while len(self.scores) < n and time.monotonic() < deadline and alive():
            before = len(self.scores)
            self.executor.spin_once(timeout_sec=0.1)
            if progress and len(self.scores) > before:
                progress(self.scores[-1])
        return len(self.scores) >= n

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def format_table(scores: list) -> str:
    head = (f"{'set':>3} {'pulls':>5} {'stationary':>11} {'raw moving':>11} {'m*a corr.':>10} {'+ MA(140)':>10}"
            f" {'diff raw':>9} {'diff m*a':>9} {'diff MA':>8}\n"
            f"{'':>3} {'':>5} {'peak lbf':>11} {'peak lbf':>11} {'peak lbf':>10} {'peak lbf':>10}"
            f" {'%':>9} {'%':>9} {'%':>8}")
    rows = [head, '-' * 84]
    for s in sorted({sc['test_set'] for sc in scores}):
        group = [sc for sc in scores if sc['test_set'] == s]

        def mean(k):
            return sum(g[k] for g in group) / len(group)
        rows.append(f"{s:>3} {len(group):>5} {mean('stationary_peak_n') / N_PER_LBF:>11.1f} "
                    f"{mean('raw_peak_n') / N_PER_LBF:>11.1f} {mean('corrected_peak_n') / N_PER_LBF:>10.1f} "
                    f"{mean('filtered_peak_n') / N_PER_LBF:>10.1f} {mean('raw_diff_pct'):>9.1f} "
                    f"{mean('corrected_diff_pct'):>9.1f} {mean('filtered_diff_pct'):>8.1f}")
    dropped = sum(sc['dropped_blocks'] for sc in scores)
    rows.append(f'% difference is thesis eq 1 at the peaks: |F_stat - F| / F_stat; dropped blocks: {dropped}')
    return '\n'.join(rows)


def rig_params(rig: str) -> dict:
    """The sim node's rig_file and coupons parameters for --rig."""
    if rig == 'nominal':
        return {'rig_file': '', 'coupons': 'rated'}
    if rig == 'truth':
        from thesis_cmd import truth_rig_path
        return {'rig_file': str(truth_rig_path()), 'coupons': 'measured'}
    return {'rig_file': str(Path(rig).resolve()), 'coupons': 'measured'}


def run_live(out: Path, sets, pulls: int, seed: int, rate: float, timeout: float, say=print,
             rig: str = 'truth') -> list:
    """Run the graph, record out/bag, return the validator's scores (raises RuntimeError on failure)."""
    bag = out / 'bag'
    if bag.exists():
        shutil.rmtree(bag)
    out.mkdir(parents=True, exist_ok=True)
    graph = Graph(out / 'logs')
    collector = ScoreCollector()
    expected = len(sets) * pulls
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(bag)})
        collector.wait_for_graph({'/force_corrected': 2, '/force': 3, '/pull_event': 2}, timeout=30)
        graph.start('force_tester_sim', 'sim_node', {
            'test_sets': '[' + ','.join(str(s) for s in sets) + ']', 'pulls_per_set': pulls, 'seed': seed,
            'rate': float(rate), 'wait_for_subscribers': 3, 'exit_when_done': True, **rig_params(rig)})
        say(f'demo: {expected} pull(s) of 2 s at 50 kHz, sets {list(sets)}, {rig} rig; logs in {graph.log_dir}')
        ok = collector.wait(expected, timeout, alive=lambda: not graph.dead(),
                            progress=lambda sc: say(f"demo: scored pull {sc['pull_id'] + 1}/{expected} "
                                                    f"(set {sc['test_set']})"))
        if ok and not collector.wait_recorder_caught_up():  # it may lag behind on a busy machine
            say('demo: the recorder did not catch up within 30 s; stopping it anyway')
    finally:
        codes = graph.stop()
        collector.close()
    if not ok:
        dead = graph.dead() or ['sim_node']
        raise RuntimeError(f'only {len(collector.scores)} of {expected} pulls were scored; '
                           f'last lines of {dead[0]}:\n{graph.tail(dead[0])}')
    if codes.get('recorder_node') not in (0, -signal.SIGINT) or not (bag / 'metadata.yaml').is_file():
        raise RuntimeError(f'the recorder did not close the bag cleanly:\n{graph.tail("recorder_node")}')
    return sorted(collector.scores, key=lambda sc: sc['pull_id'])


def main(args) -> int:
    out = Path(args.out)
    t0 = time.monotonic()
    try:
        scores = run_live(out, args.sets, args.pulls, args.seed, args.rate, args.timeout,
                          say=lambda m: print(m, file=sys.stderr), rig=args.rig)
    except RuntimeError as exc:
        print(f'ft demo: error: {exc}', file=sys.stderr)
        return 1
    (out / 'scores.json').write_text(json.dumps(scores, indent=1))
    print(format_table(scores))
    print(f'bag: {out / "bag"}  (./ft bag info {os.path.relpath(out / "bag")})   scores: {out / "scores.json"}   '
          f'{time.monotonic() - t0:.1f} s')
    return 0
