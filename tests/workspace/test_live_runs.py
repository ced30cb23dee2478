"""Acceptance: the live pair (correction + validator, separate processes over Fast DDS) survives
replays, a parameter change between them and malformed messages from outside.

A bag of three short pulls is played into the pair three times by the player process: the second
play must give the first play's scores again (a replay is a new run, not a stream to reject), and
after `window` is set to 2000 over the parameter service the third play must give what offline
`correct` computes with that window. Before the plays, malformed messages (rate 0, NaN, negative,
ragged, empty, an unknown event code) go to every topic the pair reads: both nodes must live,
report them on /diagnostics and score the plays as if they never came.
"""
import time

import numpy as np
import pytest
from daq_data import T0, make_pulls

from ft_cli.graph import SCORE_KEYS, Graph, ScoreCollector

pytestmark = pytest.mark.slow

PULLS = 3


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    from bag_tools.core.convert import campaign_to_bag
    from bag_tools.core.daq import write_campaign
    tmp = tmp_path_factory.mktemp('runs')
    write_campaign(tmp / 'campaign', make_pulls(PULLS, start=T0))
    return campaign_to_bag(tmp / 'campaign', tmp / 'bag')


def publish_bad_messages(node, diags_seen):
    """Publish one malformed message of each kind on /force, /accel, /force_corrected, /pull_event."""
    from force_tester_msgs.msg import PullEvent

    from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, fill_block
    from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
    topics = {t.topic: t for t in BLOCK_TOPICS}
    pubs = {name: node.create_publisher(t.msg_type, t.topic, BLOCK_QOS)
            for name, t in (('force', topics['/force']), ('accel', topics['/accel']),
                            ('corrected', CORRECTED_TOPIC))}
    events = node.create_publisher(PullEvent, '/pull_event', EVENT_QOS)
    ones = np.ones(50)
    bad = [('force', topics['/force'], 0.0, {'moving_n': ones, 'stationary_n': ones}),
           ('force', topics['/force'], 5e4, {'moving_n': ones, 'stationary_n': np.ones(49)}),
           ('force', topics['/force'], 5e4, {}),
           ('accel', topics['/accel'], float('nan'), {'axial_m_s2': ones}),
           ('corrected', CORRECTED_TOPIC, -5e4, {'raw_n': ones, 'inertial_n': ones, 'corrected_n': ones,
                                                 'filtered_n': ones})]
    for name, topic, rate, arrays in bad:
        pubs[name].publish(fill_block(topic.msg_type(), T0 - 10**10, rate, 0, arrays))
    events.publish(PullEvent(event=7, pull_id=1, test_set=1))
    return len(bad) + 1


def bad_message_reports(collector) -> int:
    return sum(1 for d in collector.diagnostics for st in d.status if 'dropped' in st.message
               and 'bad' in st.message)


def play(graph, bag, name):
    graph.start('bag_tools', 'player', extra=[str(bag), '--topics', '/force', '/accel', '/pull_event',
                                              '--wait-for-subscribers', '1'])
    graph.procs[name] = graph.procs.pop('player')


