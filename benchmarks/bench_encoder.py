"""Benchmark: the encoder's Savitzky-Golay fit (force_discovery.core.prep.as_encoder) against scipy's savgol_filter
on pull-sized records (./ft bench encoder [--samples 25000,100000] [--rate 50000] [--reps 30]).

Discovery derives the carriage's position, speed and acceleration from the encoder of every pull (and smooths a2
so in the search beyond the catalog). as_encoder convolves the interior by scipy's overlap-add and takes
savgol_filter's own end fits. This prints, per record length, the median time of x3, v3 and a3 together by each
(alternating, in this process), the ratio, and the largest difference relative to each derivative's largest value.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.signal import savgol_filter

from force_discovery.core.prep import as_encoder, encoder_window


def motion(n: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """An encoder-like position: a launch ramp, a cruise and a stop, quantised to 1 um, with a little jitter."""
    t = np.arange(n) * dt
    v = 4.0 * np.clip(t / (0.3 * t[-1]), 0.0, 1.0) * (t < 0.8 * t[-1])
    x = np.cumsum(v) * dt + 2e-7 * rng.standard_normal(n)
    return np.round(x * 1e6) / 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--samples', default='25000,100000', help='record lengths, comma-separated (default 25000,100000)')
    ap.add_argument('--rate', type=float, default=50000.0, help='sample rate, Hz (default 50000)')
    ap.add_argument('--reps', type=int, default=30, help='timed runs of each per length (default 30)')
    args = ap.parse_args(argv)
    dt = 1.0 / args.rate
    win = encoder_window(dt)
    rng = np.random.default_rng(42)
    print(f'x3, v3 and a3 of one record at {args.rate:g} Hz ({win} taps), median of {args.reps} runs each, alternately')
    for n in (int(s) for s in args.samples.split(',')):
        x = motion(n, dt, rng)
        times = {'scipy savgol_filter': [], 'as_encoder': []}
        for _ in range(args.reps):
            for name in times:
                t0 = time.perf_counter()
                if name == 'as_encoder':
                    out = [as_encoder(x, dt, k) for k in range(3)]
                else:
                    ref = [savgol_filter(x, win, 3, deriv=k, delta=dt) for k in range(3)]
                times[name].append(time.perf_counter() - t0)
        diff = max(float(np.max(np.abs(a - b)) / np.max(np.abs(b))) for a, b in zip(out, ref))
        med = {k: float(np.median(v)) for k, v in times.items()}
        print(f'  {n:7d} samples: savgol_filter {1e3 * med["scipy savgol_filter"]:6.2f} ms, as_encoder '
              f'{1e3 * med["as_encoder"]:6.2f} ms, {med["scipy savgol_filter"] / med["as_encoder"]:.2f}x; '
              f'largest difference {diff:.1e} of the largest value')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
