"""How a node process spins (force_tester_common.ros.make_executor and spin): every executor kind
delivers every message and stops on shutdown, the EventsExecutor included (its own spin() in the
Jazzy wheels does neither: benchmarks/events_executor_spin.py)."""
import threading
import time

import pytest

from force_tester_common.node_params import ParameterError
from force_tester_common.ros import EXECUTORS, make_executor, spin


def test_an_unknown_executor_is_named():
    with pytest.raises(ParameterError, match=r"executor 'fastest' .*expected one of single, multi, events"):
        make_executor('fastest')


@pytest.mark.parametrize('kind', EXECUTORS)
def test_every_executor_delivers_and_stops_on_shutdown(kind, ros_domain):
    import rclpy
    from std_msgs.msg import Int32
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        pub_node = rclpy.create_node('talker', context=context)
        sub_node = rclpy.create_node('listener', context=context)
        got = []
        sub_node.create_subscription(Int32, 'numbers', lambda m: got.append(m.data), 1000)
        pub = pub_node.create_publisher(Int32, 'numbers', 1000)
        executor = make_executor(kind, context=context)
        executor.add_node(sub_node)
        # our spin() polls rclpy.ok() of the default context; this test's context is its own
        spinner = threading.Thread(target=lambda: _spin_until_shutdown(executor, context), daemon=True)
        spinner.start()
        deadline = time.monotonic() + 30
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(300):
            pub.publish(Int32(data=i))
        while len(got) < 300 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert got == list(range(300))
    finally:
        context.try_shutdown()
    spinner.join(timeout=10)
    assert not spinner.is_alive(), f'{kind}: spinning did not stop on shutdown'


def _spin_until_shutdown(executor, context):
    from rclpy.executors import ExternalShutdownException
    try:
        spin(executor, ok=context.ok)
    except ExternalShutdownException:
        pass
