"""The streamed discovery's per-pull passes (stream.py runs them in order): each a top-level function of (pull,
small settings) that the campaign engine maps over the pulls, its settings and its small result. ROS-free.

- read_pass (every pull): read, check, screen and prepare it (PullRead: its data-quality verdict and window, its
  friction offsets); the prepared pull is spilled to a scratch folder (one pickle per pull) so the later passes need
  not parse its file again (load_pull).
- cell_record: the cells' damping ratio from the pull's free decay.
- hum_record (a few fitted pulls): the pre-pull residual and the free-decay mode (HumRecord).
- pull_stats (every usable pull): the hum amplitude, the force model's statistics; held-out pulls: the free decay and
  the current residual scored (StatsJob -> PullStats).
- held_out (the held-out pulls): the structure check's share and spectrum, the force errors, the re-simulation
  (HeldJob -> HeldOut).
- beyond_pass: the search beyond the catalog's residual spectra or library statistics (BeyondJob).
"""
import os
import pickle
from dataclasses import dataclass
from typing import Optional

import numpy as np

from . import beyond as bey
from .budget import (
    DELAY_FORMS,
    delay_form,
    filter_delay,
    force_variants,
    friction_variants,
)
from .cells import (
    cell_mode,
    with_tension,
)
from .errors import DiscoveryError
from .force_errors import ErrorPart, error_part
from .force_model import ForceModel, TermsFit, resid_at
from .force_stats import force_blocks
from .friction import (
    friction_row,
    friction_sse,
)
from .hum import hum_per_pull, pre_residual
from .leftover import LeftoverPart, leftover_part
from .prep import Pull, PullQuality, check_quality, prepare
from .quality import PullScreen, screen_pull
from .resim import ResimPart, ResimSetup, resim_pull
from .ringing import RingPart, cell_modes, free_decay_mode, free_decay_variants, ring_part
from .source import PullRef, load_channels, rated_ranges
from .stages import (
    PullInfo,
)

SPILL_ARRAYS = ('t', 'fm', 'fs', 'a2', 'T', 'x3', 'v3', 'a3', 'current', 'ok')
SPILL_SCALARS = ('dt', 'w0', 'w1', 'pre1', 'load0', 'brk', 'peak')


# ------------------------------------------------------------------------------------------ per-pull results
@dataclass(frozen=True)
class PullRead:
    """What pass 1 (read_pass) found in one pull."""

    name: str
    quality: Optional[PullQuality] = None
    screen: Optional[PullScreen] = None
    rejected: Optional[str] = None     # the pull is not analysable (DiscoveryError): the campaign stops
    excluded: Optional[str] = None     # why the data-quality screen leaves it out
    info: Optional[PullInfo] = None
    friction: Optional[tuple] = None   # friction.friction_row
    spill: Optional[str] = None        # where the prepared pull was spilled
    friction_variants: Optional[dict] = None   # budget.friction_variants: the row with each drive constant off


@dataclass(frozen=True)
class HumRecord:
    """Pass 2, one of the few fitted pulls: its pre-pull residual (t, r), its free-decay mode and that mode under the
    analysis's variants (ringing.free_decay_variants)."""

    t: np.ndarray
    r: np.ndarray
    mode: Optional[tuple]
    mode_variants: Optional[dict] = None


@dataclass(frozen=True)
class StatsJob:
    """Pass 3's settings for one pull."""

    f_hum: float
    held: bool
    dt: float                           # the campaign's sample interval (the first usable pull's)
    fcf: Optional[float] = None         # the friction force (held-out pulls with a current channel)
    db: float = 0.0                     # ... and the viscous damping's departure fitted with it (friction.py)
    mode: Optional[tuple] = None        # the observed free-decay mode (held-out pulls, when there is one)
    variants: bool = False              # also the force statistics under budget.force_variants (a few fitted pulls)
    fcal: Optional[tuple] = None        # ... with the measured cell frequency (cells.cell_frequency_from)


@dataclass(frozen=True)
class PullStats:
    """Pass 3, one pull: hum amplitude, force statistics; held-out pulls: current and free decay scored."""

    amp: float
    dt: float
    blocks: np.ndarray
    friction: Optional[tuple] = None    # (squared current residual without, with the friction)
    ring: Optional[RingPart] = None
    variants: Optional[dict] = None     # budget variant name -> its force_blocks


@dataclass(frozen=True)
class HeldJob:
    """Pass 4's settings for one held-out pull: the hum, the two force fits to take residuals of, the re-simulation."""

    f_hum: float
    left_scale: Optional[float]         # hum factor for the structure check (None: no hum)
    err_scale: Optional[float]          # ... for the extended force error
    left_fit: TermsFit                  # the model of record's fit, for the structure check
    err_fit: TermsFit                   # ... for the extended force error
    keep: bool                          # keep residuals and traces (plots)
    setup: Optional[ResimSetup]


