"""Carriage motion sources: x3(t), v3(t), a3(t), the input u of the force-chain model.

A motion source is anything with ``kinematics(t) -> (x, v, a)`` (t in seconds, scalar or array,
measured from the start of the record) and ``command_velocity(t)``. ``PrescribedMotion`` is the
stand-in until the motor/PID drive model produces x3(t).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, Tuple

import numpy as np

from .errors import SimError

# Motion profile choices (documented in the package README).
PRE_TRIGGER_S = 0.3          # carriage at rest for this long after the record starts
ACCEL_PEAK_M_S2 = 50.0       # peak of the smooth (sin^2) launch pulse, ~5.1 g (drive can do ~8 g at 66 A)
BRAKE_M_S2 = 50.0            # braking plateau after the pull
DECEL_ONSET_S = 1.0e-3       # the -1.24 g of sets 4/5 builds up over 1 ms from the taut instant
BRAKE_RAMP_S = 0.02          # raised-cosine ramp into and out of the braking plateau
MIN_HOLD_S = 0.02            # carriage keeps going at least this long after taut before braking
TARGET_TAUT_S = 0.7          # nominal slack puts the taut instant here if the track allows it
TRACK_MARGIN_M = 0.05        # nominal stop point stays this far inside the usable track


class MotionSource(Protocol):
    def kinematics(self, t) -> Tuple[np.ndarray, np.ndarray, np.ndarray]: ...

    def kinematics_scalar(self, t: float) -> Tuple[float, float, float]: ...

    def command_velocity(self, t) -> np.ndarray: ...


@dataclass(frozen=True)
class AccelStep:
    """Acceleration changes by ``delta_m_s2`` along a raised cosine from ``start_s`` over ``duration_s``."""
    start_s: float
    delta_m_s2: float
    duration_s: float


@dataclass(frozen=True)
class PrescribedMotion:
    """Carriage kinematics as a sum of raised-cosine acceleration steps (x, v, a exact in closed form).

    The carriage is at rest at x3 = 0 until ``steps[0]``; after ``stop_s`` it is held exactly at rest.
    """
    steps: Tuple[AccelStep, ...]
    stop_s: float
    taut_s: float                 # instant the carriage reaches the slack length (geometric taut)
    brake_s: float                # start of braking
    command_scale: float = 1.0    # commanded / actual speed (the prescribed drive tracks within ~1 %)

    def _raw(self, t):
        t = np.asarray(t, dtype=float)
        x = np.zeros_like(t)
        v = np.zeros_like(t)
        a = np.zeros_like(t)
        for st in self.steps:
            d, T = st.delta_m_s2, st.duration_s
            tau = (t - st.start_s) / T
            inside = (tau > 0.0) & (tau < 1.0)
            after = tau >= 1.0
            over = tau[after] - 1.0
            a[after] += d
            v[after] += d * T * (0.5 + over)
            x[after] += d * T * T * (0.25 - 1.0 / np.pi ** 2 + 0.5 * over + 0.5 * over * over)
            ti = tau[inside]
            c, s_ = np.cos(np.pi * ti), np.sin(np.pi * ti)
            a[inside] += d * 0.5 * (1.0 - c)
            v[inside] += d * T * (ti / 2.0 - s_ / (2.0 * np.pi))
            x[inside] += d * T * T * (ti * ti / 4.0 + (c - 1.0) / (2.0 * np.pi ** 2))
        return x, v, a

    def _raw_scalar(self, t: float):
        x = v = a = 0.0
        for st in self.steps:
            tau = (t - st.start_s) / st.duration_s
            if tau <= 0.0:
                continue
            d, T = st.delta_m_s2, st.duration_s
            if tau >= 1.0:
                over = tau - 1.0
                a += d
                v += d * T * (0.5 + over)
                x += d * T * T * (0.25 - 1.0 / math.pi ** 2 + 0.5 * over + 0.5 * over * over)
            else:
                c, s_ = math.cos(math.pi * tau), math.sin(math.pi * tau)
                a += d * 0.5 * (1.0 - c)
                v += d * T * (tau / 2.0 - s_ / (2.0 * math.pi))
                x += d * T * T * (tau * tau / 4.0 + (c - 1.0) / (2.0 * math.pi ** 2))
        return x, v, a

    def kinematics_scalar(self, t: float):
        """Fast path of ``kinematics`` for one float time (used inside the ODE solver)."""
        if t >= self.stop_s:
            return self._raw_scalar(self.stop_s)[0], 0.0, 0.0
        return self._raw_scalar(t)

    def kinematics(self, t):
        t = np.asarray(t, dtype=float)
        x, v, a = self._raw(t)
        after = t >= self.stop_s
        if np.any(after):
            x_stop = self._raw_scalar(self.stop_s)[0]
            x = np.where(after, x_stop, x)
            v = np.where(after, 0.0, v)
            a = np.where(after, 0.0, a)
        return x, v, a

    def command_velocity(self, t):
        return self.kinematics(t)[1] * self.command_scale

    @property
    def final_position_m(self) -> float:
        return float(self._raw_scalar(self.stop_s)[0])

    @classmethod
    def build(cls, velocity_m_s: float, slack_m: float, decel_m_s2: float = 0.0, hold_s: float = MIN_HOLD_S,
              pre_trigger_s: float = PRE_TRIGGER_S, accel_peak_m_s2: float = ACCEL_PEAK_M_S2,
              brake_m_s2: float = BRAKE_M_S2, command_velocity_m_s: float | None = None) -> 'PrescribedMotion':
        """Rest, sin^2 launch pulse to ``velocity_m_s``, cruise until x3 = ``slack_m`` (taut), then
        (``decel_m_s2`` < 0) decelerate from the taut instant, and ``hold_s`` after taut brake to a stop."""
        v = float(velocity_m_s)
        if not v > 0:
            raise SimError(f'velocity {v!r} m/s is not positive; expected a pull speed > 0')
        if decel_m_s2 > 0:
            raise SimError(f'decel {decel_m_s2!r} m/s^2 is positive; expected <= 0 (a deceleration)')
        if hold_s < DECEL_ONSET_S:
            raise SimError(f'hold {hold_s!r} s is too short; expected >= {DECEL_ONSET_S} s')
        t_ramp = v / accel_peak_m_s2
        launch = v * t_ramp
        if slack_m < launch:
            raise SimError(f'slack {slack_m!r} m is shorter than the launch distance {launch:.4f} m; '
                           f'expected slack >= {launch:.4f} m at {v:.3f} m/s')
        steps = [AccelStep(pre_trigger_s, accel_peak_m_s2, t_ramp),
                 AccelStep(pre_trigger_s + t_ramp, -accel_peak_m_s2, t_ramp)]
        t_taut = pre_trigger_s + 2 * t_ramp + (slack_m - launch) / v
        a_c = float(decel_m_s2)
        if a_c != 0.0:
            steps.append(AccelStep(t_taut, a_c, DECEL_ONSET_S))
        t_brake = t_taut + hold_s
        v_b = v + a_c * (hold_s - DECEL_ONSET_S / 2) if a_c != 0.0 else v
        if v_b <= 0:
            raise SimError(f'the carriage stops {v / -a_c:.4f} s after taut under decel {a_c} m/s^2; '
                           f'expected it to be still moving at the brake start ({hold_s} s after taut)')
        t_b = min(BRAKE_RAMP_S, v_b / (brake_m_s2 - a_c / 2))
        plateau = max(0.0, (v_b + a_c * t_b / 2) / brake_m_s2 - t_b)
        steps.append(AccelStep(t_brake, -brake_m_s2 - a_c, t_b))
        steps.append(AccelStep(t_brake + t_b + plateau, brake_m_s2, t_b))
        t_stop = t_brake + 2 * t_b + plateau
        scale = 1.0 if command_velocity_m_s is None else float(command_velocity_m_s) / v
        return cls(tuple(steps), t_stop, t_taut, t_brake, scale)

    def check_fits(self, usable_track_m: float, record_length_s: float) -> None:
        if self.stop_s > record_length_s:
            raise SimError(f'the carriage stops at {self.stop_s:.4f} s; expected within the '
                           f'{record_length_s} s record')
        x_end = self.final_position_m
        if x_end > usable_track_m:
            raise SimError(f'the carriage travels {x_end:.4f} m; expected within the usable track '
                           f'{usable_track_m} m')


@dataclass(frozen=True, eq=False)
class SampledMotion:
    """Carriage kinematics given as samples (e.g. a measured record): x, v, a linearly interpolated between the
    samples (the integrator's first-order hold assumes the same), the first sample held before ``t[0]`` and the
    last after ``t[-1]``. ``t`` strictly increasing; a uniform grid takes a fast path for scalar times."""
    t: np.ndarray
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray
    command_scale: float = 1.0

    def __post_init__(self):
        arrs = [np.asarray(getattr(self, k), dtype=float) for k in ('t', 'x', 'v', 'a')]
        n = len(arrs[0])
        if n < 2 or any(arr.shape != (n,) for arr in arrs):
            raise SimError(f'sampled motion has shapes {[arr.shape for arr in arrs]}; expected four equal 1-D '
                           'arrays of at least 2 samples')
        if not all(np.all(np.isfinite(arr)) for arr in arrs):
            raise SimError('sampled motion has non-finite samples; expected finite t, x, v, a')
        steps = np.diff(arrs[0])
        if not np.all(steps > 0):
            raise SimError(f'sampled motion times step by {steps.min()!r} s at the least; expected strictly '
                           'increasing times')
        for k, arr in zip(('t', 'x', 'v', 'a'), arrs):
            object.__setattr__(self, k, arr)
        h = float(steps.mean())
        object.__setattr__(self, '_h', h if np.ptp(steps) <= 1e-9 * h else None)

    def kinematics(self, t):
        t = np.asarray(t, dtype=float)
        return tuple(np.interp(t, self.t, y) for y in (self.x, self.v, self.a))

    def kinematics_scalar(self, t: float):
        h = self._h
        if h is None:
            return tuple(float(y) for y in self.kinematics(float(t)))
        s = (t - self.t[0]) / h
        n = len(self.t)
        if s <= 0.0:
            return float(self.x[0]), float(self.v[0]), float(self.a[0])
        if s >= n - 1:
            return float(self.x[-1]), float(self.v[-1]), float(self.a[-1])
        i = int(s)
        f = s - i
        return tuple(float(y[i] + f * (y[i + 1] - y[i])) for y in (self.x, self.v, self.a))

    def command_velocity(self, t):
        return self.kinematics(t)[1] * self.command_scale


def hold_time_s(coupon_break_n: float, velocity_m_s: float, series_stiffness_n_per_m: float,
                break_duration_s: float) -> float:
    """Time from taut to braking: >= MIN_HOLD_S and 3x the expected time to load the coupon to break."""
    t_load = coupon_break_n / (series_stiffness_n_per_m * velocity_m_s)
    return max(MIN_HOLD_S, 3.0 * t_load + break_duration_s + 2.0e-3)


def nominal_slack_m(velocity_m_s: float, decel_m_s2: float, hold_s: float, usable_track_m: float,
                    target_taut_s: float = TARGET_TAUT_S) -> float:
    """Slack that puts the taut instant at ``target_taut_s`` unless the track is too short for that,
    in which case the largest slack that stops the carriage TRACK_MARGIN_M inside the track."""
    v = velocity_m_s
    t_ramp = v / ACCEL_PEAK_M_S2
    launch = v * t_ramp
    slack = launch + max(0.0, target_taut_s - PRE_TRIGGER_S - 2 * t_ramp) * v
    probe = PrescribedMotion.build(v, slack, decel_m_s2, hold_s)
    beyond = probe.final_position_m - slack          # travel after taut, independent of slack
    slack = min(slack, usable_track_m - TRACK_MARGIN_M - beyond)
    if slack < launch:
        raise SimError(f'{v:.3f} m/s cannot be reached and stopped within the usable track '
                       f'{usable_track_m} m; expected a slower pull')
    return float(slack)


__all__ = ['MotionSource', 'AccelStep', 'PrescribedMotion', 'SampledMotion', 'hold_time_s', 'nominal_slack_m',
           'PRE_TRIGGER_S', 'ACCEL_PEAK_M_S2', 'BRAKE_M_S2']
