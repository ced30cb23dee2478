"""Close the loop through the simulator: re-simulate measured pulls with the model of record
and with the model of record plus a discovered extension, and compare each simulated channel with the measured one.
ROS-free.

Per pull, from that pull's own measured channels only:

- the carriage motion: the encoder's x3, v3, a3 (the Pull's Savitzky-Golay estimates) drive the force chain
  through a ``SampledMotion`` (no motion model, no commanded speed);
- the per-pull quantities (``PullQuantities``): lanyard slack and stiffness, coupon yield and hardening (when the
  tension shows a plastic flow), break instant and duration, fitted by least squares to the measured lanyard
  tension T (stationary cell + m1 a1, prep.prepare) with a quasi-static chain: in the taut pieces the cells
  (and a mount, when the model has one) are springs in series with the lanyard,
      T_el   = (K_L (x3 - slack) + c_L v3) / (1 + K_L C),        C = 1/K_LC1 + 1/K_LC2 (+ 1/k_mount)
      T_flow = (k_p (x3 - slack + F_y/H) + c_p v3) / (1 + k_p C), k_p = K_L H/(K_L + H), c_p = c_L H/(K_L + H)
      T = beta(t) [max(0, min(T_el, T_flow)) + D(t)],  beta falling linearly from the break instant over the break
      duration (averaged over each sample interval, so a break shorter than a sample still has a position),
  passed through the same 7-9 kHz zero-phase low-pass as the measured T. D is the chain's dynamic part (the cell
  and mount modes the quasi-static chain leaves out): an unbroken sim of the model over the fit window minus its
  quasi-static tension, refitted DYNAMIC_PASSES times (defect correction). The break force is then calibrated on
  that sim: the sim breaks when F_stat first reaches it, and F_stat rings, so it is set where the sim's F_stat
  crosses it nearest the fitted break instant. Each model (baseline, extended) fits its own quantities;
- the mains-hum phase (random per pull) when the extension has a hum: fitted on the pull's pre-pull record;
- each sinusoid term's phase (extra_terms: a frame mode excited afresh each pull) when the extension has one:
  fitted on the pull's analysis window with the amplitude fixed at the campaign's coefficient (sin_phases).

Once per check, from the pulls checked: the cells' damping ratio, from the stationary cell's free decay after the
break (m1 alone on its cell); both models use it (``calibrate``), since the cells ring after every fast break and a
wrong decay rate would swamp what an extension changes.

``resimulate`` runs the sim core (``run_pull_with_motion``, noise off) and records the channels as the sim does:
sensor departures through ``apply_sensor_departures``, the motor current from the drive's force balance with the
measured motion, i kf = m_c a3 + b v3 + F_move (+ F_c sign(v3) with coulomb_friction). ``simulation_check`` compares
measured and simulated channels on the held-out pulls: RMS over each pull's analysis window after the discovery
low-pass, per channel, pooled over the pulls (force samples where the measured cell is at its range left out), for
the baseline and the extended model; gain = baseline RMS / extended RMS. For a mount resonance it also compares the
free-decay ring frequency (a2 - a3 after the break, matrix pencil) of the extended sim with the measured one.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Dict, Mapping, Optional, Sequence

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares

from force_tester_common.core.units import LBF_N
from force_tester_sim.core.chain import ChainParams
from force_tester_sim.core.departures import Departures, apply_sensor_departures
from force_tester_sim.core.errors import SimError
from force_tester_sim.core.extra_terms import CHANNEL_COLUMNS, ExtraTerm, extra_channels, signals
from force_tester_sim.core.motion import SampledMotion
from force_tester_sim.core.pull import PullSpec, run_pull_with_motion

from .cells import cell_damping_ratio
from .errors import DiscoveryError
from .friction import STILL_M_S, drive_force_balance
from .hum import hum_per_pull
from .prep import Pull, filtered
from .ringing import MOUNT_MAX_FRACTION, matrix_pencil, ring_segment

SIM_CHANNELS = ('force_moving_n', 'force_stationary_n', 'accel_axial_m_s2', 'motor_current_a')
FORCE_CHANNELS = SIM_CHANNELS[:2]
FIT_LEAD_S = 3e-3          # the tension fit starts this long before the loaded start (lanyard still slack) ...
FIT_TAIL_S = 3e-3          # ... and ends this long after the break
MIN_BREAK_S = 1e-6         # break durations are fitted down to this (a sample is 20 us: below it they hardly show)
YIELD_KNEE = 0.3           # the tension rate falling below this fraction of the elastic rate marks a yield
BREAK_MARGIN_N = 0.05      # the calibrated break force stays this far off an F_stat peak (_break_force)
DYNAMIC_PASSES = 2         # defect-correction passes of the per-pull fit (fit_pull_quantities)
RING_SAMPLES = 400         # free-decay samples for the ring frequency (8 ms; a longer matrix pencil is slow)
RING_PULLS = 6             # ring frequencies compared on at most this many pulls (matrix pencils are slow)
SATURATION_SHARE = 0.98    # measured force samples beyond this share of the cells' range are not compared
RING_TOLERANCE = 0.02      # the extended sim rings at the measured frequency within 2 %


@dataclass(frozen=True)
class PullQuantities:
    """One pull's own quantities (what a pull-to-pull scatter changes), fitted from that pull's measured T."""

    slack_m: float
    lanyard_stiffness_n_per_m: float
    coupon_break_n: float                               # F_stat at which the model's sim breaks at break_time_s
    break_duration_s: float
    coupon_yield_n: Optional[float] = None             # None: elastic to the break
    coupon_hardening_n_per_m: Optional[float] = None
    break_time_s: float = float('nan')                  # the fitted break instant (the break force reproduces it)
    rms_n: float = float('nan')                         # rms misfit of the low-passed tension model, fit window

    def spec(self, velocity_m_s: float) -> PullSpec:
        """A PullSpec carrying these quantities (speed only labels it: the measured motion drives the sim)."""
        return PullSpec(test_set=0, coupon_break_n=self.coupon_break_n, velocity_m_s=velocity_m_s, decel_m_s2=0.0,
                        slack_m=self.slack_m, lanyard_stiffness_n_per_m=self.lanyard_stiffness_n_per_m,
                        break_duration_s=self.break_duration_s, seed=0, coupon_yield_n=self.coupon_yield_n,
                        coupon_hardening_n_per_m=self.coupon_hardening_n_per_m)

    def as_dict(self) -> dict:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


def with_departures(rig, departures: Departures):
    """The rig plus the extension's entries (an entry of the same name is replaced)."""
    deps = rig.departures
    for d in departures.entries:
        deps = deps.with_entry(d.name, **dict(d.params))
    return dataclasses.replace(rig, departures=deps)


