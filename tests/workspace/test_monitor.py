"""./ft monitor, the terminal scoreboard: driven headless by Textual's pilot with real messages
(PullScore, DiagnosticArray, MonitorHealth), and once in tmux against a live graph, its screen read
back with capture-pane."""
import asyncio
import queue
import time

import pytest
from rich.text import Text

from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.units import n_to_lbf
from ft_cli.commands.monitor import MonitorModel, make_app


def pull_score(pull_id, test_set, stat_n, raw_pct, corr_pct, filt_pct, status=0, start_s=100):
    from force_tester_msgs.msg import PullScore
    m = PullScore(pull_id=pull_id, test_set=test_set, status=status, stationary_peak_n=stat_n,
                  raw_peak_n=stat_n * (1 + raw_pct / 100), corrected_peak_n=stat_n * (1 + corr_pct / 100),
                  filtered_peak_n=stat_n * (1 - filt_pct / 100), raw_diff_pct=raw_pct,
                  corrected_diff_pct=corr_pct, filtered_diff_pct=filt_pct)
    m.header.stamp.sec = start_s + 3 * pull_id
    return m


def diagnostics(name, level, message, **values):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    return DiagnosticArray(status=[DiagnosticStatus(
        level=level, name=name, message=message, hardware_id='/' + name.split(':')[0],
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])])


def cells(table):
    return [[c.plain if isinstance(c, Text) else str(c) for c in table.get_row_at(i)] for i in range(table.row_count)]


def run_pilot(feed, check, threshold=5.0):
    async def main():
        app = make_app()(MonitorModel(threshold), feed)
        async with app.run_test(size=(160, 50)) as pilot:
            deadline = time.monotonic() + 20
            while True:   # wait until the app has drawn what was fed (refresh every 0.5 s)
                await pilot.pause(0.1)
                try:
                    return check(app)
                except AssertionError:
                    if time.monotonic() > deadline:
                        raise
    return asyncio.run(main())


def test_pilot_shows_pulls_sets_health_and_nodes_from_real_messages():
    from diagnostic_msgs.msg import DiagnosticStatus
    from force_tester_msgs.msg import MonitorHealth, TopicHealth
    feed = queue.SimpleQueue()
    now = time.time_ns()
    scores = [pull_score(0, 1, 950.0, 14.0, 4.0, 1.0), pull_score(1, 1, 960.0, 16.0, 6.0, 3.0),
              pull_score(2, 3, 3300.0, 54.0, 12.0, 3.5), pull_score(3, 3, 3310.0, 50.0, 9.0, 2.0, status=1)]
    for s in scores:
        feed.put(('score', s, now))
    fresh = now + 60 * NS_PER_S   # fresh for the whole test: on a loaded machine the app may draw after STALE_S
    feed.put(('diagnostics', diagnostics('sim: simulator', DiagnosticStatus.OK, 'publishing', pulls=4), fresh))
    feed.put(('diagnostics', diagnostics('validator: validator', DiagnosticStatus.WARN, 'pull 3 INCOMPLETE'), fresh))
    feed.put(('diagnostics', diagnostics('correction: inertial correction', DiagnosticStatus.OK, 'x', pairs=9),
              now - 10 * NS_PER_S))   # its last report long ago: STALE
    health = MonitorHealth(window_s=2.0, recorder_messages=12345, recorder_report_age_s=0.3, clients=1, topics=[
        TopicHealth(topic='/force', received=4000, rate_hz=1000.0, seq_gaps=2, nan_samples=5,
                    latency_p50_ms=1.25, latency_p99_ms=4.5, recorded=3999),
        TopicHealth(topic='/diagnostics', received=9, rate_hz=5.0, latency_p50_ms=1.0, latency_p99_ms=1.0)])
    feed.put(('health', health, time.time_ns() + 60 * NS_PER_S))   # fresh for the whole test

    def check(app):
        pulls = cells(app.query_one('#pulls'))
        assert len(pulls) == 4
        assert pulls[2][:3] == ['2', '3', 'OK']
        assert pulls[2][3] == f'{n_to_lbf(3300.0):.1f}' and pulls[2][4] == f'{n_to_lbf(3300.0 * 1.54):.1f}'
        assert pulls[2][7:] == ['54.0', '12.0', '3.5']
        assert pulls[3][2] == 'INCOMPLETE'
        row = app.query_one('#pulls').get_row_at(2)
        assert [c.style for c in row[7:]] == ['bold red', 'bold red', 'green']   # 54 %, 12 % > 2 x 5 %; 3.5 %
        assert app.query_one('#pulls').get_row_at(0)[8].style == 'green'         # 4 %
        assert app.query_one('#pulls').get_row_at(1)[8].style == 'yellow'        # 6 %
        sets = cells(app.query_one('#sets'))
        # set 1: 14 and 16 -> 15 +/- 1.41; set 3: the OK pull only
        assert sets[0][:2] == ['1', '2'] and sets[0][3] == '15.0 +/- 1.4' and sets[0][4] == '5.0 +/- 1.4'
        assert sets[1][:2] == ['3', '1'] and sets[1][3] == '54.0 +/- 0.0'
        health_text = str(app.query_one('#health').render())
        assert 'monitor node' in health_text and '/force 1000/s gaps 2 NaN 5 latency 1.2/4.5 ms' in health_text
        assert 'recorder 12345 msgs' in health_text and '/diagnostics' not in health_text   # block topics only
        nodes = {r[0]: r[1] for r in cells(app.query_one('#nodes'))}
        assert nodes == {'sim: simulator': 'OK', 'validator: validator': 'WARN',
                         'correction: inertial correction': 'STALE'}
        return True
    assert run_pilot(feed, check)


