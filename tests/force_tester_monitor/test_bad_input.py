"""Bad input to the monitor: a port already in use, and malformed messages from a Foxglove client.
(A client that never reads is in test_foxglove_client: it costs the graph no block.)"""
import socket
import subprocess
import time

import pytest
from fox_client import client_command, lines, monitor_port

from ft_cli.graph import Graph
from ft_cli.paths import executable

pytestmark = pytest.mark.slow


def test_a_port_in_use_gives_one_line_naming_it_and_a_nonzero_exit(ros_domain):
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run([str(executable('force_tester_monitor', 'monitor_node')), '--ros-args',
                            '-p', f'port:={port}'], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and f'port {port}' in err[0] and 'already in use' in err[0], r.stderr


def test_malformed_client_messages_are_ignored_and_logged_once(tmp_path, ros_domain):
    graph = Graph(tmp_path / 'logs')
    try:
        monitor = graph.start('force_tester_monitor', 'monitor_node', {'port': 0, 'health_period_s': 0.2})
        port = monitor_port(graph.log_dir / 'monitor_node.log', monitor)
        runs = [subprocess.run(client_command(port, '--malformed', '--topics', '/monitor/health',
                                              '--until', '/monitor/health=3', '--timeout', '60'),
                               capture_output=True, text=True, timeout=120) for _ in range(2)]
        log_file = graph.log_dir / 'monitor_node.log'
        deadline = time.monotonic() + 30   # the monitor's next pass logs what the server reported
        while 'reported once' not in log_file.read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert monitor.poll() is None
    finally:
        codes = graph.stop()
    assert codes['monitor_node'] == 0
    for r in runs:
        assert r.returncode == 0, r.stdout[-1000:]
        records = lines(r.stdout)
        # the server told the client, and went on serving it
        assert sum(1 for x in records if x['kind'] == 'status' and 'Invalid message' in x['message']) == 3
        assert sum(1 for x in records if x['kind'] == 'message') == 3
    log = (graph.log_dir / 'monitor_node.log').read_text()
    assert log.count('Invalid message') == 1, log
    assert 'reported once' in log
