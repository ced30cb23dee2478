"""The generators a discovery benchmark runs on: `--generator own|independent|both`.

- own: tests/force_discovery/generator.py on force_tester_sim, the physics the search, the budgets and the catalog
  were shaped on;
- independent: tests/independent/rig.py, written by a helper from tests/independent/SPEC.md alone (its own state
  formulation, an implicit integrator on the coupled system, a real DAQ chain, a rig drawn per seed: m2 0.8-1.6 kg,
  cells x0.5-2, 10-100 kHz). See tests/independent/PROVENANCE.md.

A figure from the independent column is a figure on physics the search was not shaped on. Each benchmark keeps its
own generator's campaigns as they were; this module gives the independent generator's campaigns the same shape
(`Case`: the campaign, the rig YAML a lab would state, which is the datasheet and never the truth, and the truth
record the benchmark alone reads) and the truths each benchmark scores against.
"""
from __future__ import annotations

import hashlib
import math
import os
import pickle
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'independent')]

import rig as R  # the independent generator

from force_tester_sim.core.params import rig_from_dict

GENERATORS = ('own', 'independent')
# an independent campaign's layout: the own generator's (3 sets x 4 pulls), on the same sets
SETS = (2, 3, 4)
PULLS = 12
# every channel present: a missing channel is another question (issue 40's), not the one these figures answer
ALL_CHANNELS = {'daq.absent': []}
CATALOG = R.CATALOG          # the catalog entries the independent generator can hide
BEYOND = R.BEYOND            # its departures outside the catalog
ALWAYS = (('moving_cell_gain', 'gain'), ('effective_mass', 'mass_kg'), ('accel_delay', 'delay_s'))


def add_option(ap) -> None:
    ap.add_argument('--generator', choices=(*GENERATORS, 'both'), default='own',
                    help='own: the physics the search was shaped on (force_tester_sim); independent: '
                         'tests/independent, written apart from it; both: the two side by side (default own)')


def chosen(value: str) -> tuple:
    return GENERATORS if value == 'both' else (value,)


REDRAWS = 5              # rigs drawn in turn when one cannot make a pull of a set (the generator raises)
REDRAW_STEP = 100_003    # the seed's step from one draw to the next


@dataclass(frozen=True)
class Case:
    campaign: list
    rig: object          # force_tester_sim RigParams from the datasheet: what `discover` is given
    truth: dict          # the generator's truth record: read by the benchmark only
    seed: int            # the seed that made it (the one asked for, or a redraw's)


#: where made campaigns are kept (a campaign takes ~20 s to make and ~5 s to discover): $FT_BENCH_CACHE, else
#: runs/cache/independent; keyed by the generator's source, so a change to it makes them anew
CACHE_ENV = 'FT_BENCH_CACHE'


def _cache_path(seed: int, departures, pulls: int, sets, all_channels: bool, overrides=None,
                keep_signals: bool = False) -> Path:
    src = hashlib.sha256()
    for f in sorted(Path(R.__file__).parent.glob('*.py')):
        src.update(f.read_bytes())
    extra = () if not overrides and not keep_signals else (sorted((overrides or {}).items()), keep_signals)
    key = repr((src.hexdigest(), seed, departures, pulls, tuple(sets), all_channels, *extra)).encode()
    root = Path(os.environ.get(CACHE_ENV) or ROOT / 'runs' / 'cache' / 'independent')
    return root / f'{hashlib.sha256(key).hexdigest()[:24]}.pickle'


def case(seed: int, departures, *, pulls: int = PULLS, sets=SETS, all_channels: bool = True, overrides=None,
         keep_signals: bool = False) -> Case:
    """An independent campaign with these departures (a list of {'name': ...}, [] for none, or 'catalog' /
    'beyond' / 'draw' for the generator's own draw), from the cache when it was made before. A drawn rig that
    cannot make an admissible pull of one of the sets (the generator's rejection rules give up on it) is drawn
    again with the next seed, said on stderr. overrides: dotted rig constants the generator takes
    (``{'daq.sample_rate_hz': 25e3}``); keep_signals: each pull's truth entry keeps its clean signals
    (truth['pulls'][k]['signals']: F_move, F_stat, T, a2, v, x, i on the sample times)."""
    path = _cache_path(seed, departures, pulls, sets, all_channels, overrides, keep_signals)
    if path.is_file():
        with path.open('rb') as f:
            return pickle.load(f)  # noqa: S301 - this benchmark's own files
    made = _make(seed, departures, pulls, sets, all_channels, overrides, keep_signals)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f'.{os.getpid()}.tmp')
    with tmp.open('wb') as f:
        pickle.dump(made, f)
    os.replace(tmp, path)
    return made


def _make(seed: int, departures, pulls: int, sets, all_channels: bool, overrides=None,
          keep_signals: bool = False) -> Case:
    rig = {**(ALL_CHANNELS if all_channels else {}), **(overrides or {})}
    for k in range(REDRAWS):
        s = seed + k * REDRAW_STEP
        try:
            camp, truth = R.generate_campaign(s, n_pulls=pulls, sets=list(sets), departures=departures,
                                              rig=rig or None, keep_signals=keep_signals)
        except RuntimeError as exc:
            if 'no admissible' not in str(exc):
                raise
            print(f'independent generator, seed {s}: {exc}; drawing the rig again', file=sys.stderr, flush=True)
            continue
        return Case(camp, rig_from_dict(yaml.safe_load(R.rig_yaml(truth))), truth, s)
    raise RuntimeError(f'independent generator: no admissible campaign in {REDRAWS} rigs from seed {seed}')