# force-model terms the search's residual is always formed with, named or not (BeyondJob.nuisance): the
# accelerometer's timing against the moving cell. A DAQ that samples its channels in turn (a multiplexed ADC) puts
# the accelerometer a few microseconds after the moving cell; the catalog names accel_delay only beyond its
# tolerance, but at a cell that rings a delay inside it still leaves a residual no product term is. On the
# independent generator's clean campaign of seed 4423 (1.6 us per ADC slot, the accelerometer two slots after the
# moving cell, a 4.0 kHz cell mode at 1.6 % damping) it left 12.3 N rms on the moving cell (1.55 N with the slots at
# 0), and the search named F_move*x and T*x there: a false alarm. With the timing fitted, nothing
BEYOND_NUISANCE = ('accel_delay',)


@dataclass(frozen=True)
class BeyondJob:
    """The search beyond the catalog (core/beyond/), one pull: the residuals after the named causes."""

    f_hum: float
    hum_scale: Optional[float]          # the hum estimate's factor (None: the hum is not named)
    err_fit: TermsFit                   # the named force-channel causes' fit
    settings: Optional[bey.SearchSettings]   # None: the spectrum pass (a few fitted pulls); else the statistics
    sensors: tuple = ()                 # terms found on the sensors on their own (beyond.sensor_corrected)
    records: bool = False               # the spectrum pass keeps the residual's samples (beyond.REFINE_PULLS pulls)
    nuisance: tuple = ()                # terms of err_fit that are not named (BEYOND_NUISANCE): no cause column


@dataclass(frozen=True)
class HeldOut:
    """Pass 4, one held-out pull."""

    leftover: LeftoverPart
    errors: ErrorPart
    resim: Optional[ResimPart]


@dataclass(frozen=True)
class Source:
    """Where a pass gets a pull: the first pass's spill, else the pull's data again."""

    ref: PullRef
    spill: Optional[str] = None


# ------------------------------------------------------------------------------------------ loading
def _write_spill(p: Pull, path: str) -> None:
    """The prepared pull's arrays and scalars as one pickle (protocol 5: the arrays' bytes as they are, no zip
    archive and no checksum to compute on the way out and back in; this process's own scratch file)."""
    arrays = {k: getattr(p, k) for k in SPILL_ARRAYS if getattr(p, k) is not None}
    with open(path, 'wb') as fh:
        pickle.dump((p.name, [float(getattr(p, k)) for k in SPILL_SCALARS], arrays), fh, protocol=5)


def _read_spill(path: str) -> Pull:
    with open(path, 'rb') as fh:
        name, scalars, arrays = pickle.load(fh)
    sc = dict(zip(SPILL_SCALARS, scalars))
    arrays = {k: arrays.get(k) for k in SPILL_ARRAYS}
    ints = {k: int(sc[k]) for k in ('w0', 'w1', 'pre1', 'load0', 'brk')}
    return Pull(name, arrays['t'], sc['dt'], arrays['fm'], arrays['fs'], arrays['a2'], arrays['T'], arrays['x3'],
                  arrays['v3'], arrays['a3'], arrays['current'], peak=sc['peak'], ok=arrays['ok'], **ints)


def prepare_ref(ref: PullRef, rig):
    """(PullQuality, PullScreen, Pull) of one pull from its data (DiscoveryError when it cannot be analysed)."""
    meta, ch = load_channels(ref)
    q = check_quality(meta, ch)
    sc = screen_pull(q.name, ch, rated_ranges(ref))
    return q, sc, prepare(meta, ch, rig, q, sc)


def load_pull(src: Source, rig, c1: Optional[tuple]) -> Pull:
    """The prepared pull (from the spill when there is one), T with the cells' calibration c1 (cells.with_tension's
    (K_LC1, c1); None: the rig's)."""
    p = _read_spill(src.spill) if src.spill is not None and os.path.exists(src.spill) else prepare_ref(src.ref, rig)[2]
    return with_tension(p, rig, c1)


# ------------------------------------------------------------------------------------------ the passes
def read_pass(item) -> PullRead:
    """Pass 1: item = (PullRef, rig, spill path or None)."""
    ref, rig, spill = item
    try:
        q, sc, p = prepare_ref(ref, rig)
    except DiscoveryError as exc:
        return PullRead(ref.name, rejected=str(exc))
    why = sc.exclusion(p.w0, p.w1)
    info = PullInfo(p.name, p.dt, len(p.t), p.w0, p.w1)
    if why:
        return PullRead(p.name, q, sc, excluded=why, info=info)
    if spill is not None:
        _write_spill(p, spill)
    return PullRead(p.name, q, sc, None, None, info, friction_row(p, rig), spill, friction_variants(p, rig))


