"""The nodes themselves, in this process over real rclpy + Fast DDS: parameters, bad samples, gaps."""
import re
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from force_tester_common.conversions import BLOCK_TOPICS, fill_block, stamp_to_ns, to_array  # noqa: E402

TOPICS = {t.topic: t for t in BLOCK_TOPICS}


@pytest.fixture
def ros(ros_domain):
    rclpy.init()
    yield
    rclpy.try_shutdown()


def sim_node():
    from force_tester_sim.sim_node import SimNode
    # waits for 99 subscribers on /force, so it never starts publishing in these tests
    return SimNode(parameter_overrides=[Parameter('wait_for_subscribers', value=99)])


def correction_node():
    from force_correction.correction_node import CorrectionNode
    return CorrectionNode()


def validator_node():
    from force_correction.validator_node import ValidatorNode
    return ValidatorNode()


@pytest.mark.parametrize('factory, name, value, quoted', [
    (correction_node, 'mass_kg', -1.0, ['-1.0', '1e-06', '1000.0']),
    (correction_node, 'window', 0, ['0', '1', '50000']),
    (sim_node, 'test_sets', [7], ['7', '1, 2, 3, 4, 5']),
    (sim_node, 'block_size', 0, ['0', '1', '100000']),
    (sim_node, 'rate', 0.0, ['0.0', '0.01', '1000.0']),
    (sim_node, 'coupons', 'foo', ['foo', 'rated, measured']),
    (validator_node, 'loaded_fraction', 1.5, ['1.5', '0.99']),
])
def test_invalid_parameter_is_rejected_with_value_and_range_and_old_value_kept(ros, factory, name, value, quoted):
    node = factory()
    try:
        old = node.get_parameter(name).value
        (result,) = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful
        for text in quoted:
            assert text in result.reason, result.reason
        assert node.get_parameter(name).value == old
    finally:
        getattr(node, 'close', lambda: None)()
        node.destroy_node()


@pytest.mark.parametrize('name, value', [('wait_for_subscribers', 2), ('wait_for_block_subscribers', 3),
                                         ('wait_timeout_s', 5.0)])
def test_the_sims_start_up_wait_cannot_be_changed_at_run_time(ros, name, value):
    """The wait for readers happens once, before the first pull: a change at run time was accepted and did nothing
    (issue 41, Low). The parameters are read-only: `ros2 param set` is refused and the value stays."""
    node = sim_node()
    try:
        old = node.get_parameter(name).value
        (result,) = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful and 'read-only' in result.reason, result.reason
        assert node.get_parameter(name).value == old
    finally:
        getattr(node, 'close', lambda: None)()
        node.destroy_node()


def test_valid_parameter_change_applies(ros):
    node = correction_node()
    try:
        (result,) = node.set_parameters([Parameter('window', value=10)])
        assert result.successful, result.reason
        assert node.corrector.params.window == 10
    finally:
        node.destroy_node()


def spin_until(executor, cond, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not cond() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.02)
    return cond()


class Loop:
    """A correction node and a probe node in one executor: the probe publishes /force and /accel
    blocks and collects /force_corrected and /diagnostics."""

    def __init__(self, node):
        from diagnostic_msgs.msg import DiagnosticArray

        from force_tester_common.conversions import CORRECTED_TOPIC
        from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
        self.node = node
        self.probe = rclpy.create_node('probe')
        self.pub_f = self.probe.create_publisher(TOPICS['/force'].msg_type, '/force', BLOCK_QOS)
        self.pub_a = self.probe.create_publisher(TOPICS['/accel'].msg_type, '/accel', BLOCK_QOS)
        self.out, self.diags = [], []
        self.probe.create_subscription(CORRECTED_TOPIC.msg_type, CORRECTED_TOPIC.topic, self.out.append, BLOCK_QOS)
        self.probe.create_subscription(DiagnosticArray, '/diagnostics', self.diags.append, EVENT_QOS)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(node)
        self.ex.add_node(self.probe)

    def __enter__(self):
        assert spin_until(self.ex, lambda: self.pub_f.get_subscription_count() and self.pub_a.get_subscription_count()
                          and self.probe.count_publishers('/force_corrected')
                          and self.node.count_subscribers('/force_corrected')
                          and self.node.count_subscribers('/diagnostics'))
        return self.ex, self.pub_f, self.pub_a, self.out, self.diags

    def __exit__(self, *exc):
        self.ex.shutdown()
        self.probe.destroy_node()
        self.node.destroy_node()


