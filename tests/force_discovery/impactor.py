"""A rig unlike ours for the discovery tests (issue 26 section 4): a DROP IMPACTOR. Never seen by the code under
test, which gets only the files, the channel map and a rig YAML.

A drop weight (body, mass MB) carries, through a mount of finite stiffness, a base (mass MBASE) on which a piezo
load cell holds the striker tip (m2, the mass in front of the cell) with an accelerometer on it. The weight falls
onto a stiff target: a compression impact of about a millisecond, then the structure rings freely. No stationary
reference cell, no encoder, no motor. The motion (x upward; contact when the tip is below 0) is integrated exactly
per regime (free / in contact: a linear system each, propagated by scipy.linalg.expm over substeps of the sample
interval); the cell reads k2 (x_base - x2) + c2 (v_base - v2) (tension positive: a compression impact is negative),
the accelerometer the tip's acceleration. Hidden effects: the cell's gain, the true m2, an accelerometer delay
(the tip's acceleration sampled d late, by a cubic spline through the substeps), the mount's mode, mains hum, and
optionally a sensor overload burst on the accelerometer of one record.

The DAQ records volts, compression positive (FORCE_MV_PER_N, ACCEL_MV_PER_G), as the channel map
CHANNEL_MAP says; files are written by the libraries' writers (asammdf) or as LabVIEW writes .lvm text.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from daq_data import ACCEL_MV_PER_G, FORCE_MV_PER_N, IMPACTOR_CHANNEL_MAP, write_lvm, write_mf4
from kinds import timed

from force_tester_common.core.units import G_M_S2
from force_tester_sim.core.params import NOMINAL_YAML

CHANNEL_MAP = IMPACTOR_CHANNEL_MAP
NOMINAL_M2 = 0.30          # the rig YAML's moving-side mass (what the lab believes)
CELL_STIFFNESS = 1.5e9     # N/m: the rig YAML's cell (about 11 kHz on m2)


@dataclass(frozen=True)
class Impactor:
    """The drop impactor as built (the truth; the rig YAML gives only NOMINAL_M2 and CELL_STIFFNESS)."""

    rate_hz: float = 100_000.0
    record_s: float = 0.08
    body_kg: float = 2.0
    base_kg: float = 0.4
    m2_kg: float = 0.33                    # true m2 (+10 % on the rig YAML's)
    gain: float = 1.0                      # the cell's true gain
    mount_hz: float = 2400.0               # the mount's mode (body vs base + tip, tip clamped to base)
    mount_zeta: float = 0.02
    cell_zeta: float = 0.02
    target_n_per_m: float = 8.0e7          # contact stiffness: a ~1 ms impact
    speed_m_s: float = 0.5
    accel_delay_s: float = 40e-6
    hum_hz: float = 50.0
    hum_n: float = 3.0
    force_noise_n: float = 2.0
    accel_noise_m_s2: float = 5.0
    tension: bool = False                  # a tension event instead: the target pulls (a lanyard), not pushes
    overload: dict = field(default_factory=dict)   # record index -> (start s, length s, amplitude m/s^2)

    def mount_stiffness(self) -> float:
        mu = self.body_kg * (self.base_kg + self.m2_kg) / (self.body_kg + self.base_kg + self.m2_kg)
        return (2 * math.pi * self.mount_hz) ** 2 * mu


def _system(imp: Impactor, contact: bool) -> np.ndarray:
    mb, mB, m2 = imp.body_kg, imp.base_kg, imp.m2_kg
    km = imp.mount_stiffness()
    cm = 2 * imp.mount_zeta * math.sqrt(km * mb * (mB + m2) / (mb + mB + m2))
    k2 = CELL_STIFFNESS
    c2 = 2 * imp.cell_zeta * math.sqrt(k2 * m2 * mB / (m2 + mB))
    kc = imp.target_n_per_m if contact else 0.0
    cc = 2 * 0.05 * math.sqrt(kc * (mb + mB + m2)) if contact else 0.0
    K = np.array([[km, -km, 0.0], [-km, km + k2, -k2], [0.0, -k2, k2 + kc]])
    C = np.array([[cm, -cm, 0.0], [-cm, cm + c2, -c2], [0.0, -c2, c2 + cc]])
    Minv = np.diag([1 / mb, 1 / mB, 1 / m2])
    return np.block([[np.zeros((3, 3)), np.eye(3)], [-Minv @ K, -Minv @ C]])


def simulate_record(imp: Impactor, seed: int, substeps: int = 4) -> dict:
    """SI channels of one record (time_s, force_moving_n, accel_axial_m_s2), the workspace's sign convention."""
    from scipy.interpolate import CubicSpline
    from scipy.linalg import expm
    rng = np.random.default_rng([seed, 26])
    n = int(round(imp.rate_hz * imp.record_s))
    dt = 1.0 / imp.rate_hz
    h = dt / substeps
    A_free, A_hit = _system(imp, False), _system(imp, True)
    P_free, P_hit = expm(A_free * h), expm(A_hit * h)
    t_hit = (0.3 + 0.1 * rng.random()) * imp.record_s
    speed = imp.speed_m_s * (1 + 0.15 * (rng.random() - 0.5))
    s = np.zeros(6)
    s[2] = speed * t_hit                  # every part at rest relative to the others, falling at `speed`
    s[:3] = s[2]
    s[3:] = -speed
    m = n * substeps + 8
    F = np.empty(m)
    a2 = np.empty(m)
    k2 = CELL_STIFFNESS
    c2 = 2 * imp.cell_zeta * math.sqrt(k2 * imp.m2_kg * imp.base_kg / (imp.m2_kg + imp.base_kg))
    side = 1.0 if not imp.tension else -1.0   # tension: the target holds the tip back as it rises
    if imp.tension:
        s[:3] = -s[2]
        s[3:] = speed
    kc = imp.target_n_per_m
    cc = 2 * 0.05 * math.sqrt(kc * (imp.body_kg + imp.base_kg + imp.m2_kg))
    for i in range(m):
        x2, v2 = s[2], s[5]
        fc = -kc * x2 - cc * v2                 # what the target would push (pull) on the tip
        hit = -x2 * side > 0 and fc * side > 0  # touching, and pushing (a lanyard: taut, pulling)
        F[i] = k2 * (s[1] - x2) + c2 * (s[4] - v2)
        a2[i] = (F[i] + (fc if hit else 0.0)) / imp.m2_kg
        s = (P_hit if hit else P_free) @ s
    ts = np.arange(m) * h
    t = np.arange(n) * dt
    acc = CubicSpline(ts, a2)(t - imp.accel_delay_s + 4 * h) if imp.accel_delay_s else a2[4:4 + n * substeps:substeps]
    force = F[4:4 + n * substeps:substeps]
    force = imp.gain * force + imp.hum_n * np.sin(2 * np.pi * imp.hum_hz * t + rng.uniform(0, 2 * np.pi))
    force = force + rng.normal(0.0, imp.force_noise_n, n)
    acc = acc + rng.normal(0.0, imp.accel_noise_m_s2, n)
    if seed in imp.overload:
        t0, length, amp = imp.overload[seed]
        on = (t >= t0) & (t < t0 + length)
        acc = acc.copy()
        acc[on] = amp * np.sin(2 * np.pi * 7000.0 * (t[on] - t0)) + rng.normal(0.0, 0.02 * amp, int(on.sum()))
    return {'time_s': t, 'force_moving_n': force, 'accel_axial_m_s2': acc}


