"""Offline `correct`: the live correction and scoring applied to a recorded bag or campaign.

The numbers equal the live nodes': the same pairing rules (force_correction.core.pairing), the
same streaming core (bit for bit for any block split) and the same scoring. A bag's output is a
new bag (the input plus /force_corrected, /pull_score, /set_summary); a campaign's is a new
campaign (plus inertial_n, corrected_n, filtered_n columns and scores.json).
"""
from __future__ import annotations

import shutil
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from bag_tools.core.fastcdr import FastPathError
from bag_tools.core.sources import source_kind
from force_tester_common.core.correction import LOADED_FRACTION, LOADED_FRACTION_RANGE, MASS_KG, MAX_PENDING, WINDOW

from ..core.errors import CorrectionError
from ..core.extension import Extension
from ..core.pairing import BlockAligner
from ..core.params import CorrectionParams
from ..core.peak_uncertainty import PeakInputs
from ..core.short_events import advice, bandwidth_window, short_events
from ..core.streaming import correct_signal
from . import bag as bagio
from .result import CorrectionResult
from .scorer import running_summaries
from .stream import SEGMENT_SAMPLES, CorrectionStream

if TYPE_CHECKING:
    from bag_tools.core.daq import Mapper

# A campaign's modules (bag_tools' DAQ reading and conversion, .campaign) are imported by the paths that use them:
# a bag corrected into a bag needs none of them.
Progress = Callable[[int, int], None]
PATHS = ('auto', 'fast', 'fast_read', 'generic')


@dataclass(frozen=True)
class CorrectionSetup:
    """Everything offline `correct` computes with, validated: the correction parameters, the
    extension undone before m*a, the scoring window, the aligner's patience and the fast path's
    segment size (it changes no number, only memory and speed)."""

    params: CorrectionParams = field(default_factory=CorrectionParams)
    extension: Extension | None = None
    loaded_fraction: float = LOADED_FRACTION
    max_pending: int = MAX_PENDING
    segment_samples: int = SEGMENT_SAMPLES
    #: choose the moving average from the short events' bandwidth (short_events.bandwidth_window)
    window_from_bandwidth: bool = False
    #: the inputs' uncertainties of each corrected peak's expanded uncertainty (default: only the noise)
    peak_inputs: PeakInputs = field(default_factory=PeakInputs)

    def __post_init__(self):
        lo, hi = LOADED_FRACTION_RANGE
        if not lo <= self.loaded_fraction <= hi:
            raise CorrectionError(f'loaded_fraction {self.loaded_fraction!r} is out of range; '
                                  f'expected a float in [{lo}, {hi}]')
        if not isinstance(self.segment_samples, int) or self.segment_samples < 1:
            raise CorrectionError(f'segment_samples {self.segment_samples!r} is out of range; '
                                  'expected an integer >= 1')
        BlockAligner(max_pending=self.max_pending)  # validates it

    @classmethod
    def build(cls, mass_kg: float = MASS_KG, window: int = WINDOW,
              extension_file: str | Path | None = None, **kwargs) -> CorrectionSetup:
        """From plain options: an extension file's mass_kg replaces ``mass_kg`` (as in the node)."""
        ext = Extension.from_yaml(extension_file) if extension_file is not None else None
        if ext is not None and ext.mass_kg is not None:
            mass_kg = ext.mass_kg
        return cls(CorrectionParams(mass_kg=mass_kg, window=window), ext, **kwargs)


