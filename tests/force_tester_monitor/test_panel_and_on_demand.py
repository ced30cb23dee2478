"""Acceptance: Foxglove's Parameters panel and on-demand topics, through the real npm client
(@foxglove/ws-protocol) against a monitor and a correction node running as processes.

- The panel reads every node's parameters, and a value it sets reaches the node. JSON has one
  number type, so a float parameter set to a whole number arrives as an integer; the node must get
  a float.
  A value the node refuses leaves the node as it was, and the monitor reports the refusal.
- /motor, /encoder and /accel are subscribed only while a client watches them: ROS's own graph shows the
  monitor's subscription appear with the client and go with it.
"""
import subprocess

import pytest
from fox_client import client_command, lines, monitor_port

from force_tester_common.core.correction import WINDOW, WINDOW_RANGE
from ft_cli.graph import Graph, ScoreCollector

pytestmark = pytest.mark.slow


def _node_value(collector, client, name: str):
    future = client.get_parameters([name])
    collector.executor.spin_until_future_complete(future, timeout_sec=30)
    return future.result().values[0]


def _panel_parameters(port: int) -> dict:
    r = subprocess.run(client_command(port, '--get-params', '--timeout', '30'), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
    replies = [x for x in lines(r.stdout) if x['kind'] == 'parameters' and x['id'] == 'get']
    return {p['name']: p['value'] for p in replies[0]['parameters']}


def test_the_parameters_panel_reads_and_sets_and_raw_topics_are_watched_on_demand(tmp_path, ros_domain):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
    from rclpy.parameter_client import AsyncParameterClient

    from force_tester_common.ros import EVENT_QOS
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    node = collector.node
    monitor_warnings = []
    node.create_subscription(
        DiagnosticArray, '/diagnostics',
        lambda m: monitor_warnings.extend(s.message for s in m.status
                                          if s.name.startswith('monitor') and s.level == DiagnosticStatus.WARN),
        EVENT_QOS)
    watcher = None
    try:
        graph.start('force_correction', 'correction_node')
        monitor = graph.start('force_tester_monitor', 'monitor_node', {'port': 0})
        port = monitor_port(graph.log_dir / 'monitor_node.log', monitor)
        assert collector.wait_for_graph({'/force': 2, '/force_corrected': 1}, timeout=60)

        # on demand: nobody watches /motor, /encoder or /accel yet (the correction reads /accel)
        assert node.count_subscribers('/motor') == 0 and node.count_subscribers('/encoder') == 0
        assert node.count_subscribers('/accel') == 1
        watcher = subprocess.Popen(client_command(port, '--topics', '/motor', '--timeout', '120'),
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        assert collector.spin_until(lambda: node.count_subscribers('/motor') == 1, 60)
        assert node.count_subscribers('/encoder') == 0
        watcher.kill()
        watcher.wait()
        assert collector.spin_until(lambda: node.count_subscribers('/motor') == 0, 60), \
            'the monitor kept /motor after its only client left'

        # the panel reads the correction node's parameters (the monitor fetches them: it started after)
        params = {}

        def panel_has_correction():
            params.update(_panel_parameters(port))
            return '/correction.window' in params
        assert collector.spin_until(panel_has_correction, 60), sorted(params)
        correction = AsyncParameterClient(node, '/correction')
        assert correction.wait_for_services(timeout_sec=30)
        assert params['/correction.window'] == _node_value(collector, correction, 'window').integer_value == WINDOW
        assert params['/correction.mass_kg'] == pytest.approx(_node_value(collector, correction, 'mass_kg')
                                                              .double_value, rel=1e-15)

        # a set from the panel reaches the node; a whole number for a float parameter (JSON 2, as the
        # panel sends "2.0") arrives as a float, not refused as an integer
        wanted = WINDOW + 7
        r = subprocess.run(client_command(port, '--set-param', f'/correction.window={wanted}', '--timeout', '60'),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:])
        assert _node_value(collector, correction, 'window').integer_value == wanted
        r = subprocess.run(client_command(port, '--set-param', '/correction.mass_kg=2', '--timeout', '60'),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-2000:], monitor_warnings)
        assert _node_value(collector, correction, 'mass_kg').double_value == 2.0

        # a refused set: the node keeps its value and the monitor says so
        bad = WINDOW_RANGE[1] + 1
        r = subprocess.run(client_command(port, '--set-param', f'/correction.window={bad}', '--timeout', '5'),
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 3, r.stdout[-2000:]  # the panel never saw the value it asked for
        assert _node_value(collector, correction, 'window').integer_value == wanted
        assert collector.spin_until(lambda: any('refused by /correction' in m and str(bad) in m
                                                  for m in monitor_warnings), 30), monitor_warnings
        assert monitor.poll() is None
    finally:
        if watcher is not None and watcher.poll() is None:
            watcher.kill()
            watcher.wait()
        codes = graph.stop()
        collector.close()
    assert codes['monitor_node'] == 0, graph.tail('monitor_node')
