"""Builders of serialized force_tester_msgs messages for the ROS-free bag tests."""
from pathlib import Path

import numpy as np

from bag_tools.core.typestore import make_typestore

MSG_DIR = Path(__file__).resolve().parents[1] / 'src' / 'force_tester_msgs' / 'msg'
FORCE = 'force_tester_msgs/msg/ForceBlock'


def bag_typestore():
    return make_typestore([MSG_DIR])


def header(store, ns):
    T = store.types
    return T['std_msgs/msg/Header'](
        stamp=T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9),
        frame_id='tester')


def force(store, ns, seq, n=5):
    msg = store.types[FORCE](header=header(store, ns), sample_rate_hz=1000.0, seq=seq,
                             moving_n=np.arange(n, dtype=np.float64) + seq,
                             stationary_n=np.full(n, 2.5))
    return store.serialize_cdr(msg, FORCE)