def test_nan_samples_are_reported_and_do_not_poison_the_filter(ros):
    node = correction_node()
    node.set_parameters([Parameter('window', value=20)])
    with Loop(node) as (ex, pub_f, pub_a, out, diags):
        rng = np.random.default_rng(1)
        n, nb = 50, 6
        f = 1000 + rng.normal(size=n * nb)
        a = rng.normal(size=n * nb)
        f[60] = np.nan
        for k in range(nb):
            s = slice(k * n, (k + 1) * n)
            stamp = 10**18 + k * 1_000_000
            pub_f.publish(fill_block(TOPICS['/force'].msg_type(), stamp, 50000.0, k,
                                     {'moving_n': f[s], 'stationary_n': f[s]}))
            pub_a.publish(fill_block(TOPICS['/accel'].msg_type(), stamp, 50000.0, k, {'axial_m_s2': a[s]}))
        assert spin_until(ex, lambda: len(out) == nb and any('NaN' in st.message for d in diags for st in d.status))
        filtered = np.concatenate([to_array(m.filtered_n) for m in out])
        corrected = np.concatenate([to_array(m.corrected_n) for m in out])
        assert np.isnan(corrected[60]) and np.isfinite(np.delete(corrected, 60)).all()
        assert np.isfinite(filtered).all()
        # once the NaN has left the 20-sample window, the filter equals the NaN-free result
        clean = f.copy()
        clean[60] = 1000.0
        ref = np.convolve(clean - 1.152 * a, np.ones(20) / 20)[: n * nb]
        np.testing.assert_allclose(filtered[80:], ref[80:], rtol=0, atol=1e-9)


def test_a_dropped_block_is_reported_and_never_misaligns(ros):
    with Loop(correction_node()) as (ex, pub_f, pub_a, out, diags):
        n = 50
        for k in range(6):
            stamp = 10**18 + k * 1_000_000
            value = np.full(n, float(k))
            pub_f.publish(fill_block(TOPICS['/force'].msg_type(), stamp, 50000.0, k,
                                     {'moving_n': value, 'stationary_n': value}))
            if k != 2:  # accel block 2 is lost
                pub_a.publish(fill_block(TOPICS['/accel'].msg_type(), stamp, 50000.0, k,
                                         {'axial_m_s2': np.zeros(n)}))
        assert spin_until(ex, lambda: len(out) == 5 and any('dropped' in st.message for d in diags
                                                             for st in d.status))
        for m in out:  # every corrected block carries the force of its own stamp
            k = (stamp_to_ns(m.header.stamp) - 10**18) // 1_000_000
            assert k != 2
            assert (to_array(m.raw_n) == k).all()


BAD_BLOCKS = {  # name -> (force arrays, accel arrays, rate)
    'rate_zero': ({'moving_n': np.ones(50), 'stationary_n': np.ones(50)}, {'axial_m_s2': np.ones(50)}, 0.0),
    'rate_negative': ({'moving_n': np.ones(50), 'stationary_n': np.ones(50)}, {'axial_m_s2': np.ones(50)}, -5e4),
    'rate_nan': ({'moving_n': np.ones(50), 'stationary_n': np.ones(50)}, {'axial_m_s2': np.ones(50)}, float('nan')),
    'rate_inf': ({'moving_n': np.ones(50), 'stationary_n': np.ones(50)}, {'axial_m_s2': np.ones(50)}, float('inf')),
    'ragged': ({'moving_n': np.ones(50), 'stationary_n': np.ones(49)}, {'axial_m_s2': np.ones(50)}, 5e4),
    'empty': ({}, {}, 5e4),
    'huge': ({'moving_n': np.ones(1_000_001)}, {'axial_m_s2': np.ones(1_000_001)}, 5e4),
}


