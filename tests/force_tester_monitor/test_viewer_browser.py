"""Acceptance: the workspace's viewer (./ft view: Foxglove Studio 1.48.0 from @foxglove/studio-base) in a
real browser, headless Chromium (Debian's), on a live graph: sim, correction, validator and monitor as
separate processes over Fast DDS.

The viewer is served as ./ft view serves it and opened by its URL (the layout and the monitor's
WebSocket named in Studio's deep-link parameters). Once the validator has scored the pulls, the page
must show: no connection problem; the live plot's legend with numbers that change while the sim runs;
the score history with one row per scored pull, with the validator's numbers in display units; every
node of the graph in the diagnostics panel, OK, its row named "<node>: <what>". The
screenshot is saved under the test's tmp dir (viewer.png) for a person to look at. No request of the
page may leave the machine.

Then (issue 41), with five pulls, one of each set: no table row, pager or node row lies outside its panel at
1600x1000; the correction SIGKILLed is STALE within 5 s, and started again; the monitor SIGKILLed shows the
"no connection" bar within 5 s, and restarted on its port removes it; the page then shows every pull and every
set's statistics; a second page opened at 1366x768 after the last score shows all of it with nothing cut off
(viewer_1366x768.png); a late latched ROS reader gets /monitor/score_history.
"""
from __future__ import annotations

import time

import pytest
from browser_page import Page, chromium_binary, legend_values, table_rows
from fox_client import monitor_port

from force_tester_common.core.units import n_to_lbf
from ft_cli.commands import view
from ft_cli.graph import Graph, ScoreCollector

pytestmark = pytest.mark.browser

SETS = (1, 2, 3, 4, 5)             # one pull of each (thesis Table 4): the tables' fit, a restart's completeness
SIZES = ((1600, 1000), (1366, 768))   # the first page's, the late page's (both screenshots go to docs/images)
PULLS = len(SETS)
# each node's name in its /diagnostics status ("<node>: <what>"), as the diagnostics panel lists it
NODES = ('sim', 'correction', 'validator', 'monitor')
LIVE = 'Plot!livetrace'            # the layout's panels, by id
HISTORY = 'Table!history'


def node_rows(state: dict) -> dict:
    """{node: (message, OK?)} of the diagnostics panel's rows, by the node named first in the row."""
    rows = {}
    for row in state['diagnostics']:
        node = row['name'].split(':')[0].lstrip('/')
        rows[node] = (row['message'], bool(state['okColor']) and row['color'] == state['okColor'])
    return rows


FITTED = (HISTORY, 'Table!sets', 'DiagnosticSummary!diag')


def cut_off(state: dict) -> dict:
    """{panel: what of it lies outside it} for the tables and the Nodes tab: nothing may (issue 41)."""
    return {p['id']: p['outside'] for p in state['panels'] if p['id'] in FITTED and p['outside']}


