"""Minimal reproduction: rclpy.experimental.EventsExecutor.spin() of the Jazzy wheels (ros-jazzy-rclpy
7.1.6 from PyPI) busy-waits on one core, runs no subscription callback and does not return on
shutdown, while spin_once(timeout_sec=...) in a loop works. (python benchmarks/events_executor_spin.py)

Two child processes over Fast DDS in a domain of their own: a publisher of 2000 std_msgs/String at
1 kHz and a subscriber spinning an EventsExecutor either way. The subscriber counts what it
receives and its CPU for 4 s, then calls rclpy.shutdown(). It prints, per way of spinning:
messages received, CPU seconds, and whether spinning returned after the shutdown. Exit 0 when it
reproduces (spin() broken, spin_once() fine), 1 otherwise (the defect is fixed in this wheel).
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

SUBSCRIBER = textwrap.dedent('''
    import sys, threading, time
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('sub')
    got = []
    node.create_subscription(String, 'chatter', got.append, 1000)
    ex = EventsExecutor()
    ex.add_node(node)
    cpu0 = time.process_time()
    def stop():
        time.sleep(4.0)
        print(f'received {len(got)} cpu {time.process_time() - cpu0:.2f}', flush=True)
        rclpy.shutdown()
    threading.Thread(target=stop, daemon=True).start()
    try:
        if sys.argv[1] == 'spin':
            ex.spin()
        else:
            while rclpy.ok():
                ex.spin_once(timeout_sec=0.5)
    except ExternalShutdownException:   # spin_once after the shutdown says so; either way it returned
        pass
    print('returned', flush=True)
''')

PUBLISHER = textwrap.dedent('''
    import time
    import rclpy
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node('pub')
    pub = node.create_publisher(String, 'chatter', 1000)
    deadline = time.monotonic() + 3.0
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    for i in range(2000):
        pub.publish(String(data=str(i)))
        time.sleep(0.001)
''')


def trial(mode: str, domain: int) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    sub = subprocess.Popen([sys.executable, '-c', SUBSCRIBER, mode], env=env, stdout=subprocess.PIPE, text=True)
    pub = subprocess.Popen([sys.executable, '-c', PUBLISHER], env=env)
    try:
        out, _ = sub.communicate(timeout=12)
        returned = True
    except subprocess.TimeoutExpired:   # spin() never returns: kill it and read what it printed
        sub.kill()
        out, _ = sub.communicate()
        returned = False
    pub.wait(timeout=10)
    line = next((ln for ln in out.splitlines() if ln.startswith('received')), 'received ? cpu ?')
    _, received, _, cpu = line.split()
    return {'mode': mode, 'received': received, 'cpu_s': cpu, 'returned': returned and 'returned' in out}


def main() -> int:
    if '-h' in sys.argv or '--help' in sys.argv:
        print(__doc__)
        return 0
    results = [trial('spin', 97), trial('spin_once', 98)]
    for r in results:
        print(f"EventsExecutor.{r['mode']:9s}: received {r['received']:>4} of 2000, CPU {r['cpu_s']} s in 4 s, "
              f"{'returned' if r['returned'] else 'did NOT return'} after rclpy.shutdown()")
    spin, once = results
    reproduced = spin['received'] == '0' and not spin['returned'] and once['returned'] and once['received'] != '0'
    print('reproduced: spin() is broken, spin_once() works' if reproduced else 'not reproduced')
    return 0 if reproduced else 1


if __name__ == '__main__':
    sys.exit(main())