def test_bad_blocks_are_counted_reported_and_dropped_and_the_node_lives(ros):
    """Anything on a topic is input from outside: each bad block is dropped with a diagnostic
    naming the problem; good blocks around them are corrected as if the bad ones never came."""
    ex_node = correction_node()
    with Loop(ex_node) as (ex, pub_f, pub_a, out, diags):
        good = {'moving_n': np.full(50, 7.0), 'stationary_n': np.full(50, 7.0)}
        stamp = 10**18
        for k, (f, a, rate) in enumerate(BAD_BLOCKS.values()):  # earlier stamps: they never pair
            pub_f.publish(fill_block(TOPICS['/force'].msg_type(), stamp - 10**10, rate, k, f))
            pub_a.publish(fill_block(TOPICS['/accel'].msg_type(), stamp - 10**10, rate, k, a))
        n_bad = 2 * len(BAD_BLOCKS) - 1   # the accel block of the ragged case is a good one
        for k in range(3):
            pub_f.publish(fill_block(TOPICS['/force'].msg_type(), stamp + k * 1_000_000, 5e4, k, good))
            pub_a.publish(fill_block(TOPICS['/accel'].msg_type(), stamp + k * 1_000_000, 5e4, k,
                                     {'axial_m_s2': np.zeros(50)}))
        assert spin_until(ex, lambda: len(out) == 3 and ex_node.counts['bad_messages'] == n_bad, timeout=20)
        messages = ' '.join(st.message for d in diags for st in d.status)
        for word in ('sample_rate_hz 0.0', 'ragged', 'empty', 'at most'):
            assert word in messages, (word, messages)
        assert all((to_array(m.raw_n) == 7.0).all() for m in out)
        assert ex_node.counts['pairs'] == 3