def test_replays_a_parameter_change_and_bad_messages(bag, tmp_path, ros_domain):
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from force_correction.offline import CorrectionSetup, correct
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    collector.diagnostics = []
    from diagnostic_msgs.msg import DiagnosticArray

    from force_tester_common.ros import EVENT_QOS
    collector.node.create_subscription(DiagnosticArray, '/diagnostics', collector.diagnostics.append, EVENT_QOS)
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        assert collector.wait_for_graph({'/force_corrected': 1, '/force': 2, '/pull_event': 1}, timeout=60)
        sent = publish_bad_messages(collector.node, collector.diagnostics)
        deadline = time.monotonic() + 30
        while bad_message_reports(collector) < sent and time.monotonic() < deadline:
            collector.executor.spin_once(timeout_sec=0.1)
        assert bad_message_reports(collector) >= sent, [st.message for d in collector.diagnostics
                                                         for st in d.status]
        assert graph.dead() == []

        for k, name in enumerate(('play1', 'play2')):
            play(graph, bag, name)
            assert collector.wait(PULLS * (k + 1), 120, alive=lambda: not graph.dead()), graph.tail(name)
        first, second = collector.scores[:PULLS], collector.scores[PULLS:]
        for a, b in zip(first, second):
            for key in SCORE_KEYS:
                assert b[key] == pytest.approx(a[key], rel=1e-9, abs=1e-9), (key, a, b)

        client = AsyncParameterClient(collector.node, 'correction')
        assert client.wait_for_services(timeout_sec=30)
        future = client.set_parameters([Parameter('window', value=2000)])
        collector.executor.spin_until_future_complete(future, timeout_sec=30)
        assert future.done() and all(r.successful for r in future.result().results)
        play(graph, bag, 'play3')
        assert collector.wait(3 * PULLS, 120, alive=lambda: not graph.dead()), graph.tail('play3')
        assert graph.dead() == []
    finally:
        codes = graph.stop()
        collector.close()
    assert codes['correction_node'] == 0 and codes['validator_node'] == 0, codes
    offline = correct(bag, tmp_path / 'offline', CorrectionSetup.build(window=2000)).as_dict()['pulls']
    third = collector.scores[2 * PULLS:]
    assert [s['pull_id'] for s in third] == [p['pull_id'] for p in offline]
    for live, off in zip(third, offline):
        for key in ('raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'filtered_rms_n'):
            assert live[key] == pytest.approx(off[key], rel=1e-9, abs=1e-9), (key, live, off)
    # the new window changed the filtered result: the third play is not the first again
    assert any(abs(t['filtered_diff_pct'] - f['filtered_diff_pct']) > 1e-6 for t, f in zip(third, first))


@pytest.mark.parametrize('attempt', range(3))
def test_the_by_hand_recipe_scores_every_pull(tmp_path, ros_domain, attempt):
    """docs/nodes.md's recipe: correction, validator and recorder up, then the sim waiting for the two
    readers of /pull_event, so no pull event is lost (issue: 1 run in 3 lost the first pull's
    START; with the default of one reader, 1 CI run in 3 still did when the validator matched
    after the recorder's quiet second)."""
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(tmp_path / 'bag')})
        assert collector.wait_for_graph({'/force_corrected': 2, '/force': 3, '/pull_event': 2}, timeout=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[3]', 'pulls_per_set': 2, 'rate': 1.0,
                                                      'seed': attempt, 'wait_for_subscribers': 2})
        assert collector.wait(2, 120, alive=lambda: not graph.dead()), graph.tail('validator_node')
    finally:
        graph.stop()
        collector.close()
    assert [s['pull_id'] for s in collector.scores] == [0, 1]
    assert 'without its START' not in (tmp_path / 'logs' / 'validator_node.log').read_text()


def kill(graph, name):
    import signal
    p = graph.procs.pop(name)
    p.send_signal(signal.SIGKILL)
    p.wait()


class EventWatch:
    """The /pull_event STARTs seen by the test's node: so a fault can be injected inside a given
    pull (a condition, not a timer)."""

    def __init__(self, collector):
        from force_tester_msgs.msg import PullEvent

        from force_tester_common.ros import EVENT_QOS
        self.collector, self.started, self.ended = collector, set(), set()
        collector.node.create_subscription(PullEvent, '/pull_event', self._on_event, EVENT_QOS)

    def _on_event(self, msg):
        (self.started if msg.event == msg.START else self.ended).add(msg.pull_id)

    def wait_start(self, pull_id, timeout=120, alive=lambda: True) -> bool:
        deadline = time.monotonic() + timeout
        while pull_id not in self.started and time.monotonic() < deadline and alive():
            self.collector.executor.spin_once(timeout_sec=0.05)
        return pull_id in self.started


