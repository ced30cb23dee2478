"""Benchmark: what one block message costs in rclpy, apart from the arithmetic (./ft bench messages).

Part 1, in this process (no DDS): per CorrectedForceBlock (four float64[] fields of N samples) and
per AccelBlock, for N = 50, 100, 250 and 500:
  - filling the fields from numpy arrays: as array.array (what the nodes do), as a numpy array and
    as a Python list (the generated setters check every element of anything but array.array);
  - rclpy's serialize_message and deserialize_message (the Python <-> C conversion and the CDR
    encoding that publish and take do on every message);
  - reading a received field as numpy (np.frombuffer on the array.array, no copy).
Part 2, live (--seconds S, default 10; 0 skips it): the correction node against a relay node that
does none of the arithmetic (it takes /force and /accel and publishes the force block as
/force_corrected, one for one), each as its own process under the same paced 50 kHz input, one
after the other, for each block size. The relay's CPU is the floor rclpy and DDS set for this
message pattern; the correction's CPU above it is the workspace's own Python.
"""
from __future__ import annotations

import argparse
import array
import subprocess
import sys
import time
import timeit
from pathlib import Path

import numpy as np

SIZES = (50, 100, 250, 500)


def per_call_us(fn, budget_s: float = 0.3) -> float:
    t = timeit.Timer(fn)
    n, _ = t.autorange()
    n = max(1, int(n * budget_s / 0.2))
    return min(t.repeat(3, n)) / n * 1e6


def part1() -> None:
    from force_tester_msgs.msg import AccelBlock, CorrectedForceBlock
    from rclpy.serialization import deserialize_message, serialize_message

    from force_tester_common.conversions import to_array
    print('part 1: one message in this process, microseconds per message (best of 3)')
    print(f"{'N':>4} {'fill array.array':>16} {'fill numpy':>10} {'fill list':>9} {'serialize':>9} "
          f"{'deserialize':>11} {'frombuffer':>10} {'accel ser+de':>12}")
    for n in SIZES:
        row = _costs(n, CorrectedForceBlock, AccelBlock, serialize_message, deserialize_message, to_array)
        print(f'{n:>4} {row[0]:16.1f} {row[1]:10.1f} {row[2]:9.1f} {row[3]:9.1f} {row[4]:11.1f} {row[5]:10.2f} '
              f'{row[6]:12.1f}')


def _costs(n, CorrectedForceBlock, AccelBlock, serialize_message, deserialize_message, to_array) -> list:
    data = np.linspace(0.0, 1.0, n)
    fields = ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')

    def fill(convert):
        def run():
            m = CorrectedForceBlock()
            for f in fields:
                setattr(m, f, convert(data))
            return m
        return run
    fill_aa = fill(lambda a: array.array('d', a.tobytes()))
    fill_np = fill(lambda a: a)
    fill_list = fill(lambda a: a.tolist())
    msg = fill_aa()
    raw = serialize_message(msg)
    got = deserialize_message(raw, CorrectedForceBlock)
    assert np.array_equal(to_array(got.filtered_n), data)
    accel = AccelBlock()
    accel.axial_m_s2 = array.array('d', data.tobytes())
    return [per_call_us(fill_aa), per_call_us(fill_np), per_call_us(fill_list),
            per_call_us(lambda: serialize_message(msg)),
            per_call_us(lambda: deserialize_message(raw, CorrectedForceBlock)),
            per_call_us(lambda: to_array(got.filtered_n)),
            per_call_us(lambda: deserialize_message(serialize_message(accel), AccelBlock))]


def part2(seconds: float) -> None:
    bench = Path(__file__).with_name('bench_correction.py')
    print(f'\npart 2: live, {seconds:g} s of 50 kHz per run; CPU share of one core of the node process')
    print(f"{'N':>4} {'relay (no arithmetic)':>22} {'correction node':>16} {'correction - relay':>19}")
    for n in SIZES:
        cpu = {}
        for who in ('relay', 'correction'):
            res = subprocess.run([sys.executable, str(bench), '--seconds', str(seconds), '--block', str(n),
                                  *(['--relay'] if who == 'relay' else [])], capture_output=True, text=True)
            line = next((ln for ln in res.stdout.splitlines() if 'node CPU' in ln), None)
            if line is None:
                raise SystemExit(f'bench messages: the {who} run failed:\n{res.stdout[-2000:]}{res.stderr[-2000:]}')
            cpu[who] = float(line.split('=')[1].split('%')[0]) / 100
        print(f"{n:>4} {100 * cpu['relay']:21.1f}% {100 * cpu['correction']:15.1f}% "
              f"{100 * (cpu['correction'] - cpu['relay']):18.1f}%")


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench messages', description=__doc__.splitlines()[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog='\n'.join(__doc__.splitlines()[2:]))
    ap.add_argument('--seconds', type=float, default=10.0, help='live run length per node and size (0: skip)')
    args = ap.parse_args()
    t = time.monotonic()
    part1()
    if args.seconds > 0:
        part2(args.seconds)
    print(f'\n({time.monotonic() - t:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