def _chain(rig, kl: float = 1.0) -> ChainParams:
    return ChainParams.from_rig(rig, slack_m=1.0, break_n=1.0, break_duration_s=1.0, lanyard_stiffness_n_per_m=kl)


def quasi_static_tension(t, x3, v3, params, C: float, zeta_l: float, mu: float, dynamic=None) -> np.ndarray:
    """Lanyard tension of the quasi-static chain (module docstring) on the samples t for params
    (K_L, slack, F_y (inf: no yield), H, break instant tb (inf: no break), break duration); ``dynamic`` is added
    to the unbroken tension (fit_pull_quantities' defect correction)."""
    kl, slack, fy, hard, tb, dur = params
    cl = 2.0 * zeta_l * math.sqrt(kl * mu)
    T = (kl * (x3 - slack) + cl * v3) / (1.0 + kl * C)
    if math.isfinite(fy):
        f = hard / (kl + hard)
        kp = kl * f
        T = np.minimum(T, (kp * (x3 - slack + fy / hard) + cl * f * v3) / (1.0 + kp * C))
    T = np.maximum(T, 0.0) if dynamic is None else np.maximum(T, 0.0) + dynamic
    return T if math.isinf(tb) else T * sample_beta(t, tb, dur)


def sample_beta(t, tb: float, dur: float) -> np.ndarray:
    """The coupon's load fraction beta (1 until tb, linearly 0 at tb + dur) averaged over each sample interval
    [t - dt/2, t + dt/2]: a break shorter than a sample still moves smoothly with tb and dur."""
    h = float(t[1] - t[0])

    def broken(te):   # integral of the broken fraction clip((te - tb)/dur, 0, 1) up to te, in seconds
        u = np.clip((te - tb) / dur, 0.0, None)
        return dur * np.where(u <= 1.0, 0.5 * u * u, u - 0.5)
    return 1.0 - (broken(t + h / 2) - broken(t - h / 2)) / h