def test_faults_mid_pull_are_scored_with_their_status(tmp_path, ros_domain):
    """The window changed mid-pull: RECONFIGURED. The correction node SIGKILLed mid-pull and
    restarted: the corrected stream resumes and the pull is INCOMPLETE, with the gap. The sim
    SIGKILLed mid-pull: the validator closes that pull as ABORTED after abort_timeout_s, and the
    sim's worker process does not outlive it. Every pull gets a score message, whatever happened
    to it."""
    import psutil
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from force_tester_common.core.scores import PULL_ABORTED, PULL_INCOMPLETE, PULL_OK
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    events = EventWatch(collector)
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node', {'abort_timeout_s': 3.0})
        assert collector.wait_for_graph({'/force_corrected': 1, '/force': 2, '/pull_event': 2}, timeout=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[3]', 'pulls_per_set': 6, 'rate': 0.5,
                                                      'wait_for_subscribers': 2})
        alive = lambda: not graph.dead()
        assert events.wait_start(1, alive=alive), graph.tail('sim_node')
        assert collector.wait(1, 120, alive=alive), graph.tail('validator_node')   # pull 0 is all corrected
        client = AsyncParameterClient(collector.node, 'correction')
        assert client.wait_for_services(timeout_sec=30)
        future = client.set_parameters([Parameter('window', value=200)])
        collector.executor.spin_until_future_complete(future, timeout_sec=30)
        assert future.done() and all(r.successful for r in future.result().results)
        assert events.wait_start(3, alive=alive), graph.tail('sim_node')
        kill(graph, 'correction_node')
        graph.start('force_correction', 'correction_node', {'window': 200})
        assert events.wait_start(5, alive=alive), graph.tail('sim_node')
        helpers = psutil.Process(graph.procs['sim_node'].pid).children(recursive=True)
        assert helpers, 'the sim simulates the next pull in a worker process'
        kill(graph, 'sim_node')
        assert collector.wait(6, 180, alive=alive), graph.tail('validator_node')
        _gone, left = psutil.wait_procs(helpers, timeout=30)
    finally:
        graph.stop()
        collector.close()
    assert not left, f'the SIGKILLed sim left {[p.cmdline() for p in left]} running'
    status = {s['pull_id']: (s['status'], s['detail']) for s in collector.scores}
    assert sorted(status) == [0, 1, 2, 3, 4, 5], status
    assert status[0] == (PULL_OK, ''), status
    assert any('reconfigured mid-pull (window)' in status[k][1] for k in (1, 2)), status
    # the gap: seen when corrected blocks resume, or (when the restart outlasts the finish timeout,
    # as next to CPU hogs) as data that stopped before the END
    assert status[3][0] == PULL_INCOMPLETE and ('the correction restarted' in status[3][1]
                                                 or 'the data stopped before the END' in status[3][1]), status
    assert status[5][0] == PULL_ABORTED and 'no data and no END' in status[5][1], status