def test_the_viewer_shows_the_live_graph_in_headless_chromium(tmp_path, ros_domain):
    chromium = chromium_binary()
    view.check_installed()
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    server = page = None
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        monitor = graph.start('force_tester_monitor', 'monitor_node', {'port': 0})
        port = monitor_port(graph.log_dir / 'monitor_node.log', monitor)
        server = view.serve('127.0.0.1', 0)
        url = view.url('127.0.0.1', server.server_address[1], f'ws://127.0.0.1:{port}')
        page = Page(url, chromium, SIZES[0])
        first = page.next(timeout=120)
        if first['kind'] == 'launch-failed':
            pytest.skip(f'Chromium ({chromium}) did not start: {first["error"]}')
        # the app is up and connected: it subscribed to the monitor's topics (the heartbeat counts a client)
        assert page.state_until(lambda s: any(p['id'] == LIVE for p in s['panels']), 120), \
            'the layout did not open'
        assert collector.wait_for_graph({'/force': 3, '/force_corrected': 2, '/pull_event': 2}, timeout=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': str(list(SETS)), 'pulls_per_set': 1, 'seed': 5,
                                                     'wait_for_subscribers': 2})
        spin = lambda: collector.executor.spin_once(timeout_sec=0.05)
        # the live plot's legend shows numbers, and they move while the sim pulls
        seen = []

        def moving(state):
            values = legend_values(state, LIVE)
            if values:
                seen.append(values)
            return len({tuple(sorted(v.items())) for v in seen}) >= 3
        assert page.state_until(moving, 180, spin), (seen[-3:], graph.tail('sim_node'))
        assert collector.wait(PULLS, 180, alive=lambda: not graph.dead()), graph.tail('sim_node')

        last_state = []

        def settled(state):
            last_state[:] = [state]
            shown = {r.get('pull') for r in table_rows(state, HISTORY)}
            rows = node_rows(state)
            return {str(s['pull_id']) for s in collector.scores} <= shown and \
                all(rows.get(n, ('', False))[1] for n in NODES) and len(table_rows(state, 'Table!sets')) == len(SETS)
        state = page.state_until(settled, 120, spin)
        page.command(f'screenshot {tmp_path / "viewer.png"}', 'screenshot')
        assert state is None or cut_off(state) == {}, cut_off(state)
        print(f'screenshot: {tmp_path / "viewer.png"}')
        assert state is not None, ('the score history or the diagnostics never settled',
                                   table_rows(last_state[0], HISTORY), node_rows(last_state[0]))
        # no connection problem: the app reported none for its data source
        assert page.problems == [], page.problems
        # the score history: a row per scored pull, newest first, with the validator's numbers (lbf, rounded)
        rows = table_rows(state, HISTORY)
        assert [r['pull'] for r in rows] == [str(s['pull_id']) for s in reversed(collector.scores)], rows
        for row, score in zip(rows, reversed(collector.scores)):
            assert float(row['stationary_lbf']) == pytest.approx(n_to_lbf(score['stationary_peak_n']), abs=0.051)
            assert float(row['raw_pct']) == pytest.approx(score['raw_diff_pct'], abs=0.0051)
            assert row['corrected_lbf'].startswith(f"{n_to_lbf(score['corrected_peak_n']):.1f}"), (row, score)
        # and the set's running statistics, as the validator summed them up
        sets = table_rows(state, 'Table!sets')
        assert [(r['test_set'], r['pulls']) for r in sets] == [(str(s), '1') for s in SETS], sets
        # each diagnostics row reads "<node>: <what>" (no node name twice, as "/validator: validator: ...")
        assert all(row['name'].count(':') == 1 for row in state['diagnostics']), state['diagnostics']
        # every node is listed, OK
        assert {n: ok for n, (_, ok) in node_rows(state).items() if n in NODES} == {n: True for n in NODES}, \
            node_rows(state)
        assert page.errors == [], page.errors
        # nothing was asked of the internet
        assert page.external == [], page.external
        # and nothing it asked for was missing (a favicon 404 came with every load)
        assert page.http_errors == [], page.http_errors
        assert graph.dead() == [], [graph.tail(n) for n in graph.dead()]

        # liveness (issue 41): a SIGKILLed node's row is STALE within 5 s (it stayed orange for 13.6 s); a lost
        # monitor is said plainly (its row stayed green through an 18.6 s outage), and goes once it is back
        def killed(name):
            proc = graph.procs.pop(name)
            proc.kill()
            proc.wait()
            return time.monotonic()
        t0 = killed('correction_node')
        stale = page.state_until(lambda s: node_rows(s).get('correction', ('',))[0].startswith('STALE'), 15, spin)
        assert stale is not None and time.monotonic() - t0 <= 5.0, (time.monotonic() - t0, stale and node_rows(stale))
        assert all(node_rows(stale)[n][1] for n in ('sim', 'validator', 'monitor')), node_rows(stale)
        graph.start('force_correction', 'correction_node')   # back: its row OK again (checked on the late page)
        t0 = killed('monitor_node')
        lost = page.state_until(lambda s: s['connectionLost'], 15, spin)
        assert lost is not None and time.monotonic() - t0 <= 5.0, time.monotonic() - t0
        assert 'No connection to the monitor' in lost['connectionLost'], lost['connectionLost']
        graph.start('force_tester_monitor', 'monitor_node', {'port': port})
        back = page.state_until(lambda s: not s['connectionLost'] and node_rows(s).get('monitor', ('', False))[1],
                                60, spin)
        assert back is not None, graph.tail('monitor_node')

        # the restarted monitor heard the validator's newest set summary only (latched, depth 1), yet the page
        # shows the whole test: every pull in the history, every set's statistics (issue 41, item 4)
        def complete(state):
            if not {HISTORY, 'Table!sets'} <= {p['id'] for p in state['panels']}:
                return False   # a page still opening
            return [r.get('pull') for r in table_rows(state, HISTORY)] == \
                [str(s['pull_id']) for s in reversed(collector.scores)] and \
                [(r['test_set'], r['pulls']) for r in table_rows(state, 'Table!sets')] == [(str(s), '1') for s in SETS]
        assert page.state_until(complete, 60, spin) is not None, (table_rows(back, HISTORY),
                                                                   table_rows(back, 'Table!sets'))
        # and so does a page opened now, after the last score (before: its tables stayed empty until the next)
        # at the smaller size, with the correction back: every table row, the pager and every node row in view
        late = Page(url, chromium, SIZES[1])
        last = []

        def whole(state):
            last[:] = [state]
            return complete(state) and not cut_off(state) and all(node_rows(state).get(n, ('', False))[1]
                                                                   for n in NODES)
        try:
            shown = late.state_until(whole, 120, spin)
            late.command(f'screenshot {tmp_path / "viewer_1366x768.png"}', 'screenshot')
            assert shown is not None, (last and (cut_off(last[0]), node_rows(last[0]), table_rows(last[0], HISTORY)))
        finally:
            late.close()
        # a late ROS reader (`ros2 topic echo /monitor/score_history --once`) gets the history at once: latched
        from force_tester_msgs.msg import ScoreHistory

        from force_tester_common.ros import LATCHED_QOS
        latched = []
        collector.node.create_subscription(ScoreHistory, '/monitor/score_history', latched.append, LATCHED_QOS)
        assert collector.spin_until(lambda: latched, 30) and len(latched[0].pulls) == PULLS, latched
    finally:
        if page is not None:
            page.close()
        if server is not None:
            server.shutdown()
        graph.stop()
        collector.close()
