"""Benchmark: force_tester_common.core.events.median against np.median on pull-sized records
(./ft bench median [--samples 25000,100000,400000] [--reps 200]).

The short-event baselines of `./ft bag correct` and discovery's friction and overload take a whole pull's median
many times a pull; events.median is the hand-written selection that replaces np.median there. This prints, for
each length, the median time of each (alternating, in this process) and the ratio, on a noisy, spiky record like a
cell's (a ramp and a pull on noise), and checks the two values are equal.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from force_tester_common.core.events import median


def record(n: int, rng: np.random.Generator) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)
    pull = 4000.0 * np.clip((t - 0.4) / 0.2, 0.0, 1.0) * (t < 0.7)
    return pull + rng.normal(0.0, 2.0, n) + rng.standard_cauchy(n) * 0.01


def timed(f, x: np.ndarray) -> tuple[float, float]:
    t0 = time.perf_counter()
    v = f(x)
    return time.perf_counter() - t0, float(v)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--samples', default='25000,100000,400000', help='record lengths, comma-separated')
    p.add_argument('--reps', type=int, default=200, help='timed calls of each, alternating')
    a = p.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"{'samples':>9} {'np.median ms':>13} {'events.median ms':>17} {'ratio':>6}  equal")
    for n in (int(s) for s in a.samples.split(',')):
        x = record(n, rng)
        ours, theirs, same = [], [], True
        for _ in range(a.reps):
            dt, v = timed(np.median, x)
            theirs.append(dt)
            dt, w = timed(median, x)
            ours.append(dt)
            same &= v == w
        t_np, t_ev = np.median(theirs) * 1e3, np.median(ours) * 1e3
        print(f'{n:>9} {t_np:>13.3f} {t_ev:>17.3f} {t_np / t_ev:>5.1f}x  {same}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
