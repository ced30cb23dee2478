"""A bag's later segments corrected in a second process (force_correction.offline.split): the output bag, its
metadata.yaml and the result the same byte for byte as one process's, from a run's start or its middle; a child that
raises or dies is the parent's one error (no hang, nothing left), and `./ft bag correct` exits 2 with one line."""
from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from daq_data import RATE, T0, N, make_pulls

from bag_tools.core.convert import campaign_to_bag
from bag_tools.core.daq import write_campaign
from bag_tools.core.errors import BagError
from force_correction.core import CorrectionError, CorrectionParams
from force_correction.core.streaming import correct_block, initial_state, state_after
from force_correction.offline import CorrectionSetup, correct, scorer, split
from force_correction.offline import bag as bagio

PULLS = 10


def pulls_bag(tmp_path, joined: bool):
    """A bag of PULLS pulls: one continuous run (joined) or one run a pull."""
    pulls = make_pulls(PULLS, start=T0)
    if joined:
        for i, (m, _ch) in enumerate(pulls):
            m['start_ns'] = T0 + i * N * int(1e9 / RATE)
    return campaign_to_bag(write_campaign(tmp_path / 'camp', pulls), tmp_path / 'bag')


@pytest.fixture
def forked(monkeypatch):
    """Fork whatever the load (split.spare_core), and count the forks."""
    calls = []
    monkeypatch.setattr(split, 'spare_core', lambda: True)
    real = bagio.in_two

    def spy(stream, feed, own, theirs, *args):
        calls.append((len(own), len(theirs)))
        return real(stream, feed, own, theirs, *args)
    monkeypatch.setattr(bagio, 'in_two', spy)
    return calls


def files_of(bag):
    return {p.name: p.read_bytes() for p in sorted(bag.iterdir())}


@pytest.mark.parametrize('joined', [True, False])
def test_two_processes_write_the_same_bytes_as_one(tmp_path, forked, joined):
    bag = pulls_bag(tmp_path, joined)
    setup = {'segment_samples': 2 * N}   # several segments: places to split
    (tmp_path / 'a').mkdir()
    (tmp_path / 'b').mkdir()
    one = correct(bag, tmp_path / 'a' / 'out', CorrectionSetup(processes=1, **setup))
    assert not forked
    two = correct(bag, tmp_path / 'b' / 'out', CorrectionSetup(**setup))
    assert len(forked) == 1 and min(forked[0]) >= 1, forked
    assert one == two and len(two.pulls) == PULLS and two.runs == (1 if joined else PULLS)
    assert files_of(tmp_path / 'a' / 'out') == files_of(tmp_path / 'b' / 'out')


def test_too_few_pulls_or_a_busy_machine_stay_in_one_process(tmp_path, forked, monkeypatch):
    pulls = make_pulls(split.MIN_PULLS - 1, start=T0)
    bag = campaign_to_bag(write_campaign(tmp_path / 'camp', pulls), tmp_path / 'bag')
    correct(bag, tmp_path / 'out', CorrectionSetup(segment_samples=N))
    monkeypatch.setattr(split, 'spare_core', lambda: False)
    (tmp_path / 'many').mkdir()
    correct(pulls_bag(tmp_path / 'many', True), tmp_path / 'out2', CorrectionSetup(segment_samples=N))
    assert not forked


def test_state_after_is_the_streamed_state():
    rng = np.random.default_rng(3)
    f, a = rng.normal(0, 10, 5000), rng.normal(0, 5, 5000)
    f[[7, 4990]] = np.nan
    a[4995] = np.inf
    params = CorrectionParams(window=140)
    for k in (0, 1, 100, 139, 140, 4000, 5000):
        _out, state = correct_block(f[:k], a[:k], params, initial_state(params))
        assert state_after(f[:k], a[:k], params) == state, k


def _in_child_only(parent: int, act):
    real = scorer.score_pull

    def score_pull(*args, **kwargs):
        if os.getpid() != parent:
            act()
        return real(*args, **kwargs)
    return score_pull


def test_a_child_that_dies_is_one_error_and_leaves_nothing(tmp_path, forked, monkeypatch):
    bag = pulls_bag(tmp_path, True)
    monkeypatch.setattr(scorer, 'score_pull',
                        _in_child_only(os.getpid(), lambda: os.kill(os.getpid(), signal.SIGKILL)))
    with pytest.raises(CorrectionError, match=r'second process .* ended with signal 9 \(SIGKILL\) before sending '
                                              r'its results; expected its scores'):
        correct(bag, tmp_path / 'out', CorrectionSetup(segment_samples=2 * N))
    assert forked and not (tmp_path / 'out').exists()


def test_a_child_that_raises_raises_in_the_parent(tmp_path, forked, monkeypatch):
    bag = pulls_bag(tmp_path, False)

    def fail():   # not a CorrectionError: the scorer would make that the pull's outcome
        raise BagError("block 'x' is odd; expected a test")
    monkeypatch.setattr(scorer, 'score_pull', _in_child_only(os.getpid(), fail))
    with pytest.raises(BagError, match="block 'x' is odd; expected a test"):
        correct(bag, tmp_path / 'out', CorrectionSetup(segment_samples=2 * N))
    assert forked and not (tmp_path / 'out').exists()


CLI = """import os, signal, sys
from force_correction.offline import scorer, split
split.spare_core = lambda: True
parent, real = os.getpid(), scorer.score_pull
def score_pull(*a, **k):
    if os.getpid() != parent:
        os.kill(os.getpid(), signal.SIGKILL)
    return real(*a, **k)
scorer.score_pull = score_pull
from ft_cli.main import main
sys.exit(main(['bag', 'correct', sys.argv[1], sys.argv[2]]))
"""


def test_cli_exits_2_with_one_line_when_the_child_dies(tmp_path):
    # the default segments (2**17 samples) hold the whole bag: one that splits it needs more samples than PULLS
    # short pulls; a segment a pull instead, through the setup's default, is what the CLI cannot choose
    big = make_pulls(PULLS, start=T0, n=20 * N)
    for i, (m, _ch) in enumerate(big):
        m['start_ns'] = T0 + i * 20 * N * int(1e9 / RATE)
    bag = campaign_to_bag(write_campaign(tmp_path / 'big', big), tmp_path / 'bigbag')
    r = subprocess.run([sys.executable, '-c', CLI, str(bag), str(tmp_path / 'out')], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count('\n') == 1 and 'ended with signal 9 (SIGKILL)' in r.stderr, r.stderr
    assert not (tmp_path / 'out').exists()