def cell_record(item) -> Optional[tuple]:
    """Pass 1b: item = (Source, rig); cells.cell_mode of the pull (its T does not matter)."""
    src, rig = item
    return cell_mode(load_pull(src, rig, None), rig)


def hum_record(item) -> HumRecord:
    """Pass 2: item = (Source, rig, c1)."""
    src, rig, c1 = item
    p = load_pull(src, rig, c1)
    t, r = pre_residual(p, rig.force_chain.m2)
    mode = free_decay_mode(p)
    return HumRecord(t, r, mode, free_decay_variants(p, mode))


def pull_stats(item) -> PullStats:
    """Pass 3: item = (Source, rig, c1, StatsJob)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    amp, hum = hum_per_pull(p, job.f_hum, rig.force_chain.m2)
    friction = ring = None
    if job.held and job.fcf is not None and p.current is not None:
        friction = (friction_sse(p, rig, 0.0, job.db), friction_sse(p, rig, job.fcf, job.db))
    if job.held and job.mode is not None:
        ring = ring_part(p, job.dt, cell_modes(rig.force_chain), job.mode, keep=True)
    variants = None
    if job.variants:
        variants = {name: force_blocks(v, hum) for name, v in force_variants(p, rig, c1, job.fcal).items()}
    return PullStats(amp, p.dt, force_blocks(p, hum), friction, ring, variants)


def form_stats(item) -> PullStats:
    """Pass 3b, only where the data prefer a filter-shaped accelerometer delay (budget.filter_form_preferred):
    item = (Source, rig, c1, StatsJob); the pull's force statistics under budget.delay_form at its filter_delay,
    and on the variant pulls those of the budget's variants of that pull (the delay's own form variants left out:
    the shift is the alternative the data rejected)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    m2 = rig.force_chain.m2
    hum = hum_per_pull(p, job.f_hum, m2)[1]
    d = filter_delay(p, m2)
    variants = None
    if job.variants:   # each variant of the pull, then the filter form (a variant's T is made from the cells again)
        variants = {name: force_blocks(delay_form(v, d), hum)
                    for name, v in force_variants(p, rig, c1, job.fcal).items() if name not in DELAY_FORMS}
    return PullStats(0.0, p.dt, force_blocks(delay_form(p, d), hum), None, None, variants)


def held_out(item) -> HeldOut:
    """Pass 4: item = (Source, rig, c1, HeldJob)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    m2 = rig.force_chain.m2
    hum = None
    if job.left_scale is not None or job.err_scale is not None:
        hum = hum_per_pull(p, job.f_hum, m2)[1]
    h_left = None if job.left_scale is None else hum * job.left_scale
    h_err = None if job.err_scale is None else hum * job.err_scale
    terms, coef, d = job.left_fit
    left = leftover_part(p, h_left, ForceModel([p], m2, [h_left]).resid(set(terms), coef, d, 0), rig)
    terms, coef, d = job.err_fit
    err = error_part(p, ForceModel([p], m2).resid(set(), {}, 0.0, 0),
                       ForceModel([p], m2, [h_err]).resid(set(terms), coef, d, 0), keep=job.keep)
    sim = resim_pull(p, job.setup, trace=job.keep) if job.setup is not None else None
    return HeldOut(left, err, sim)


def beyond_pass(item, series: bool = False):
    """Pass 5 (core/beyond/): item = (Source, rig, c1, BeyondJob); the pull's residual spectra (job.settings None) or
    its library statistics (series=True: its beyond.channel_series)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    if job.sensors:
        p = bey.sensor_corrected(p, job.sensors, rig, c1)
    m2 = rig.force_chain.m2
    h = None if job.hum_scale is None else hum_per_pull(p, job.f_hum, m2)[1] * job.hum_scale
    terms, coef, d = job.err_fit
    fm_ = ForceModel([p], m2, [h])
    r = fm_.resid(set(terms), coef, d, 0)
    named = [k for k in terms if k not in job.nuisance]
    causes = {k: fm_.resid(set(terms) - {k}, coef, d, 0) - r for k in named}   # each cause undone (cause_check)
    # the moving cell's free phase before the load, at the same fitted parameters (beyond.series.before_samples)
    sel = bey.before_samples(p)
    r_b = resid_at(p, m2, h, set(terms), coef, d, sel)
    causes_b = {k: resid_at(p, m2, h, set(terms) - {k}, coef, d, sel) - r_b for k in named}
    if h is not None:
        causes['mains_hum'], causes_b['mains_hum'] = h[p.w0:p.w1], h[sel]
    out = bey.channel_series(p, rig, r, h, causes, (sel, r_b, causes_b))
    if series:
        return out
    series = out
    if job.settings is None:
        return bey.spectrum_part(series, p.dt * bey.decimation(p.dt), job.records)
    return bey.beyond_part(series, job.settings)
