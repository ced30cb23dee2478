"""A channel shifted in time by any amount, band-limited (exact in the frequency domain): a sensor's delay as the
simulator applies it (departures: accel_delay) and as discovery fits it. ROS-free."""
from __future__ import annotations

import numpy as np


class Shifter:
    """x(t + d) for any d, band-limited (exact in the frequency domain; the end trend removed first and put
    back): the spectrum computed once. A physical delay (a sensor's, a DAQ's channel skew) is a shift, and a
    shift, unlike an interpolation between samples, does not low-pass what it moves."""

    def __init__(self, x: np.ndarray, dt: float):
        n = len(x)
        self.n, self.dt = n, dt
        self.trend = np.linspace(x[0], x[-1], n)
        self.slope = (x[-1] - x[0]) / (dt * (n - 1))
        self.X = np.fft.rfft(x - self.trend)
        self.w = 2 * np.pi * np.fft.rfftfreq(n, dt)

    def __call__(self, d: float) -> np.ndarray:
        return np.fft.irfft(self.X * np.exp(1j * self.w * d), self.n) + self.trend + self.slope * d

    def rate(self) -> np.ndarray:
        """dx/dt, band-limited (what a shift by a small d adds, per unit d)."""
        return np.fft.irfft(self.X * 1j * self.w, self.n) + self.slope


__all__ = ['Shifter']
