"""Seeded campaigns (test sets x pulls) and the thesis-shaped tables (Tables 7, 8, 9), ROS-free.

``generate_campaign(rig, sets, pulls, seed, mapper=...)`` simulates every pull of the chosen sets; each pull
has its own seed (derived from ``seed``, the set and the pull index only), so the output does not depend on
where or in which order the pulls run. This core runs them one after the other; a caller maps them over
Dask workers by passing ``mapper=force_tester_common.engine.map_pulls`` (or a Mapper), or writes each pull
where it is simulated with ``campaign_jobs`` + ``simulate_campaign_pull`` (``./ft thesis``).

Which pulls are simulated depends on the rig:
- a rig without departures (the nominal rig): ``make_pull_specs(rig, set, pulls, seed)``, unchanged.
- a rig with departures (a "truth" rig, e.g. config/truth_reference.yaml): ``truth_pull_specs``, which
  draws each pull's coupon break force around the set's *measured* level (Table 7 exceeds the coupon
  ratings: copper coupons break higher at speed) and uses per-set lanyard/coupon compliance and break
  duration (``TRUTH_SETS``). These are per-pull quantities (rig README), not hidden effects.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_common.core.mapping import map_here

from .errors import SimError
from .motion import hold_time_s, nominal_slack_m
from .params import RigParams
from .pull import (
    COUPON_SCATTER_REL,
    DECEL_SCATTER_REL,
    LANYARD_STIFFNESS_SCATTER_REL,
    SLACK_SCATTER_M,
    SPEED_SCATTER_REL,
    PullSpec,
    clipped_normal,
    make_pull_specs,
)
from .simulate import simulate_pull

# The stationary side (m1 on its cell, about 3.9 kHz) has a period of 0.255 ms: an elastic rise lasting a whole
# number of these periods leaves it without overshoot (a ramp of one period excites no ringing), so the
# "truth" cell is clean; the 1 kHz mount, slower, is still rung by the rise (sinc(pi f T) = 0.7).
STATIONARY_PERIOD_S = 2.55e-4
YIELD_SCATTER_REL = 0.01   # coupon yield / break force ratio, 1 sigma (same coupon material in a set)


@dataclass(frozen=True)
class TruthSet:
    """Per-set pull properties of the truth campaign (documented in the package README).

    break_over_measured: mean coupon break force / the set's measured stationary average (Table 7).
    yield_fraction: the copper coupon yields at this fraction of its break force: the wire rope (nominal
        stiffness) loads it elastically in well under a millisecond -- the "snap" that rings the mount --
        then the coupon flows plastically with linear hardening up to the break.
    flow_time_s: nominal duration of the plastic flow at the set's speed (sets the hardening stiffness,
        H, once per set; the thesis's 140-point moving average loses about (1 - yield_fraction) * 1.39 ms /
        flow_time_s of the peak on that ramp).
    break_duration_s: (low, high) of the uniform break-duration draw (ductile copper at speed: tens of us).
    """
    break_over_measured: float
    yield_fraction: float
    flow_time_s: float
    break_duration_s: Tuple[float, float]
    elastic_rise_s: float = STATIONARY_PERIOD_S

    def lanyard_stiffness_n_per_m(self, ts) -> float:
        """Lanyard stiffness that loads the coupon to its yield in ``elastic_rise_s`` at the set's speed."""
        return self.yield_fraction * ts.measured_stationary_avg_n * self.break_over_measured \
            / (ts.velocity_m_s * self.elastic_rise_s)


