"""What the monitor's subprotocol gate costs: `./ft bench gate [--messages N] [--reps R]`.

foxglove-sdk's server alone, and the same server behind the monitor's gate (core/subprotocol.py), each send N
/force_corrected messages (500-sample CorrectedForceBlocks, 16 kB each, as the live graph's 10 ms blocks) to
the Foxglove npm client (tools/foxglove_client), which decodes every one. Direct and gated runs alternate, R
of each, in one process. Prints, per 1000 messages: the gate thread's CPU time, and the whole process's
(server + gate), and the wall time until the client had all N; and the gate's CPU at the live graph's 100
/force_corrected messages a second, as a share of one core.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / 'tests' / 'force_tester_monitor'))   # the Foxglove client's helpers (fox_client)

from fox_client import client_command, lines  # noqa: E402

TOPIC = '/force_corrected'
TYPE = 'force_tester_msgs/msg/CorrectedForceBlock'


def message_bytes(store, n: int = 500) -> bytes:
    from force_tester_common.core.channels import CORRECTED_FIELDS
    cls = store.types[TYPE]
    hdr = store.types['std_msgs/msg/Header'](
        stamp=store.types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='')
    rng = np.random.default_rng(0)
    fields = {f: rng.normal(size=n) for f in CORRECTED_FIELDS}
    kwargs = {a: 0 for a in cls.__dataclass_fields__ if a not in fields and a != 'header'}
    return bytes(store.serialize_cdr(cls(header=hdr, **fields, **kwargs), TYPE))


def thread_cpu(name: str) -> float:
    """CPU seconds of this process's thread called ``name`` (0 if there is none)."""
    ids = [t.native_id for t in threading.enumerate() if t.name == name]
    return sum(t.user_time + t.system_time for t in psutil.Process().threads() if t.id in ids)


def one_run(channel, port: int, legacy: bool, n: int, data: bytes) -> dict:
    args = ['--topics', TOPIC, '--until', f'{TOPIC}={n}', '--keep', f'{TOPIC}=0', '--timeout', '300']
    client = subprocess.Popen(client_command(port, *(['--legacy'] if legacy else []), *args),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc = psutil.Process()
    gate0, cpu0, t0 = thread_cpu('foxglove-gate'), sum(proc.cpu_times()[:2]), time.monotonic()
    deadline = t0 + 300
    while client.poll() is None and time.monotonic() < deadline:
        channel.log(data)          # as fast as the client takes them; the backlog drops what it cannot
        time.sleep(0.001)
    out, err = client.communicate(timeout=60)
    done = [r for r in lines(out) if r['kind'] == 'done']
    assert done and done[0]['counts'].get(TOPIC, 0) >= n, (out[-500:], err[-500:])
    return {'wall_s': time.monotonic() - t0, 'cpu_s': sum(proc.cpu_times()[:2]) - cpu0,
            'gate_s': thread_cpu('foxglove-gate') - gate0, 'n': done[0]['counts'][TOPIC]}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--messages', type=int, default=3000, help='messages per run (default 3000)')
    p.add_argument('--reps', type=int, default=3, help='runs of each kind, alternating (default 3)')
    a = p.parse_args()
    import foxglove
    from force_tester_monitor.core.subprotocol import SubprotocolGate

    from bag_tools.core.typestore import default_typestore
    store = default_typestore()
    definition = store.generate_msgdef(TYPE, ros_version=2)[0]
    server = foxglove.start_server(name='bench gate', host='127.0.0.1', port=0, message_backlog_size=100_000)
    channel = foxglove.Channel(TOPIC, message_encoding='cdr',
                               schema=foxglove.Schema(name=TYPE, encoding='ros2msg', data=definition.encode()))
    gate = SubprotocolGate('127.0.0.1', 0, server.port)
    data = message_bytes(store)
    runs = {'direct (SDK, foxglove.sdk.v1)': [], 'gated (old client, foxglove.websocket.v1)': []}
    try:
        for rep in range(a.reps):
            for label, port, legacy in (('direct (SDK, foxglove.sdk.v1)', server.port, False),
                                        ('gated (old client, foxglove.websocket.v1)', gate.port, True)):
                r = one_run(channel, port, legacy, a.messages, data)
                runs[label].append(r)
                print(f'rep {rep + 1}/{a.reps} {label}: {r["n"]} messages in {r["wall_s"]:.2f} s', flush=True)
    finally:
        gate.close()
        server.stop()
    print(f'\n{len(data)} bytes a message, {a.messages} messages a run, {a.reps} runs each; medians per 1000 messages:')
    print(f'{"":45} {"wall s":>8} {"process CPU s":>14} {"gate CPU s":>11}')
    for label, rs in runs.items():
        med = {k: float(np.median([r[k] / r['n'] * 1000 for r in rs])) for k in ('wall_s', 'cpu_s', 'gate_s')}
        print(f'{label:45} {med["wall_s"]:8.3f} {med["cpu_s"]:14.3f} {med["gate_s"]:11.3f}')
    gate_ms = float(np.median([r['gate_s'] / r['n'] for r in runs['gated (old client, foxglove.websocket.v1)']]))
    print(f'the gate at the live graph\'s 100 {TOPIC} messages a second: {gate_ms * 100 * 100:.2f} % of one core')


if __name__ == '__main__':
    main()