def volts(ch: dict) -> dict:
    """The DAQ's volts (compression positive) of SI channels."""
    return {'Load cell': -ch['force_moving_n'] * FORCE_MV_PER_N * 1e-3,
            'Accel': -ch['accel_axial_m_s2'] / G_M_S2 * ACCEL_MV_PER_G * 1e-3}


def rig_yaml(path: Path, rate_hz: float, record_s: float) -> Path:
    """The lab's rig YAML: the nominal one with its own m2, cell stiffness and DAQ (nothing of the truth)."""
    doc = yaml.safe_load(NOMINAL_YAML.read_text())
    doc['daq'] = {'sample_rate_hz': rate_hz, 'record_length_s': record_s}
    doc['force_chain']['moving_side_mass_kg'] = NOMINAL_M2
    doc['force_chain']['load_cell_stiffness_n_per_m'] = CELL_STIFFNESS
    doc.pop('uncertainty', None)
    path.write_text(yaml.safe_dump(doc))
    return path


@timed('campaign')
def lab_campaign(folder: Path, imp: Impactor, records: int = 4, fmt: str = '.lvm', seed0: int = 0,
                 channel_map: dict = CHANNEL_MAP) -> Path:
    """A campaign folder as the lab hands it over: one DAQ file per record in volts, channels.yaml (the channel
    map) and campaign.yaml naming it; the rig YAML beside it (rig.yaml)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'channels.yaml').write_text(yaml.safe_dump(channel_map))
    entries = []
    for i in range(records):
        ch = simulate_record(imp, seed0 + i)
        name = f'drop{i + 1}{fmt}'
        (write_lvm if fmt == '.lvm' else write_mf4)(folder / name, volts(ch), imp.rate_hz)
        entries.append({'file': name, 'set': 0, 'coupon_lbf': 0.0, 'velocity_fps': 0.0, 'decel_g': 0.0})
    (folder / 'campaign.yaml').write_text(yaml.safe_dump({'channels': 'channels.yaml', 'pulls': entries}))
    rig_yaml(folder / 'rig.yaml', imp.rate_hz, imp.record_s)
    return folder


@timed('campaign')
def memory_campaign(imp: Impactor, records: int = 4, seed0: int = 0) -> list:
    """[(meta, SI channels)] of the same records, for the in-memory path."""
    return [({'file': f'drop{i + 1}', 'set': 0, 'coupon_lbf': 0.0, 'velocity_fps': 0.0, 'decel_g': 0.0},
             simulate_record(imp, seed0 + i)) for i in range(records)]


def tip_mode_hz(imp: Impactor) -> float:
    """The free structure's lowest mode (the mount's, as the accelerometer sees it)."""
    ev = np.linalg.eigvals(_system(imp, False))
    ev = ev[(ev.imag > 1.0)]
    lam = min(ev, key=abs)
    return abs(lam.imag) / (2 * np.pi)