TRUTH_SETS: Dict[int, TruthSet] = {
    # set: break/measured, yield fraction, flow time, break duration range, elastic rise
    1: TruthSet(1.0, 0.70, 16.7e-3, (0.6e-3, 1.0e-3), 2 * STATIONARY_PERIOD_S),
    2: TruthSet(1.0, 0.80, 5.2e-3, (0.5e-3, 1.0e-3), 2 * STATIONARY_PERIOD_S),
    3: TruthSet(1.0, 0.90, 3.7e-3, (5e-6, 15e-6), STATIONARY_PERIOD_S),
    4: TruthSet(1.0, 0.60, 2.55e-3, (30e-6, 100e-6), STATIONARY_PERIOD_S),
    5: TruthSet(1.0, 0.85, 2.6e-3, (100e-6, 250e-6), STATIONARY_PERIOD_S),
}


def truth_hardening_n_per_m(rig: RigParams, test_set: int, cfg: TruthSet) -> float:
    """Coupon hardening stiffness H that makes the flow last ``cfg.flow_time_s`` at the set's speed."""
    ts = rig.test_set(test_set)
    fb = ts.measured_stationary_avg_n * cfg.break_over_measured
    k_el = 1.0 / (1.0 / cfg.lanyard_stiffness_n_per_m(ts) + 2.0 / rig.force_chain.load_cell_stiffness_n_per_m)
    k_flow = (1.0 - cfg.yield_fraction) * fb / (ts.velocity_m_s * cfg.flow_time_s)   # series, flowing
    if not k_flow < k_el:
        raise SimError(f'set {ts.set}: flow time {cfg.flow_time_s} s is too short for the lanyard; expected a '
                       f'flow stiffness {k_flow:.3g} N/m < {k_el:.3g} N/m')
    k_l = cfg.lanyard_stiffness_n_per_m(ts)
    k_p = 1.0 / (1.0 / k_flow - 2.0 / rig.force_chain.load_cell_stiffness_n_per_m)  # lanyard+coupon part
    return k_p * k_l / (k_l - k_p)


def truth_pull_specs(rig: RigParams, test_set: int, n: int, seed: int,
                     truth_sets: Optional[Dict[int, TruthSet]] = None) -> List[PullSpec]:
    """``n`` seeded pulls of ``test_set`` for a truth rig (coupon at the measured level, yielding, per-set flow)."""
    ts = rig.test_set(test_set)
    tsets = TRUTH_SETS if truth_sets is None else truth_sets
    if ts.set not in tsets:
        raise SimError(f'test set {ts.set} has no truth-set entry; expected one of {sorted(tsets)}')
    cfg = tsets[ts.set]
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise SimError(f'number of pulls {n!r} is invalid; expected an integer >= 1')
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise SimError(f'seed {seed!r} is invalid; expected an integer >= 0')
    mean_break = ts.measured_stationary_avg_n * cfg.break_over_measured
    hard = truth_hardening_n_per_m(rig, ts.set, cfg)
    hold = hold_time_s(mean_break * 1.1, ts.velocity_m_s * 0.97, mean_break / (ts.velocity_m_s * cfg.flow_time_s)
                       * 0.85, cfg.break_duration_s[1])
    slack0 = nominal_slack_m(ts.velocity_m_s * 1.03, ts.decel_m_s2, hold, rig.drive.usable_track_m)
    ss = np.random.SeedSequence([int(seed), int(test_set), 0x7275])   # distinct from make_pull_specs' stream
    specs = []
    for i, child in enumerate(ss.spawn(n)):
        rng = np.random.default_rng(child)
        brk = mean_break * (1.0 + clipped_normal(rng, COUPON_SCATTER_REL))
        specs.append(PullSpec(
            test_set=ts.set,
            coupon_break_n=brk,
            velocity_m_s=ts.velocity_m_s * (1.0 + clipped_normal(rng, SPEED_SCATTER_REL)),
            decel_m_s2=ts.decel_m_s2 * (1.0 + clipped_normal(rng, DECEL_SCATTER_REL)),
            slack_m=slack0 + clipped_normal(rng, SLACK_SCATTER_M),
            lanyard_stiffness_n_per_m=cfg.lanyard_stiffness_n_per_m(ts)
            * (1.0 + clipped_normal(rng, LANYARD_STIFFNESS_SCATTER_REL)),
            break_duration_s=float(rng.uniform(*cfg.break_duration_s)),
            seed=int(child.generate_state(1)[0]),
            pull=i,
            command_velocity_m_s=ts.velocity_m_s,
            coupon_yield_n=cfg.yield_fraction * brk * (1.0 + clipped_normal(rng, YIELD_SCATTER_REL)),
            coupon_hardening_n_per_m=hard,
        ))
    return specs