def correct(src: str | Path, dst: str | Path, setup: CorrectionSetup | None = None, *,
            to: str | None = None, path: str = 'auto',
            progress: Progress | None = None, mapper: Mapper | None = None,
            skip_failed: bool = False) -> CorrectionResult:
    """Correct and score a bag or a campaign; write the result to dst (a new bag or campaign).

    to: 'bag' or 'campaign' (default: the kind of src). path, for a bag: 'auto' (the fast path
    where it applies, else the generic one), 'fast' (CorrectionError if it does not apply),
    'fast_read' (the fast reader, the generic writer) or 'generic'.
    mapper (force_tester_common.engine.map_pulls or a Mapper): reads and writes a campaign's pull
    files in parallel; a bag is one file, read and written here in one pass, and the correction
    itself streams through each run in time order. skip_failed: a campaign's pull file that fails
    to read is left out (a warning names it) instead of failing the whole correction.
    """
    setup = CorrectionSetup() if setup is None else setup
    src, dst = Path(src), Path(dst)
    kind = source_kind(src)
    if setup.window_from_bandwidth and not dst.exists():   # the events decide the window, then correct
        events = _events_of(src, kind, setup.params, mapper, skip_failed)
        window = bandwidth_window([e for _pid, e, _rate in events], setup.params.window)
        chosen = replace(setup, params=replace(setup.params, window=window), window_from_bandwidth=False)
        res = correct(src, dst, chosen, to=to, path=path, progress=progress, mapper=mapper,
                      skip_failed=skip_failed)
        note = (f'window {window} samples chosen from the bandwidth of {len(events)} short event(s) '
                f'(instead of {setup.params.window})' if events else
                f'no short event: window {setup.params.window} kept')
        return replace(res, warnings=(note, *res.warnings))
    res = _correct(src, dst, setup, kind, to, path, progress, mapper, skip_failed)
    unscored = [w for w in res.warnings if 'but stationary has 0' in w]   # a bag of a rig with no stationary cell
    if unscored:
        res = replace(res, warnings=(*(w for w in res.warnings if w not in unscored),
                                     f'{len(unscored)} pull(s) have no stationary cell samples: corrected but not '
                                     'scored'))
    return res


def _with_short_events(result: CorrectionResult, found: list, setup: CorrectionSetup) -> CorrectionResult:
    """The result naming the short events ``found`` ([(pull_id, ShortEvent, rate)]), one warning each."""
    if not found:
        return result
    return replace(result, short_events=tuple(_event_dict(pid, e) for pid, e, _r in found),
                   warnings=(*result.warnings, *(f'pull {pid}: {e.line(rate)}' for pid, e, rate in found),
                             advice(setup.extension is not None)))


def _event_dict(pid, e) -> dict:
    return {'pull_id': int(pid), 'start_s': e.start_s, 'width_s': e.width_s, 'window': e.window,
            'peak_n': e.peak_n, 'filtered_peak_n': e.filtered_peak_n, 'loss': e.loss,
            'bandwidth_hz': e.bandwidth_hz, 'bandwidth_window': e.bandwidth_window,
            'bandwidth_loss': e.bandwidth_loss}


def _events_of(src: Path, kind: str, params: CorrectionParams, mapper, skip_failed) -> list:
    """[(pull_id, ShortEvent, rate)] of every pull: m*a on the moving cell (no moving average) against
    the same with ``params.window``."""
    from bag_tools.core.convert import read_bag_pulls
    from bag_tools.core.daq import read_campaign
    if kind == 'campaign':
        # here, not on the mapper: it counts its failed pulls, and the correction has reported those already
        camp = read_campaign(src, mapper=None, skip_failed=True)
        rate, pulls = camp.sample_rate_hz, [(p.meta.get('pull_id') or i + 1, p.channels)
                                            for i, p in enumerate(camp.pulls)]
    else:
        rate, bag_pulls = read_bag_pulls(src, [], None)
        pulls = [(p.meta['pull_id'], p.channels) for p in bag_pulls]
    out = []
    for pid, ch in pulls:
        corr = correct_signal(ch['force_moving_n'], ch['accel_axial_m_s2'], params).corrected_n
        out += [(pid, e, rate) for e in short_events(ch['force_moving_n'], corr, rate, params.window)]
    return out


def _correct(src: Path, dst: Path, setup: CorrectionSetup, kind: str, to, path: str, progress, mapper,
             skip_failed) -> CorrectionResult:
    to = to or kind
    if to not in ('bag', 'campaign'):
        raise CorrectionError(f'output kind {to!r} is invalid; expected bag or campaign')
    if path not in PATHS:
        raise CorrectionError(f'path {path!r} is invalid; expected one of {", ".join(PATHS)}')
    if dst.exists():
        raise CorrectionError(f'output {str(dst)!r} exists already; expected a new directory name')
    if kind == 'campaign' and to == 'bag':  # the same placement of pulls, then that bag
        if not dst.parent.is_dir():
            raise CorrectionError(f'parent directory {str(dst.parent)!r} of output {str(dst)!r} '
                                  'does not exist')
        import tempfile

        from bag_tools.core.convert import campaign_to_bag
        tmp = Path(tempfile.mkdtemp(prefix=f'.{dst.name}.import-', dir=dst.parent))
        try:
            warnings: list = []
            campaign_to_bag(src, tmp / 'bag', warnings=warnings, mapper=mapper, skip_failed=skip_failed)
            res = correct(tmp / 'bag', dst, setup, to='bag', path=path, progress=progress)
            return replace(res, warnings=(*warnings, *res.warnings))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    if kind == 'bag':
        return _correct_bag(src, dst, setup, to, path, progress, mapper)
    return _correct_campaign(src, dst, setup, mapper, skip_failed)


