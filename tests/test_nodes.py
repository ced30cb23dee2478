"""The nodes themselves, in this process over real rclpy + Fast DDS: parameters, bad samples, gaps."""
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402


@pytest.fixture
def ros(ros_domain):
    rclpy.init()
    yield
    rclpy.try_shutdown()


def make(node_cls):
    node = node_cls()
    return node


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


def test_nan_samples_are_reported_and_do_not_poison_the_filter(ros):
    from diagnostic_msgs.msg import DiagnosticArray
    from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, fill_block, to_array
    from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
    node = correction_node()
    node.set_parameters([Parameter('window', value=20)])
    probe = rclpy.create_node('probe')
    topics = {t.topic: t for t in BLOCK_TOPICS}
    pub_f = probe.create_publisher(topics['/force'].msg_type, '/force', BLOCK_QOS)
    pub_a = probe.create_publisher(topics['/accel'].msg_type, '/accel', BLOCK_QOS)
    out, diags = [], []
    probe.create_subscription(CORRECTED_TOPIC.msg_type, CORRECTED_TOPIC.topic, out.append, BLOCK_QOS)
    probe.create_subscription(DiagnosticArray, '/diagnostics', diags.append, EVENT_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(probe)
    try:
        assert spin_until(ex, lambda: pub_f.get_subscription_count() and pub_a.get_subscription_count()
                          and probe.count_publishers('/force_corrected'))
        time.sleep(0.3)
        rng = np.random.default_rng(1)
        n, nb = 50, 6
        f = 1000 + rng.normal(size=n * nb)
        a = rng.normal(size=n * nb)
        f[60] = np.nan
        for k in range(nb):
            s = slice(k * n, (k + 1) * n)
            stamp = 10**18 + k * 1_000_000
            pub_f.publish(fill_block(topics['/force'].msg_type(), stamp, 50000.0, k,
                                     {'moving_n': f[s], 'stationary_n': f[s]}))
            pub_a.publish(fill_block(topics['/accel'].msg_type(), stamp, 50000.0, k, {'axial_m_s2': a[s]}))
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
    finally:
        ex.shutdown()
        probe.destroy_node()
        node.destroy_node()


def test_a_dropped_block_is_reported_and_never_misaligns(ros):
    from diagnostic_msgs.msg import DiagnosticArray
    from force_tester_common.conversions import BLOCK_TOPICS, CORRECTED_TOPIC, fill_block, stamp_to_ns, to_array
    from force_tester_common.ros import BLOCK_QOS, EVENT_QOS
    node = correction_node()
    probe = rclpy.create_node('probe')
    topics = {t.topic: t for t in BLOCK_TOPICS}
    pub_f = probe.create_publisher(topics['/force'].msg_type, '/force', BLOCK_QOS)
    pub_a = probe.create_publisher(topics['/accel'].msg_type, '/accel', BLOCK_QOS)
    out, diags = [], []
    probe.create_subscription(CORRECTED_TOPIC.msg_type, CORRECTED_TOPIC.topic, out.append, BLOCK_QOS)
    probe.create_subscription(DiagnosticArray, '/diagnostics', diags.append, EVENT_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(probe)
    try:
        assert spin_until(ex, lambda: pub_f.get_subscription_count() and pub_a.get_subscription_count()
                          and probe.count_publishers('/force_corrected'))
        time.sleep(0.3)
        n = 50
        for k in range(6):
            stamp = 10**18 + k * 1_000_000
            value = np.full(n, float(k))
            pub_f.publish(fill_block(topics['/force'].msg_type(), stamp, 50000.0, k,
                                     {'moving_n': value, 'stationary_n': value}))
            if k != 2:  # accel block 2 is lost
                pub_a.publish(fill_block(topics['/accel'].msg_type(), stamp, 50000.0, k,
                                         {'axial_m_s2': np.zeros(n)}))
        assert spin_until(ex, lambda: len(out) == 5 and any('dropped' in st.message for d in diags
                                                             for st in d.status))
        for m in out:  # every corrected block carries the force of its own stamp
            k = (stamp_to_ns(m.header.stamp) - 10**18) // 1_000_000
            assert k != 2
            assert (to_array(m.raw_n) == k).all()
    finally:
        ex.shutdown()
        probe.destroy_node()
        node.destroy_node()