def test_a_best_effort_publisher_on_a_reliable_topic_is_reported(ros):
    """DDS delivers nothing from a best-effort writer to a reliable reader, silently; the node
    says so on /diagnostics (the incompatible-QoS event)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    with Loop(correction_node()) as (ex, pub_f, pub_a, out, diags):
        probe = ex.get_nodes()[1] if ex.get_nodes()[0].get_name() == 'correction' else ex.get_nodes()[0]
        probe.create_publisher(TOPICS['/force'].msg_type, '/force',
                               QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        assert spin_until(ex, lambda: any('incompatible' in st.message and 'RELIABILITY' in st.message
                                          for d in diags for st in d.status), timeout=30)


def test_a_change_that_leaves_the_correction_as_it_was_does_not_restart_it(ros):
    node = correction_node()
    try:
        before = node.corrector
        for p in (Parameter('use_sim_time', value=False), Parameter('window', value=node.params.values['window'])):
            (result,) = node.set_parameters([p])
            assert result.successful, result.reason
            assert node.corrector is before, p.name
        node.set_parameters([Parameter('window', value=10)])
        assert node.corrector is not before and node.corrector.params.window == 10
    finally:
        node.destroy_node()


@pytest.mark.parametrize('package, name, args, quoted', [
    ('force_correction', 'correction_node', ['-p', 'window:=0'], ['window', '0', '[1, 50000]']),
    ('force_correction', 'correction_node', ['-p', 'mass_kg:=abc'], ['mass_kg', 'abc']),
    ('force_correction', 'validator_node', ['-p', 'loaded_fraction:=1.5'], ['loaded_fraction', '1.5', '0.99']),
    ('force_correction', 'correction_node', ['-p', 'extension_file:=/nonexistent/ext.yaml'], ['/nonexistent/ext.yaml']),
])
def test_an_invalid_parameter_at_startup_stops_the_node_with_one_line(ros_domain, package, name, args, quoted):
    """As plain rclpy refuses to start: exit 2, one line naming the parameter, value and range."""
    import subprocess

    from ft_cli.paths import executable
    res = subprocess.run([str(executable(package, name)), '--ros-args', *args], capture_output=True, text=True,
                         timeout=120, stdin=subprocess.DEVNULL)
    assert res.returncode == 2, (res.returncode, res.stdout, res.stderr)
    lines = [ln for ln in res.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f'{name}: error: '), res.stderr
    for text in quoted:
        assert text in lines[0], lines[0]


def test_extension_file_sets_the_mass_and_a_bad_one_is_refused(ros, tmp_path):
    good = tmp_path / 'extension.yaml'
    good.write_text('correction:\n  mass_kg: 1.3\n  accel_delay_s: 4.0e-5\n')
    node = correction_node()
    try:
        (ok,) = node.set_parameters([Parameter('extension_file', value=str(good))])
        assert ok.successful, ok.reason
        assert node.corrector.params.mass_kg == 1.3
        assert node.extension.accel_delay_s == 4.0e-5 and node.extension.not_applied == ()
        dragged = tmp_path / 'dragged.yaml'
        dragged.write_text('correction: {}\nextra_terms: [{channel: force_moving, term: v, coefficient: 9.0}]\n')
        (ok,) = node.set_parameters([Parameter('extension_file', value=str(dragged))])
        assert ok.successful and node.extension.not_applied == ('force_moving: v',)
        (ok,) = node.set_parameters([Parameter('extension_file', value=str(good))])
        (bad,) = node.set_parameters([Parameter('extension_file', value=str(tmp_path / 'missing.yaml'))])
        assert not bad.successful and 'missing.yaml' in bad.reason
        assert node.get_parameter('extension_file').value == str(good)
    finally:
        node.destroy_node()


@pytest.mark.parametrize('sim_time', (False, True), ids=('wall_clock', 'use_sim_time_without_clock'))
def test_recorder_reports_its_progress_on_diagnostics(ros, tmp_path, sim_time):
    """The recorder publishes how many messages it has written (what `./ft demo` waits on
    before stopping it): the count matches the blocks sent and the bag it closes. With use_sim_time:=true and
    nothing on /clock too: the node's timers (topic discovery, flushing, the heartbeat) are on the steady clock
    (before, none fired: the recorder recorded nothing and no heartbeat went out; issue 41, Low)."""
    from diagnostic_msgs.msg import DiagnosticArray

    from bag_tools.core.info import bag_info
    from bag_tools.recorder_node import RecorderNode
    from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
    node = RecorderNode(parameter_overrides=[Parameter('bag_path', value=str(tmp_path / 'bag')),
                                             Parameter('topics', value=['/force']),
                                             Parameter('use_sim_time', value=sim_time)])
    probe = rclpy.create_node('probe')
    pub = probe.create_publisher(TOPICS['/force'].msg_type, '/force', BLOCK_QOS)
    counts = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda m: counts.extend(
        int(kv.value) for st in m.status if st.name.startswith('recorder:')
        for kv in st.values if kv.key == 'messages'), EVENT_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(probe)
    try:
        assert spin_until(ex, lambda: pub.get_subscription_count() > 0)
        for k in range(7):
            msg = TOPICS['/force'].msg_type()
            fill_block(msg, 1_700_000_000 * 10**9 + k * 10**6, 50_000.0, k,
                       {'moving_n': np.ones(50), 'stationary_n': np.ones(50)}, 'force')
            pub.publish(msg)
        assert spin_until(ex, lambda: counts and counts[-1] == 7), counts
        assert counts == sorted(counts)
    finally:
        node.close()
        ex.shutdown()
        probe.destroy_node()
        node.destroy_node()
    assert bag_info(tmp_path / 'bag')['topics']['/force']['count'] == 7


def test_a_recorder_given_no_bag_path_writes_a_dated_bag_as_ros2_bag_record(ros, tmp_path, monkeypatch):
    """A second launch with a recorder in the same folder recorded nothing: the default bag_path was the fixed
    'bag', which then existed (issue 41, Low). Empty (the default) is rosbag2_YYYY_MM_DD-HH_MM_SS in the working
    directory, as `ros2 bag record` names it; a recorder started while an earlier one's bag is there records."""

    from bag_tools.core.recording import dated_bag_path
    from bag_tools.recorder_node import SPECS, RecorderNode
    assert [s.default for s in SPECS if s.name == 'bag_path'] == ['']
    at = time.mktime((2026, 11, 28, 7, 5, 9, 0, 0, -1))
    assert dated_bag_path(at) == 'rosbag2_2026_11_28-07_05_09'
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'bag').mkdir()   # what an earlier launch with the old default left
    node = RecorderNode(parameter_overrides=[Parameter('topics', value=['/force'])])
    try:
        path = node.writer.path
    finally:
        node.close()
        node.destroy_node()
    assert re.fullmatch(r'rosbag2_\d{4}_\d\d_\d\d-\d\d_\d\d_\d\d', path.name) and path.parent.resolve() == tmp_path


def test_a_state_file_that_cannot_be_written_stops_the_validator_at_start_up(ros, tmp_path):
    """An unwritable state_file was accepted at start-up and failed at the first score (issue 41, Low): the
    validator refuses it at once, in one line naming the file (a CorrectionError: exit 2 from a process)."""
    from force_correction.core.errors import CorrectionError
    from force_correction.validator_node import ValidatorNode
    blocker = tmp_path / 'not_a_folder'
    blocker.write_text('')   # a file where the state file's folder should be: even root cannot write under it
    state = blocker / 'scores.jsonl'
    with pytest.raises(CorrectionError, match=re.escape(f"state_file '{state}' cannot be written")):
        ValidatorNode(parameter_overrides=[Parameter('state_file', value=str(state))])
    ok = tmp_path / 'new' / 'scores.jsonl'   # a folder that does not exist yet is made, as before
    node = ValidatorNode(parameter_overrides=[Parameter('state_file', value=str(ok))])
    try:
        assert ok.parent.is_dir()
    finally:
        node.destroy_node()