def _initial(p: Pull, s: slice, C: float):
    """First guesses from the measured T: elastic slope, where it starts, knee (yield), flow slope, break instant
    and fall time."""
    T, x3, v3 = p.T[s], p.x3[s], p.v3[s]
    dt = p.dt
    ipk = int(np.argmax(T))
    tpk = float(T[ipk])
    rate = np.gradient(T, dt)
    # the elastic rise: the steepest rate before T first reaches half its peak (the break's edge, later, is steeper)
    half_up = int(np.flatnonzero(T >= 0.5 * tpk)[0])
    ir = int(np.argmax(rate[:half_up + 3]))
    v = max(float(v3[ir]), 1e-3)
    k_app = rate[ir] / v                                      # apparent (series) stiffness
    kl = k_app / max(1e-3, 1.0 - k_app * C)
    x_zero = x3[ir] - T[ir] / k_app                            # where the elastic line reaches T = 0
    # yield: after the steepest rise, the first sample where the rate falls below YIELD_KNEE x the elastic rate
    knee = np.flatnonzero(rate[ir:ipk + 1] < YIELD_KNEE * rate[ir])
    fy, hard = math.inf, 0.0
    if len(knee):
        iy = ir + int(knee[0])
        if T[iy] < 0.97 * tpk and ipk - iy >= 4:
            fy = float(T[iy])
            seg = slice(iy + (ipk - iy) // 4, iy + 3 * (ipk - iy) // 4 + 1)
            if seg.stop - seg.start >= 2 and np.ptp(x3[seg]) > 0:
                k_flow = float(np.polyfit(x3[seg], T[seg], 1)[0])
                kp = k_flow / max(1e-3, 1.0 - k_flow * C)
                if 0 < kp < 0.9 * kl:
                    hard = kp * kl / (kl - kp)
            if hard <= 0:
                fy = math.inf
    # break: T falls from 90 % to 10 % of the peak in about 0.8 x its duration; the middle is tb + dur/2
    after = np.flatnonzero(T[ipk:] < 0.1 * tpk)
    i10 = ipk + (int(after[0]) if len(after) else 1)
    above = np.flatnonzero(T[ipk:i10] > 0.9 * tpk)
    i90 = ipk + (int(above[-1]) if len(above) else 0)
    dur = max(MIN_BREAK_S, (i10 - i90) * dt / 0.8)
    half = ipk + int(np.flatnonzero(T[ipk:] < 0.5 * tpk)[0]) if np.any(T[ipk:] < 0.5 * tpk) else ipk
    tb = float(p.t[s][half]) - dur / 2
    return kl, x_zero, fy, hard, tb, dur, v


def _unbroken_run(pull: Pull, rig, i0: int, i1: int, q: 'PullQuantities') -> Dict[str, np.ndarray]:
    """The sim's clean signals on samples i0:i1 (lanyard still slack at i0, so the chain starts at rest there) for
    the quantities q with a coupon that never breaks."""
    unbroken = dataclasses.replace(q, coupon_break_n=1e12)
    motion = SampledMotion(pull.t, pull.x3, pull.v3, pull.a3)
    return run_pull_with_motion(rig, unbroken.spec(1.0), motion, noise=False, t=pull.t[i0:i1]).truth


def _break_force(t: np.ndarray, fs: np.ndarray, tb: float) -> float:
    """The break force that makes the sim's coupon break nearest to tb, from its unbroken F_stat on the samples t.

    The sim breaks the first time F_stat reaches the break force, and F_stat rings (the cell mode), so a level
    just under the running maximum M at tb breaks at the peak that set M, and a level just over M at the next
    time F_stat exceeds M: whichever of the two is nearer tb (a rising F_stat at tb is both). The margin keeps the
    crossing off the peak, where the sim could miss a tangential crossing."""
    if not t[0] < tb < t[-1]:
        raise DiscoveryError(f'break at {tb!r} s is outside the fit window {t[0]!r}..{t[-1]!r} s; expected inside')
    fine = np.linspace(t[0], t[-1], (len(t) - 1) * 16 + 1)
    spline = CubicSpline(t, fs)             # F_stat between the samples (the cell's response is smooth)
    f = spline(fine)
    top = max(float(np.max(f[fine <= tb])), float(spline(tb)))
    best = None
    for level in (top - BREAK_MARGIN_N, top + BREAK_MARGIN_N):
        hit = np.flatnonzero(f >= level)
        if len(hit) and (best is None or abs(fine[hit[0]] - tb) < best[0]):
            best = (abs(fine[hit[0]] - tb), level)
    return float(best[1]) if best is not None else top


def fit_pull_quantities(pull: Pull, rig, passes: int = DYNAMIC_PASSES) -> PullQuantities:
    """The pull's slack, lanyard stiffness, coupon yield/hardening (if it flows), break force and duration, from
    its measured tension and carriage motion only (module docstring); ``rig`` is the model the quantities are
    for (its cells, a mount if it has one, the lanyard damping ratio, m1 and m2).

    The quasi-static fit is refined ``passes`` times by a defect correction: an unbroken sim of the rig's chain over
    the fit window gives the tension's dynamic part (sim minus quasi-static), which is added to the quasi-static
    model for the next fit. The break instant is fitted with the rest; the break force is then the one at which
    this rig's chain breaks at that instant."""
    pc = _chain(rig)                  # the chain as this rig's sim builds it (an effective mass changes m2)
    C = 1.0 / pc.k1 + 1.0 / pc.k2 + (1.0 / pc.km if pc.has_mount else 0.0)
    mu = pc.m1 * pc.m2 / (pc.m1 + pc.m2)
    zeta = rig.force_chain.lanyard_damping_ratio
    dt = pull.dt
    i0 = max(0, pull.load0 - int(round(FIT_LEAD_S / dt)))
    i1 = min(len(pull.t), pull.brk + int(round(FIT_TAIL_S / dt)))
    s = slice(i0, i1)
    t, x3, v3, Tm = pull.t[s], pull.x3[s], pull.v3[s], pull.T[s]
    kl0, x_zero, fy0, hard0, tb0, dur0, v = _initial(pull, s, C)
    slack0 = x_zero + 2.0 * zeta * math.sqrt(mu / kl0) * v
    yields = math.isfinite(fy0)
    scale = max(float(np.max(Tm)), 1.0)

    def unpack(z):
        kl = kl0 * math.exp(z[0])
        slack = slack0 + z[1] * 1e-4
        tb = tb0 + z[2] * dt
        dur = dur0 * math.exp(z[3])
        if yields:
            return kl, slack, fy0 * (1.0 + z[4]), hard0 * math.exp(z[5]), tb, dur
        return kl, slack, math.inf, 0.0, tb, dur

    def quantities(z, rms=float('nan')) -> PullQuantities:
        kl, slack, fy, hard, tb, dur = unpack(z)
        if not (math.isfinite(kl) and kl > 0 and slack > 0):
            raise DiscoveryError(f'pull {pull.name!r}: per-pull fit gave stiffness {kl!r} N/m, slack {slack!r} m; '
                                 'expected positive values')
        return PullQuantities(float(slack), float(kl), math.inf, float(max(dur, MIN_BREAK_S)),
                              float(fy) if yields else None, float(hard) if yields else None, float(tb), rms)

    dynamic = np.zeros(len(t))

    def resid(z):
        model = filtered(quasi_static_tension(t, x3, v3, unpack(z), C, zeta, mu, dynamic), dt)
        return (model - Tm) / scale

    lo = np.array([-1.5, -50.0, -20.0, math.log(MIN_BREAK_S / dur0) - 1e-9] + ([-0.5, -3.0] if yields else []))
    hi = np.array([1.5, 50.0, 20.0, max(math.log(5e-3 / dur0), 1e-9)] + ([0.5, 3.0] if yields else []))
    z = np.clip(np.zeros(len(lo)), lo + 1e-9, hi - 1e-9)
    for k in range(passes + 1):
        z = least_squares(resid, z, bounds=(lo, hi), x_scale=np.full(len(z), 0.05), diff_step=1e-3,
                          xtol=1e-8, ftol=1e-10, max_nfev=200).x
        run = _unbroken_run(pull, rig, i0, i1, quantities(z))
        if k < passes:
            par = unpack(z)[:4] + (math.inf, 1.0)
            dynamic = run['tension_n'] - quasi_static_tension(t, x3, v3, par, C, zeta, mu)
    rms = float(np.sqrt(np.mean(resid(z) ** 2)) * scale)
    q = quantities(z, rms)
    return dataclasses.replace(q, coupon_break_n=_break_force(t, run['force_stationary_n'], q.break_time_s))


def _hum(pull: Pull, departures: Departures, m2: float) -> Optional[np.ndarray]:
    """The extension's hum (its frequency and amplitude) with the phase fitted on this pull's pre-pull record."""
    d = departures.get('mains_hum')
    if d is None or d['amplitude_n'] == 0.0:
        return None
    a, h = hum_per_pull(pull, d['frequency_hz'], m2)
    return h * (d['amplitude_n'] / max(a, 1e-12))


def _physics(pull: Pull, rig, q: PullQuantities) -> Dict[str, np.ndarray]:
    """The sim's clean signals (PullResult.truth) of the whole record, driven by the pull's measured motion."""
    motion = SampledMotion(pull.t, pull.x3, pull.v3, pull.a3)
    v_max = float(np.max(pull.v3))
    return run_pull_with_motion(rig, q.spec(v_max if v_max > 0 else 1.0), motion, noise=False, t=pull.t).truth


def _signals(pull: Pull, truth: Dict[str, np.ndarray]) -> Dict[str, np.ndarray]:
    """The extra terms' signals (force_tester_sim.core.extra_terms.SIGNALS) of the sim's clean signals."""
    return signals(pull.t, truth['force_moving_n'], truth['force_stationary_n'], truth['tension_n'], truth['a2_m_s2'],
                   pull.v3, pull.x3)


def _record(pull: Pull, rig, truth: Dict[str, np.ndarray], m2_nominal: float,
            phases: Optional[Mapping[ExtraTerm, float]] = None) -> Dict[str, np.ndarray]:
    """What the DAQ records of the clean signals: the rig's sensor departures, its extra terms, the drive's
    current. phases: the sinusoid terms' phases on this pull (sin_phases); a sin term without one is left out."""
    deps = rig.departures
    fm = truth['force_moving_n']
    fm_rec, a2_rec = apply_sensor_departures(deps.without('mains_hum'), pull.t, fm, truth['a2_m_s2'], 0)
    hum = _hum(pull, deps, m2_nominal)
    if hum is not None:
        fm_rec = fm_rec + hum
    extra = {}
    if rig.extra_terms:   # terms beyond the catalog
        extra = extra_channels(rig.extra_terms, _signals(pull, truth), phases={} if phases is None else phases)
    out = {'force_moving_n': fm_rec + extra.get('force_moving', 0.0),
           'force_stationary_n': truth['force_stationary_n'] + extra.get('force_stationary', 0.0),
           'accel_axial_m_s2': a2_rec + extra.get('accel_axial', 0.0), 'tension_n': truth['tension_n']}
    if pull.current is not None:
        d = rig.drive
        f = drive_force_balance(pull, d, fm)
        cf = deps.get('coulomb_friction')
        if cf is not None:
            f = f + cf['force_n'] * np.where(np.abs(pull.v3) > STILL_M_S, np.sign(pull.v3), 0.0)
        out['motor_current_a'] = f / d.force_per_amp_n_per_a + extra.get('motor_current', 0.0)
    return out


def resimulate(pull: Pull, rig, departures: Departures, q: PullQuantities) -> Dict[str, np.ndarray]:
    """Simulated channels of ``pull`` on its own time base: the rig (model of record, with its extra terms) plus
    ``departures``, driven by the pull's measured carriage motion, with the per-pull quantities ``q``; noise off;
    a sinusoid term at the phase fitted on the pull (sin_phases). Keys: SIM_CHANNELS (motor_current_a only when the
    pull has a current channel) and tension_n."""
    rig_x = with_departures(rig, departures)
    truth = _physics(pull, rig_x, q)
    m2 = rig.force_chain.m2
    phases = sin_phases(pull, rig_x, truth, m2, rig.sensors.load_cell_range_lbf * LBF_N)
    return _record(pull, rig_x, truth, m2, phases)


def _measured(pull: Pull) -> Dict[str, np.ndarray]:
    out = {'force_moving_n': pull.fm, 'force_stationary_n': filtered(pull.fs, pull.dt), 'accel_axial_m_s2': pull.a2}
    if pull.current is not None:
        out['motor_current_a'] = filtered(pull.current, pull.dt)
    return out


def _compared(ch: str, m: np.ndarray, cell_range_n: float) -> np.ndarray:
    """Which samples m of the measured channel ch (on the analysis window) are compared: not a force sample at the
    cells' range (SATURATION_SHARE of it; a DAQ clips there)."""
    return np.abs(m) < SATURATION_SHARE * cell_range_n if ch in FORCE_CHANNELS else np.ones(len(m), bool)


def sin_phases(pull: Pull, rig, truth: Dict[str, np.ndarray], m2_nominal: float,
               cell_range_n: float) -> Dict[ExtraTerm, float]:
    """{sinusoid term of rig.extra_terms: its phase on this pull, rad}: one nuisance parameter a pull, as the hum's
    phase and the per-pull quantities are; the amplitude stays the campaign's coefficient.

    On the analysis window, after the comparison's low-pass, what the measured channel leaves of the sim without
    its sinusoids (truth recorded by _record) is regressed on each term at phase 0 and at pi/2 (its own values,
    ExtraTerm.values: coefficient x factor x sin / cos); the sin terms of one channel together. The phase is
    atan2 of the two weights. With the amplitude fixed, a sinusoid s the data do not hold cannot lower the channel's
    RMS: at any phase it changes the squared error by |s|^2 - 2 <r, s>, below 0 only when the residual r holds
    more than half of s along it."""
    sins = [e for e in rig.extra_terms if e.is_sin]
    if not sins:
        return {}
    rest = _record(pull, rig, truth, m2_nominal, {})
    meas = _measured(pull)
    sig = _signals(pull, truth)
    w = slice(pull.w0, pull.w1)
    out: Dict[ExtraTerm, float] = {}
    for ch in dict.fromkeys(e.channel for e in sins):
        col = CHANNEL_COLUMNS[ch]
        if col not in meas:           # no such channel measured: nothing to fit the phase on, nothing compared
            continue
        terms = [e for e in sins if e.channel == ch]
        ok = _compared(col, meas[col][w], cell_range_n)
        basis = np.column_stack([filtered(e.values(sig, ph), pull.dt)[w][ok] for e in terms
                                 for ph in (0.0, 0.5 * math.pi)])
        r = (meas[col][w] - filtered(rest[col], pull.dt)[w])[ok]
        weights = np.linalg.lstsq(basis, r, rcond=None)[0]
        for k, e in enumerate(terms):
            out[e] = float(math.atan2(weights[2 * k + 1], weights[2 * k]))
    return out


def ring_mode(pull: Pull, a2: np.ndarray, f_max: float) -> Optional[tuple]:
    """(frequency Hz, damping ratio) of the strongest free-decay mode of a2 - a3 after the break below f_max
    (ring_segment / matrix_pencil as discovery's ring stage), or None."""
    return window_mode(ring_window(pull, a2), pull.dt, f_max)


def ring_window(pull: Pull, a2: np.ndarray) -> Optional[np.ndarray]:
    """The RING_SAMPLES of a2 - a3 after the break that ring_mode() analyses (None: no clean free decay)."""
    seg = ring_segment(dataclasses.replace(pull, a2=a2))
    return None if seg is None else seg[:RING_SAMPLES].copy()


def window_mode(seg: Optional[np.ndarray], dt: float, f_max: float) -> Optional[tuple]:
    """ring_mode() of a ring_window()."""
    if seg is None:
        return None
    modes = [m for m in matrix_pencil(seg, dt) if 100.0 < m[0] < f_max and 0 < m[1] < 0.5]
    return (modes[0][0], modes[0][1]) if modes else None


@dataclass(frozen=True)
class SimulationCheck:
    """Measured vs re-simulated channels over held-out pulls (baseline: model of record; extended: + extension)."""

    channels: dict          # channel -> {baseline_rms, extended_rms, gain}
    pulls: tuple            # names of the pulls re-simulated
    quantities: tuple       # per pull: {'baseline': PullQuantities dict, 'extended': ...}
    ring: Optional[dict]    # mount resonance only: measured vs extended-sim ring frequency
    trace: dict             # one pull: t and, per channel, measured / baseline / extended (low-passed, window)
    time_s: float
    cell_damping: dict = dataclasses.field(default_factory=dict)   # the cells' damping ratio: rig's and used
    skipped: dict = dataclasses.field(default_factory=dict)        # pull name -> why it was not re-simulated
    saturated: dict = dataclasses.field(default_factory=dict)      # channel -> samples left out (at the range)
    terms: tuple = ()       # the extension's extra terms re-simulated: {channel, term, how} (resimulated_terms)

    def as_dict(self) -> dict:
        return {ch: dict(v) for ch, v in self.channels.items()}

    def details(self) -> dict:
        return {'pulls': list(self.pulls), 'ring': self.ring, 'time_s': self.time_s,
                'cell_damping': dict(self.cell_damping), 'skipped': dict(self.skipped),
                'saturated_samples': dict(self.saturated), 'terms_resimulated': [dict(e) for e in self.terms],
                'quantities': [dict(q) for q in self.quantities]}


SIN_HOW = ("amplitude the campaign's coefficient, phase fitted on each held-out pull as the hum's is (one nuisance "
           "parameter a pull, simulation_check.quantities[].sin_phase_rad)")


def resimulated_terms(terms) -> tuple:
    """SimulationCheck.terms: each extra term (ExtraTerm) as {channel, term, how it was re-simulated}."""
    return tuple({'channel': e.channel, 'term': e.term, 'how': SIN_HOW if e.is_sin else 'as found'} for e in terms)


@dataclass(frozen=True)
class ResimSetup:
    """What re-simulating a pull needs besides the pull (resim_setup): the two models and the comparison's
    constants. Small and picklable: a Dask worker gets it with each pull."""

    base_rig: object          # the model of record (with the measured cell damping when calibrated)
    ext_rig: object           # ... plus the extension
    same_chain: bool          # the extension changes only sensors: one fit and one sim serve both
    m2: float
    cell_range_n: float
    mount: bool               # the extension has a mount resonance: compare ring frequencies
    f_cell: float
    damping: dict             # the cells' damping ratio: the rig's, the one used, pulls it was measured on


def resim_setup(rig, departures: Departures, cal: Optional[tuple] = None, extra: tuple = ()) -> ResimSetup:
    """ResimSetup for the rig (model of record) and the extension's departures (and its extra_terms, as
    force_tester_sim.core.extra_terms.ExtraTerm); cal: (damping ratio, pulls) of the cells measured on the pulls
    checked (cells.cell_damping_ratio), or None to keep the rig's."""
    fc = rig.force_chain
    damping = {'rig': fc.load_cell_damping_ratio, 'used': fc.load_cell_damping_ratio, 'pulls': 0}
    if cal is not None:
        damping.update(used=cal[0], pulls=cal[1])
        rig = dataclasses.replace(rig, force_chain=dataclasses.replace(fc, load_cell_damping_ratio=cal[0]))
    ext_rig = dataclasses.replace(with_departures(rig, departures), extra_terms=tuple(extra))
    f_cell = math.sqrt(rig.force_chain.load_cell_stiffness_n_per_m / rig.force_chain.m2) / (2 * np.pi)
    return ResimSetup(rig, ext_rig, _chain(rig) == _chain(ext_rig), rig.force_chain.m2,
                      rig.sensors.load_cell_range_lbf * LBF_N, 'mount_resonance' in departures, f_cell, damping)


@dataclass(frozen=True)
class ResimPart:
    """One pull re-simulated (resim_pull): its squared errors per channel, or why it was skipped."""

    name: str
    skipped: Optional[str] = None
    sse: tuple = ()                 # (channel, baseline SSE, extended SSE, samples compared, samples saturated)
    quantities: Optional[dict] = None
    windows: Optional[tuple] = None  # (measured, extended-sim) ring_window()s (a mount in the extension only); their
    #                                  modes are found by ResimSum, on the first RING_PULLS pulls that have them
    trace: Optional[dict] = None    # the pull's traces (asked for with trace=True)
    time_s: float = 0.0
    dt: float = 0.0


def resim_pull(p: Pull, setup: ResimSetup, trace: bool = False) -> ResimPart:
    """Re-simulate one pull with the model of record and with the extension (setup) and compare each channel with
    the measured one over the analysis window (see simulation_check). A pull whose fit or sim fails is skipped
    (ResimPart.skipped says why). trace: keep the traces (for the plot)."""
    t0 = time.perf_counter()
    base_rig, ext_rig, same_chain = setup.base_rig, setup.ext_rig, setup.same_chain
    try:
        qb = fit_pull_quantities(p, base_rig)
        qe = qb if same_chain else fit_pull_quantities(p, ext_rig)
        clean_b = _physics(p, base_rig, qb)
        clean_e = clean_b if same_chain else _physics(p, ext_rig, qe)
    except (DiscoveryError, SimError) as exc:   # one pull the sim cannot reproduce does not end the check
        return ResimPart(p.name, skipped=str(exc), time_s=time.perf_counter() - t0)
    phases = sin_phases(p, ext_rig, clean_e, setup.m2, setup.cell_range_n)
    sims = {'baseline': _record(p, base_rig, clean_b, setup.m2),
            'extended': _record(p, ext_rig, clean_e, setup.m2, phases)}
    meas = _measured(p)
    w = slice(p.w0, p.w1)
    tr = None
    if trace:
        tr = {'pull': p.name, 't': p.t[w].copy(),
              'focus_s': (float(p.t[max(p.w0, p.load0 - int(5e-3 / p.dt))]),
                          float(p.t[min(p.w1 - 1, p.brk + int(30e-3 / p.dt))]))}
    rows = []
    for ch, m in meas.items():
        ok = _compared(ch, m[w], setup.cell_range_n)
        sse = {}
        for kind, sim in sims.items():
            y = filtered(sim[ch], p.dt)
            sse[kind] = float(np.sum((y[w] - m[w])[ok] ** 2))
            if tr is not None:
                tr.setdefault(ch, {'measured': m[w].copy()})[kind] = y[w]
        rows.append((ch, sse['baseline'], sse['extended'], int(np.count_nonzero(ok)), int(np.count_nonzero(~ok))))
    windows = None
    if setup.mount:
        windows = (ring_window(p, p.a2), ring_window(p, filtered(sims['extended']['accel_axial_m_s2'], p.dt)))
    quantities = {'baseline': qb.as_dict(), 'extended': qe.as_dict()}
    if phases:
        quantities['sin_phase_rad'] = {f'{e.channel}: {e.term}': ph for e, ph in phases.items()}
    return ResimPart(p.name, None, tuple(rows), quantities, windows, tr, time.perf_counter() - t0, p.dt)


class ResimSum:
    """resim_pull()'s parts added up in pull order into a SimulationCheck. keep: the list position of the pull
    whose traces are kept (None: the first pull re-simulated); the part of that pull must carry its trace."""

    def __init__(self, setup: ResimSetup, keep: Optional[int] = None):
        self.setup, self.keep = setup, keep
        self.sse, self.names, self.quants, self.rings = {}, [], [], []
        self.trace, self.skipped, self.time_s = {}, {}, 0.0

    def add(self, j: int, part: ResimPart) -> None:
        self.time_s += part.time_s
        if part.skipped is not None:
            self.skipped[part.name] = part.skipped
            return
        if self.keep is None:
            self.keep = j
        if j == self.keep and part.trace is not None:
            self.trace = part.trace
        for ch, b, e, n, sat in part.sse:
            acc = self.sse.setdefault(ch, {'baseline': 0.0, 'extended': 0.0, 'n': 0, 'saturated': 0})
            acc['n'] += n
            acc['saturated'] += sat
            acc['baseline'] += b
            acc['extended'] += e
        self.names.append(part.name)
        self.quants.append(part.quantities)
        if self.setup.mount and part.windows is not None and len(self.rings) < RING_PULLS:
            f_max = MOUNT_MAX_FRACTION * self.setup.f_cell
            rm, re_ = (window_mode(w, part.dt, f_max) for w in part.windows)
            if rm is not None and re_ is not None:
                self.rings.append((rm[0], re_[0]))

    def result(self) -> SimulationCheck:
        if not self.names:
            raise DiscoveryError(f'simulation check: no pull could be re-simulated ({self.skipped}); expected at '
                                 'least one')
        channels, saturated = {}, {}
        for ch, acc in self.sse.items():
            b = math.sqrt(acc['baseline'] / acc['n'])
            e = math.sqrt(acc['extended'] / acc['n'])
            channels[ch] = {'baseline_rms': b, 'extended_rms': e, 'gain': b / e if e > 0 else math.inf}
            if acc['saturated']:
                saturated[ch] = acc['saturated']
        ring = None
        rings = self.rings
        if self.setup.mount:
            if rings:
                fm_, fe = (float(np.median([r[k] for r in rings])) for k in (0, 1))
                err = abs(fe / fm_ - 1.0)
                worst = max(abs(r[1] / r[0] - 1.0) for r in rings)
                ring = {'measured_hz': fm_, 'extended_sim_hz': fe, 'rel_error': err, 'max_pull_rel_error': worst,
                        'tolerance': RING_TOLERANCE, 'within_tolerance': bool(err <= RING_TOLERANCE),
                        'pulls': len(rings)}
            else:
                ring = {'measured_hz': None, 'extended_sim_hz': None, 'rel_error': None, 'max_pull_rel_error': None,
                        'tolerance': RING_TOLERANCE, 'within_tolerance': False, 'pulls': 0}
        return SimulationCheck(channels, tuple(self.names), tuple(self.quants), ring, self.trace, self.time_s,
                               dict(self.setup.damping), self.skipped, saturated,
                               resimulated_terms(self.setup.ext_rig.extra_terms))


def simulation_check(pulls: Sequence[Pull], idx: Sequence[int], rig, departures: Departures,
                     trace_pull: Optional[int] = None, calibrate: bool = True, extra: tuple = ()) -> SimulationCheck:
    """Re-simulate pulls[idx] twice (model of record; plus ``departures`` and the ``extra`` terms, ExtraTerm; a
    sinusoid at its phase fitted per pull, sin_phases) and compare with the measurements.

    RMS per channel over each pull's analysis window w0:w1 after the discovery low-pass (7-9 kHz, zero phase),
    pooled over the pulls. ``trace_pull``: list position of the pull whose traces are kept (default: the first
    pull re-simulated). A pull whose fit or sim fails is skipped (``skipped`` says why). Force samples where the
    measured channel is at the cells' range (SATURATION_SHARE of it) are left out: a DAQ clips there.
    ``calibrate``: both runs use the cells' damping ratio measured on these pulls (cell_damping_ratio) instead of
    the rig's assumed one: the cells ring after every fast break, and a wrong decay rate of that ringing would
    swamp what the extension changes. time_s: the seconds spent re-simulating, summed over the pulls.

    The same work one pull at a time: resim_setup, resim_pull per pull, ResimSum (what discover's stream does)."""
    if not len(idx):
        raise DiscoveryError('simulation check has no pulls; expected at least one held-out pull')
    setup = resim_setup(rig, departures, cell_damping_ratio(pulls, idx, rig) if calibrate else None, extra)
    acc = ResimSum(setup, trace_pull)
    for j in idx:
        want = j == trace_pull if trace_pull is not None else acc.keep is None
        acc.add(j, resim_pull(pulls[j], setup, trace=want))
    return acc.result()


__all__ = ['PullQuantities', 'ResimPart', 'ResimSetup', 'ResimSum', 'SimulationCheck', 'SIM_CHANNELS',
           'cell_damping_ratio', 'fit_pull_quantities', 'quasi_static_tension', 'resim_pull', 'resim_setup',
           'resimulate', 'ring_mode', 'ring_window', 'sample_beta', 'simulation_check', 'sin_phases', 'window_mode',
           'with_departures']