def campaign_specs(rig: RigParams, sets: Sequence[int] = (1, 2, 3, 4, 5), pulls: int = 20,
                   seed: int = 0) -> List[PullSpec]:
    """The pulls of a campaign: nominal rig -> make_pull_specs; rig with departures -> truth_pull_specs."""
    out = []
    for s in sets:
        out.extend(truth_pull_specs(rig, s, pulls, seed) if rig.departures else make_pull_specs(rig, s, pulls, seed))
    return out


def _meta(rig: RigParams, spec: PullSpec, seed: int) -> dict:
    ts = rig.test_set(spec.test_set)
    return {'file': f'set{spec.test_set}_pull{spec.pull + 1:02d}.csv', 'set': ts.set, 'coupon_lbf': ts.coupon_lbf,
            'velocity_fps': ts.velocity_fps, 'decel_g': ts.decel_g, 'pull': spec.pull + 1, 'seed': int(spec.seed),
            'campaign_seed': int(seed)}


def simulate_campaign_pull(job: tuple) -> Dict[str, np.ndarray]:
    """One pull of a campaign (the per-pull step, run on a worker): job = (rig, spec, noise) from campaign_jobs."""
    rig, spec, noise = job
    return simulate_pull(rig, spec, noise)


def campaign_jobs(rig: RigParams, sets: Sequence[int] = (1, 2, 3, 4, 5), pulls: int = 20, seed: int = 0,
                  noise: bool = True) -> List[Tuple[dict, tuple]]:
    """[(meta, job)] of a campaign: simulate_campaign_pull(job) gives the pull's channels (meta as in
    generate_campaign)."""
    return [(_meta(rig, sp, seed), (rig, sp, bool(noise))) for sp in campaign_specs(rig, sets, pulls, seed)]


def generate_campaign(rig: RigParams, sets: Sequence[int] = (1, 2, 3, 4, 5), pulls: int = 20, seed: int = 0,
                      noise: bool = True, mapper: Optional[Callable] = None
                      ) -> List[Tuple[dict, Dict[str, np.ndarray]]]:
    """[(meta, channels)] for ``pulls`` pulls of each set (channels: simulate_pull's dict).

    meta: file 'set{S}_pull{NN}.csv' (NN from 01), set, coupon_lbf (the set's rating), velocity_fps, decel_g
    (commanded, Table 4), pull (1-based), seed (the pull's own seed), campaign_seed.
    mapper: mapper(fn, jobs, names=...) -> .results in order and .failed (force_tester_common.engine.map_pulls);
    None runs the pulls here, one after the other. The result is the same either way.
    """
    jobs = campaign_jobs(rig, sets, pulls, seed, noise)
    if mapper is None:
        chans = map_here(simulate_campaign_pull, [job for _m, job in jobs], catch=()).results
    else:
        done = mapper(simulate_campaign_pull, [job for _m, job in jobs], names=[m['file'] for m, _j in jobs])
        if done.failed:
            name, why = done.failed[0]
            raise SimError(f'campaign pull {name} failed: {why}; expected every pull to simulate')
        chans = done.results
    return [(meta, ch) for (meta, _job), ch in zip(jobs, chans)]


__all__ = ['TruthSet', 'TRUTH_SETS', 'truth_pull_specs', 'campaign_specs', 'campaign_jobs', 'simulate_campaign_pull',
           'generate_campaign']