def _result(setup, pulls, stats, stream, path, warnings) -> CorrectionResult:
    """The result, with the short events the scorer found in the pulls it held (scorer.PullScorer)."""
    return _with_short_events(CorrectionResult(setup.params, setup.loaded_fraction, pulls,
                                               tuple(stats.summary(s) for s in sorted(stats.sets())),
                                               stream.nan_count, stream.runs, path, tuple(warnings)),
                              stream.scorer.events, setup)


def _correct_bag(src: Path, dst: Path, setup: CorrectionSetup, to: str, path: str,
                 progress, mapper) -> CorrectionResult:
    warnings: list = []
    fast = bagio.fast_bag(src) if path != 'generic' else None
    if fast is not None:
        fast.map_ahead()   # while the output, the stream and the message types are set up
    if path == 'fast' and fast is None:
        raise CorrectionError(f'bag {str(src)!r} is not one uncompressed MCAP file; the fast '
                              'path does not apply')
    target = bagio.extension_target(fast, dst) if to == 'bag' and path in ('auto', 'fast') \
        else None
    stream = CorrectionStream(setup.params, setup.extension, setup.loaded_fraction, peak_inputs=setup.peak_inputs,
                              keep=target is None)
    with target if target is not None else nullcontext():
        if target is not None:  # results go out as they are computed
            cids, sink = bagio.extended_sink(target)
            stream.write_to(sink)
        read, used = None, 'generic'
        if fast is not None:
            try:
                read = bagio.read_fast(fast, stream, warnings, progress, setup.max_pending,
                                       setup.segment_samples)
                used = 'fast'
            except FastPathError as exc:
                if path == 'fast':
                    raise CorrectionError(f'bag {str(src)!r}: the fast path does not apply: '
                                          f'{exc}') from None
        if read is None:
            read = bagio.read_generic(src, stream, warnings, progress, setup.max_pending)
        pulls, stats, score_warnings = stream.scores(read.windows, read.drops)
        warnings += score_warnings
        running = running_summaries(pulls, stats)
        if target is not None:
            bagio.write_results(target, cids, pulls, running)
    if to == 'bag':
        if target is None:
            bagio.rewrite_bag(src, dst, stream.arrays(), read, pulls, running, warnings)
        return _result(setup, pulls, stats, stream, used, warnings)
    from .campaign import bag_pulls_with_columns, write_corrected_campaign
    result = _result(setup, pulls, stats, stream, used, warnings)
    rate, camp_pulls = bag_pulls_with_columns(src, stream.arrays())
    write_corrected_campaign(dst, camp_pulls, rate, None, _scores_doc(result), mapper)
    return result


def _correct_campaign(src: Path, dst: Path, setup: CorrectionSetup, mapper, skip_failed) -> CorrectionResult:
    from bag_tools.core.daq import DaqPull, read_campaign

    from .campaign import correct_runs, write_corrected_campaign
    camp = read_campaign(src, mapper=mapper, skip_failed=skip_failed)
    stream = CorrectionStream(setup.params, setup.extension, setup.loaded_fraction, peak_inputs=setup.peak_inputs)
    windows, columns = correct_runs(camp, stream)
    pulls, stats, warnings = stream.scores(windows, [])
    if 'force_stationary_n' in camp.absent:   # one line, not one per pull
        warnings = [w for w in warnings if 'stationary peak nan' not in w]
        warnings.append('no stationary cell (absent in campaign.yaml): the pulls are corrected but not scored')
    result = _result(setup, pulls, stats, stream, 'campaign', [*camp.warnings, *warnings])
    camp_pulls = [DaqPull(p.meta, {**p.channels, **c}) for p, c in zip(camp.pulls, columns)]
    rig = (camp.path / camp.rig) if camp.rig else None
    write_corrected_campaign(dst, camp_pulls, camp.sample_rate_hz, rig, _scores_doc(result), mapper)
    return result


def _scores_doc(result: CorrectionResult) -> dict:
    doc = result.as_dict()
    del doc['warnings']
    return doc