def test_pilot_health_from_heartbeats_without_the_monitor_node():
    from diagnostic_msgs.msg import DiagnosticStatus
    feed = queue.SimpleQueue()
    t0 = time.time_ns()
    for k in range(3):   # three heartbeats one second apart: 1000 pairs/s, recorder 1000 /force/s
        t = t0 - (2 - k) * NS_PER_S
        feed.put(('diagnostics', diagnostics('correction: inertial correction', DiagnosticStatus.OK, 'running',
                                             pairs=1000 * k, nan_samples=3, events=0), t))
        feed.put(('diagnostics', diagnostics('recorder: bag recorder', DiagnosticStatus.OK, 'recording',
                                             messages=5000 * k, **{'/force': 1000 * k}), t))
    feed.put(('score', pull_score(0, 2, 2600.0, 30.0, 8.0, 4.0), t0))
    feed.put(('score', pull_score(1, 2, 2600.0, 30.0, 8.0, 4.0, status=1), t0))
    feed.put(('score', pull_score(1, 2, 2600.0, 30.0, 8.0, 4.0, status=1), t0))   # delivered twice

    def check(app):
        text = str(app.query_one('#health').render())
        assert 'node heartbeats' in text and '/force 1000/s (rec 2000)' in text
        assert '/force_corrected 1000/s (2000 blocks)' in text and 'NaN 3' in text
        assert 'recorder 10000 msgs' in text and 'latency n/a' in text
        assert len(cells(app.query_one('#pulls'))) == 2
        return True
    assert run_pilot(feed, check)


