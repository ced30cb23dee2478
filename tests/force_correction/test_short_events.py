"""Issue 26 section 3: the correction on events shorter than a few moving-average windows. The peak loss is
estimated from the data and checked against the moving average's exact effect on a Gaussian impact (a
W-point average of a pulse of area A peaks at about A / W when the pulse is much narrower than W)."""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from daq_data import SRC_DIRS, run_cli

for _d in reversed(SRC_DIRS):
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'bag_tools'))

from test_daq_files import lvm_campaign  # noqa: E402

from force_correction.core.short_events import ShortEventMonitor, short_events, trailing_mean  # noqa: E402
from force_correction.offline import CorrectionSetup, correct  # noqa: E402
from force_tester_common.core.correction import SHORT_EVENT_WINDOWS, WINDOW  # noqa: E402

RATE = 100_000.0


def impact(sigma_s: float, n: int = 30_000, at_s: float = 0.12, peak: float = -3000.0, seed: int = 0):
    """A compression impact (Gaussian, ~1 ms from foot to foot for sigma 0.13 ms) on noise."""
    t = np.arange(n) / RATE
    noise = np.random.default_rng(seed).normal(0.0, 1.0, n)
    return peak * np.exp(-0.5 * ((t - at_s) / sigma_s) ** 2) + noise


def test_thesis_window_cuts_a_1ms_impact_by_about_80_percent():
    sigma = 0.13e-3                         # +-4 sigma ~ 1 ms
    f = impact(sigma)
    ev, = short_events(f, f, RATE, WINDOW)
    expect = 1 - math.sqrt(2 * math.pi) * sigma * RATE / WINDOW   # area / W against the peak
    assert ev.loss == pytest.approx(expect, abs=0.02)
    assert 0.7 < ev.loss < 0.9
    direct = 1 - np.max(-trailing_mean(f, WINDOW)) / np.max(-f)
    assert ev.loss == pytest.approx(direct, abs=0.01)
    assert ev.bandwidth_window < WINDOW / 3 and ev.bandwidth_loss < 0.2    # the option keeps the peak
    assert ev.width_s == pytest.approx(2.3548 * sigma, rel=0.05)


def test_a_long_pull_has_no_short_event():
    f = impact(20e-3, n=200_000, at_s=0.8)   # 47 ms wide: many windows
    assert short_events(f, f, RATE, WINDOW) == []
    noise = np.random.default_rng(1).normal(0, 1, 50_000)
    assert short_events(noise, noise, RATE, WINDOW) == []


def test_event_of_exactly_the_threshold_width():
    w = SHORT_EVENT_WINDOWS * WINDOW / RATE
    sigma = w / 2.3548
    assert short_events(impact(sigma * 0.9), impact(sigma * 0.9), RATE, WINDOW)
    assert not short_events(impact(sigma * 1.1), impact(sigma * 1.1), RATE, WINDOW)


def test_monitor_in_blocks_reports_each_event_once_as_batch():
    f = np.concatenate([impact(0.13e-3, n=150_000, at_s=0.3), impact(0.2e-3, n=150_000, at_s=0.9, seed=3)])
    mon = ShortEventMonitor(WINDOW, RATE)
    got = [e for k in range(0, f.size, 50) for e in mon.add(f[k:k + 50], f[k:k + 50])]
    got += mon.add(np.zeros(int(RATE)), np.zeros(int(RATE)))    # a quiet second lets the last one out
    assert [round(e.start_s, 3) for e in got] == pytest.approx([0.3, 2.4], abs=0.002)
    one, = short_events(f[:150_000], f[:150_000], RATE, WINDOW)
    assert got[0].loss == pytest.approx(one.loss, abs=1e-9)


def test_correct_names_short_events_and_the_bandwidth_option(tmp_path):
    folder, _truth = lvm_campaign(tmp_path, n=10_000, records=2)
    res = correct(folder, tmp_path / 'out', CorrectionSetup())
    lines = [w for w in res.warnings if 'cuts its peak by' in w]
    assert len(lines) == 2 and all(w.startswith('pull ') for w in lines)
    assert any('--window-from-bandwidth' in w for w in res.warnings)
    assert any('not scored' in w for w in res.warnings)          # no stationary cell: said once
    doc = json.loads((tmp_path / 'out' / 'scores.json').read_text())
    assert [e['pull_id'] for e in doc['short_events']] == [1, 2]
    assert all(0.3 < e['loss'] < 0.8 and e['window'] == WINDOW for e in doc['short_events'])
    res2 = correct(folder, tmp_path / 'out2', CorrectionSetup(window_from_bandwidth=True))
    assert res2.params.window == min(e['bandwidth_window'] for e in doc['short_events']) < WINDOW
    r = run_cli('correct', folder, tmp_path / 'out3', module='force_correction.offline.cli')
    assert r.returncode == 0, r.stderr
    assert r.stderr.count('the moving average cuts its peak by') == 2


def test_correct_on_a_bag_without_stationary_cell_finds_them_too(tmp_path):
    from bag_tools.core.convert import campaign_to_bag
    folder, _truth = lvm_campaign(tmp_path, n=10_000, records=2)
    bag = campaign_to_bag(folder, tmp_path / 'bag')
    res = correct(bag, tmp_path / 'out', CorrectionSetup())
    assert sum('cuts its peak by' in w for w in res.warnings) == 2
    assert sum('not scored' in w for w in res.warnings) == 1            # one line, not one per pull
    assert [e['pull_id'] for e in res.short_events] == [1, 2]


def test_noise_and_a_removed_wiggle_are_not_short_events_and_no_loss_reads_minus_zero():
    """Between pulls (issue 41, Low): noise spikes of a quiet record were reported as short events ('cuts its peak by
    95 % (0.38 -> 0.02 N) ... bandwidth: -0 %'), and so was a wiggle of the moving cell that the m*a correction
    removes. An event is reported only when its corrected peak stands EVENT_SNR noise deviations clear of the
    corrected force's noise; a loss below 0 (a window that raises a peak a little) reads 0 %."""
    from force_correction.core.short_events import ShortEvent, percent
    rate, n = 50_000.0, 50_000
    t = np.arange(n) / rate
    noise = np.random.default_rng(2).normal(0.0, 0.1, n)
    wide = 2.3 * np.sin(2 * np.pi * t / 4e-3) * np.exp(-0.5 * ((t - 0.5) / 1e-3) ** 2)
    found = short_events(wide + noise, wide + noise, rate, WINDOW)
    assert [round(e.start_s, 2) for e in found] == [0.5], [e.line(rate) for e in found]   # the wiggle alone
    inertial = 2.3 * np.exp(-0.5 * ((t - 0.5) / 0.2e-3) ** 2)   # in the moving cell only: m*a removes it
    assert short_events(inertial + noise, noise, rate, WINDOW) == []
    assert percent(-0.004) == '0' and percent(0.5) == '50'
    assert '-0 %' not in ShortEvent(0.1, 1e-3, WINDOW, 2.0, 1.0, 1e3, 5, 2.01).line(rate)