def test_a_restarted_validator_keeps_its_scores(tmp_path, ros_domain):
    """With state_file, a validator killed and started again republishes the scores it had, and
    its set summaries count them."""
    from force_tester_msgs.msg import SetSummary

    from force_tester_common.core.scores import PULL_OK
    from force_tester_common.ros import SUMMARY_QOS
    state = tmp_path / 'scores.jsonl'
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    summaries = []
    collector.node.create_subscription(SetSummary, '/set_summary', summaries.append, SUMMARY_QOS)
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node', {'state_file': str(state)})
        assert collector.wait_for_graph({'/force_corrected': 1, '/force': 2, '/pull_event': 1}, timeout=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[3]', 'pulls_per_set': 3, 'rate': 1.0})
        alive = lambda: not graph.dead()
        assert collector.wait(2, 120, alive=alive), graph.tail('validator_node')
        kill(graph, 'validator_node')
        before = collector.scores[:]
        graph.start('force_correction', 'validator_node', {'state_file': str(state)})
        assert collector.wait(len(before) + 2, 120, alive=alive), graph.tail('validator_node')
        ok = {s['pull_id'] for s in before if s['status'] == PULL_OK}
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not (summaries and summaries[-1].pulls >= len(ok)):
            collector.executor.spin_once(timeout_sec=0.1)
    finally:
        graph.stop()
        collector.close()
    restored = collector.scores[len(before):len(before) + 2]
    assert [s['pull_id'] for s in restored] == [s['pull_id'] for s in before[:2]], (before, restored)
    for a, b in zip(before, restored):
        assert a == b
    assert summaries[-1].pulls >= len(ok) > 0, (summaries[-1], ok)
    lines = state.read_text().splitlines()
    assert len(lines) >= 2 and len(lines) == len({s['pull_id'] for s in collector.scores})


def test_each_validator_follows_its_own_correction(tmp_path, ros_domain):
    """The demo's two pairs (the plain one and the extension's, as `./ft demo` starts them): the window of
    /correction changed mid-pull (1, else 2) marks that plain pull RECONFIGURED and not the extension's; the window
    of /correction_extension changed two pulls later marks the extension's pull and not the plain one (issue 41)."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from force_tester_common.core.scores import PULL_RECONFIGURED
    from ft_cli.commands.demo import EXT_CORRECTION, EXT_SCORE_TOPIC, extension_args
    extension = tmp_path / 'extension.yaml'
    extension.write_text('correction:\n  moving_cell_gain: 1.01\n')
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector(also=(EXT_SCORE_TOPIC,))
    events = EventWatch(collector)
    alive = lambda: not graph.dead()  # noqa: E731

    def set_window_mid_pull(client, pull_ids, value):
        """The window set while one of pull_ids runs: the first pull whose END had not come when the change was
        acknowledged (on a loaded machine the sim may finish a pull before the call returns: then the next)."""
        for pull_id in pull_ids:
            assert events.wait_start(pull_id, alive=alive), graph.tail('sim_node')
            if pull_id in events.ended:
                continue
            future = client.set_parameters([Parameter('window', value=value)])
            collector.executor.spin_until_future_complete(future, timeout_sec=30)
            assert future.done() and all(r.successful for r in future.result().results)
            if pull_id not in events.ended:
                return pull_id
            value += 1   # a new value, so the next try is a change too
        raise AssertionError(f'pulls {pull_ids} all ended before the change of window was acknowledged')
    try:
        graph.start('force_correction', 'correction_node')
        graph.start('force_correction', 'validator_node')
        for exe, kw in extension_args(extension).items():
            graph.start('force_correction', f'{exe}_node', **kw)
        wanted = {'/force_corrected': 1, '/extension/force_corrected': 1, '/force': 4, '/pull_event': 3}
        assert collector.wait_for_graph(wanted, timeout=60), {t: collector.node.count_subscribers(t) for t in wanted}
        # the parameter services are found before the sim starts: a change is then one round trip
        plain_client, ext_client = (AsyncParameterClient(collector.node, n) for n in ('correction', EXT_CORRECTION))
        assert plain_client.wait_for_services(timeout_sec=60) and ext_client.wait_for_services(timeout_sec=60)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[3]', 'pulls_per_set': 6, 'rate': 0.5,
                                                      'wait_for_subscribers': 3, 'wait_for_block_subscribers': 4})
        plain_pull = set_window_mid_pull(plain_client, (1, 2), 200)
        ext_pull = set_window_mid_pull(ext_client, (plain_pull + 2, plain_pull + 3), 200)
        assert collector.wait(ext_pull + 1, 120, alive=alive), graph.tail('validator_extension')
    finally:
        graph.stop()
        collector.close()
    plain = {s['pull_id']: s['status'] for s in collector.scores}
    ext = {s['pull_id']: s['status'] for s in collector.also_scores[EXT_SCORE_TOPIC]}
    assert plain[plain_pull] == PULL_RECONFIGURED != plain[ext_pull], (plain_pull, ext_pull, plain)
    assert ext[ext_pull] == PULL_RECONFIGURED != ext[plain_pull], (plain_pull, ext_pull, ext)