def _accel_lead_s(truth: dict) -> float:
    """How far the accelerometer's samples lead the moving cell's: its DAQ slot is later, so it samples later."""
    ch = truth['daq']['channels']
    return ch['accel_axial_m_s2']['skew_s'] - ch['force_moving_n']['skew_s']


def observed_mount(dep: dict) -> float:
    """The mount's mode as the accelerometer sees it after the break: the lanyard-free mode of the coupled chain
    nearest the bracket's own frequency."""
    params = dep['params']
    modes = params.get('modal_frequencies_hz', {}).get('lanyard_free') or [params['frequency_hz']]
    return min(modes, key=lambda f: abs(f - params['frequency_hz']))


def observed_mount_damping(truth: dict, dep: dict) -> float:
    """The damping ratio of the mount's mode as the accelerometer sees it after the break (what `discover` reports,
    as the own generator's truth is): the damped mode, nearest observed_mount(), of the lanyard-free chain m2 - moving
    cell (K2, c2) - bracket m_b - mount (k_m, c_m) - carriage M_eff, the carriage damped by its viscous b and by the
    drive's velocity loop (SPEC 3: a force k_F K_pv on the carriage's speed through the current loop's first-order
    closed loop at f_ci; the loops' integral parts act far below the mount's mode). The bracket's own zeta_m (the
    catalog's parameter) is not the mode's: the cell's damping and the drive's add to it."""
    r, q = truth['rig'], dep['params']
    m2 = next((d['params']['mass_kg'] for d in truth['departures'] if d['name'] == 'effective_mass'),
              r['force_chain.moving_side_mass_kg'])
    mb, mt = q['base_mass_kg'], q['base_mass_kg'] + m2
    km = (2 * math.pi * q['frequency_hz']) ** 2 * mt
    cm = 2 * q['damping_ratio'] * math.sqrt(km * mt)
    k2 = r['cells.K2_n_per_m']
    c2 = 2 * r['cells.zeta_2'] * math.sqrt(k2 * m2)
    K, C = np.zeros((3, 3)), np.zeros((3, 3))
    for (a, b), k, c in (((0, 1), k2, c2), ((1, 2), km, cm)):
        for X, v in ((K, k), (C, c)):
            X[a, a] += v
            X[b, b] += v
            X[a, b] -= v
            X[b, a] -= v
    C[2, 2] += r['derived.b_n_s_per_m']
    Minv = np.diag(1.0 / np.array([m2, mb, r['derived.M_eff_kg']]))
    w_ci = 2 * math.pi * r['control.f_ci_hz']
    A = np.zeros((7, 7))          # states: the three positions, their speeds, the motor current
    A[:3, 3:6] = np.eye(3)
    A[3:6, :3], A[3:6, 3:6] = -Minv @ K, -Minv @ C
    A[5, 6] = r['derived.k_F_n_per_a'] * Minv[2, 2]                   # the drive's force on the carriage
    A[6, 5], A[6, 6] = -w_ci * r['control.K_pv'], -w_ci              # i' = w_ci (-K_pv v3 - i)
    ev = np.linalg.eigvals(A)
    lam = min(ev[ev.imag > 0], key=lambda v: abs(v.imag - 2 * math.pi * observed_mount(dep)))
    return float(-lam.real / abs(lam))


def catalog_truths(truth: dict) -> dict:
    """{(cause, parameter): true value} for every catalog departure of the truth, and the three parameters the
    force model always fits (the moving cell's gain, the effective mass, the accelerometer's delay against the
    moving cell: its conditioning delay less its DAQ slot's lead)."""
    deps = {d['catalog']['name']: d for d in truth['departures'] if d.get('catalog')}
    out = {('moving_cell_gain', 'gain'): 1.0,
           ('effective_mass', 'mass_kg'): truth['rig']['force_chain.moving_side_mass_kg'],
           ('accel_delay', 'delay_s'): -_accel_lead_s(truth)}
    for name, d in deps.items():
        params = d['catalog']['params']
        if name == 'mount_resonance':
            out[(name, 'frequency_hz')] = observed_mount(d)
            out[(name, 'damping_ratio')] = observed_mount_damping(truth, d)
        elif name == 'accel_delay':
            out[(name, 'delay_s')] = params['delay_s'] - _accel_lead_s(truth)
        else:
            for k, v in params.items():
                out[(name, k)] = v
    return out


def beyond_term(truth: dict):
    """The first grammar term the truth's departures state ({channel, term, coefficient}), or None when the
    departure has none (its physics is outside the grammar)."""
    terms = R.grammar_terms(truth)
    return terms[0] if terms else None


def pull_tensions(truth: dict) -> list:
    """The lanyard tension's peak of each pull, in campaign order (the truth the corrected peak estimates)."""
    return [p['peak_tension_n'] for p in truth['pulls']]