@pytest.mark.slow
def test_in_tmux_against_a_live_graph(tmp_path, ros_domain):
    """`./ft monitor` in a tmux pane on a real graph (sim, correction, validator, recorder as
    processes): the screen read back shows the pull's score as the validator published it, and the
    nodes alive."""
    import os
    import re
    import shutil
    import subprocess

    from ft_cli.graph import Graph, ScoreCollector
    from ft_cli.paths import ROOT
    if shutil.which('tmux') is None:
        pytest.fail('tmux is not installed; the scoreboard smoke test needs it')
    sock = f'ft-monitor-test-{os.getpid()}'
    tmux = ['tmux', '-L', sock]
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    screen = ''

    def capture():
        return subprocess.run([*tmux, 'capture-pane', '-p', '-t', 'mon'], capture_output=True, text=True).stdout
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(tmp_path / 'bag')})
        env = ' '.join(f'{k}={os.environ[k]}' for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE'))
        # without xdist's COLUMNS=80 LINES=24, which the tmux server inherits from this worker: Textual takes them
        # over the pane's size (bash refreshed them only after an external command, which ./ft no longer runs)
        subprocess.run([*tmux, 'new-session', '-d', '-s', 'mon', '-x', '150', '-y', '45',
                        f'env -u COLUMNS -u LINES {env} {ROOT}/ft monitor --exit-after 300'], check=True)
        # the scoreboard is up when it subscribes to the scores (besides this test's collector)
        assert collector.wait_for_graph({'/force_corrected': 2, '/force': 3, '/pull_event': 2, '/pull_score': 2},
                                        timeout=90), capture()
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[2]', 'pulls_per_set': 1, 'rate': 1.0,
                                                      'wait_for_subscribers': 2})
        assert collector.wait(1, 120, alive=lambda: not graph.dead()), graph.tail('validator_node')
        (s,) = collector.scores
        want = [str(s['pull_id']), '2', 'OK', f"{n_to_lbf(s['stationary_peak_n']):.1f}",
                f"{n_to_lbf(s['raw_peak_n']):.1f}", f"{n_to_lbf(s['corrected_peak_n']):.1f}",
                '+/-', f"{n_to_lbf(s['corrected_peak_u_n']):.1f}",   # the corrected peak with its U (k = 2)
                f"{n_to_lbf(s['filtered_peak_n']):.1f}", f"{s['raw_diff_pct']:.1f}",
                f"{s['corrected_diff_pct']:.1f}", f"{s['filtered_diff_pct']:.1f}"]
        deadline = time.monotonic() + 30

        def shown(screen):
            rows = [line.split() for line in screen.splitlines()]
            states = dict(m.groups() for m in re.finditer(
                r'^\s*(sim|correction|validator|recorder): .*?\s{2,}(OK|WARN|ERROR|STALE)\s', screen, re.M))
            return want in [r[:12] for r in rows] and states == dict.fromkeys(
                ('sim', 'correction', 'validator', 'recorder'), 'OK')
        while not shown(screen := capture()) and time.monotonic() < deadline:
            time.sleep(0.25)
        (tmp_path / 'screen.txt').write_text(screen)
    finally:
        subprocess.run([*tmux, 'kill-server'], capture_output=True)
        graph.stop()
        collector.close()
    assert shown(screen), f'{want}\n{screen}'
    assert 'health (' in screen and 'recorder ' in screen


def test_demo_with_monitor_in_tmux(tmp_path, ros_domain):
    """`./ft demo --monitor` in a tmux pane: while it runs, the scoreboard shows the pull's row and
    the monitor node's health line; when the demo is done, the scoreboard closes and the demo's table
    is printed on the same terminal, and the exit code is 0."""
    import json
    import os
    import shutil
    import subprocess

    from ft_cli.paths import ROOT
    if shutil.which('tmux') is None:
        pytest.fail('tmux is not installed; the scoreboard smoke test needs it')
    sock = f'ft-demo-monitor-test-{os.getpid()}'
    tmux = ['tmux', '-L', sock]
    out = tmp_path / 'demo'
    env = ' '.join(f'{k}={os.environ[k]}' for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE'))

    def capture():
        return subprocess.run([*tmux, 'capture-pane', '-p', '-t', 'demo'], capture_output=True, text=True).stdout
    seen_live, screen = False, ''
    try:
        subprocess.run([*tmux, 'new-session', '-d', '-s', 'demo', '-x', '160', '-y', '50',
                        f'env -u COLUMNS -u LINES {env} {ROOT}/ft demo --monitor --sets 2 --pulls 1 --extension none '
                        f'--out {out}; '
                        f'echo DEMO EXIT $?; sleep 600'], check=True)
        deadline = time.monotonic() + 300
        while 'DEMO EXIT' not in screen and time.monotonic() < deadline:
            screen = capture()
            rows = [line.split() for line in screen.splitlines()]
            if 'health (monitor node)' in screen and any(r[1:3] == ['2', 'OK'] for r in rows if len(r) > 2):
                seen_live = True
                (tmp_path / 'live_screen.txt').write_text(screen)
            time.sleep(0.25)
        (tmp_path / 'final_screen.txt').write_text(screen)
    finally:
        subprocess.run([*tmux, 'kill-server'], capture_output=True)
    assert 'DEMO EXIT 0' in screen, screen
    assert seen_live, 'the scoreboard never showed the pull scored with the monitor node health line'
    (score,) = json.loads((out / 'scores.json').read_text())
    assert score['test_set'] == 2
    assert 'bag:' in screen and 'scores:' in screen  # the demo's table, printed after the scoreboard closed
