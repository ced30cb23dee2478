"""Fuzzing every reader (issue 40): a few hundred mutated inputs per format through the real reader functions
(tests/bag_tools/fuzz.py), a handful through the real `./ft bag` in a subprocess, and each defect the fuzzing
found as its own regression test. Every bad input must end in a BagError of one line (exit 2 on the CLI), never
another exception, a traceback on stderr, a crash or a hang. `./ft bench fuzz` runs 10^4 a format."""
from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import pytest
import yaml
from daq_data import run_cli
from fuzz import FORMATS, Readers, cli_command, cli_verdict, keep_seed_lvm, mutate, seed_files

from bag_tools.core.channel_map import load_channel_map
from bag_tools.core.daqfiles import read_records
from bag_tools.core.errors import BagError

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / 'tests' / 'bag_tools' / 'data' / 'fuzz'
#: inputs per format in the suite, and the seconds one input may take
INPUTS = 300
LIMIT_S = 10.0
#: the formats whose few hundred inputs take over 5 s (a bag read, an MDF4 read in a forked child: 17-21 s)
SLOW = {'metadata', 'mcap', 'mf4'}


@pytest.fixture(scope='module')
def fuzzed(tmp_path_factory):
    root = tmp_path_factory.mktemp('fuzz')
    seeds = seed_files(root)
    keep_seed_lvm(root)
    return root, seeds, Readers(root)


class Hang(Exception):
    pass


def _alarm(_signum, _frame):
    raise Hang()


@pytest.mark.parametrize('fmt', [pytest.param(f, marks=pytest.mark.slow) if f in SLOW else f for f in FORMATS])
def test_mutated_inputs_end_in_one_line_or_are_read(fmt, fuzzed):
    root, seeds, readers = fuzzed
    assert readers.feed(fmt, seeds[fmt]) == ('accepted', '')        # the seed itself is valid
    counts = {'accepted': 0, 'clean': 0, 'traceback': 0, 'noise': 0}
    bad = []
    old = signal.signal(signal.SIGALRM, _alarm)
    try:
        for i in range(INPUTS):
            data = mutate(fmt, seeds[fmt], 0, i)
            signal.setitimer(signal.ITIMER_REAL, LIMIT_S)
            try:
                outcome, detail = readers.feed(fmt, data)
            except Hang:
                outcome, detail = 'traceback', f'over {LIMIT_S} s'
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            counts[outcome] += 1
            if outcome in ('traceback', 'noise'):
                bad.append((i, outcome, detail))
    finally:
        signal.signal(signal.SIGALRM, old)
        readers.path(fmt).write_bytes(seeds[fmt])
    assert not bad, f'{fmt}: {len(bad)} of {INPUTS} inputs ended in a defect; first: {bad[:3]}'
    assert counts['clean'] > 0, counts          # the mutations reach the checks (the fuzzing can find something)


@pytest.mark.slow
@pytest.mark.parametrize('fmt', FORMATS)
def test_mutated_inputs_through_the_real_cli(fmt, fuzzed, tmp_path):
    """Two inputs a format through `./ft bag import ... --dry-run` or `./ft bag info`: exit 0, or exit 2 with one
    line; no traceback, no 'internal error', no hang."""
    root, seeds, readers = fuzzed
    verdicts = []
    try:
        for i in range(2):
            data = mutate(fmt, seeds[fmt], 0, 10_000 + i)
            readers.path(fmt).write_bytes(data)
            try:
                r = subprocess.run([str(ROOT / 'ft'), 'bag', *cli_command(fmt, root)], capture_output=True,
                                   text=True, timeout=120, cwd=ROOT)
                verdicts.append((i, r.returncode, cli_verdict(r.returncode, r.stderr), r.stderr[-300:]))
            except subprocess.TimeoutExpired:
                verdicts.append((i, None, 'hang', ''))
    finally:
        readers.path(fmt).write_bytes(seeds[fmt])
    assert all(v[2] == 'ok' for v in verdicts), verdicts


# --------------------------------------------------------------------------- each defect the fuzzing found
@pytest.mark.slow
def test_an_mdf4_file_that_crashes_asammdf_is_one_line(tmp_path):
    """asammdf dies of a segmentation fault on this file (data/fuzz/README.md); read_mdf parses in a forked
    child, so the command says so in one line and lives (before: the process died, no message)."""
    with pytest.raises(BagError, match=r'the MDF4 reader \(asammdf\) crashed on it \(exit code -11\)'):
        read_records(DATA / 'asammdf_segfault.mf4')
    r = run_cli('import', DATA / 'asammdf_segfault.mf4', '--dry-run')
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'crashed on it' in r.stderr, r.stderr


@pytest.mark.slow
def test_a_corrupt_mdf4_leaves_no_library_noise_on_stderr(tmp_path):
    """asammdf logs 'asammdf - ERROR - ...' and its half-built object's __del__ prints 'Exception ignored ...
    AttributeError' on a corrupt header: the user sees the one line only."""
    good = (DATA / 'asammdf_segfault.mf4').read_bytes()
    bad = tmp_path / 'header.mf4'
    bad.write_bytes(good[:64] + b'\0' * 64 + good[128:])
    r = run_cli('import', bad, '--dry-run')
    assert r.returncode == 2 and r.stderr.count('\n') == 1, r.stderr
    assert 'Traceback' not in r.stderr and 'asammdf - ERROR' not in r.stderr


@pytest.mark.parametrize('change, expect', [
    ({'range': ''}, "range '' is invalid"),
    ({'sign': {'a': 1}}, "sign {'a': 1} is invalid"),
    ({'sign': True}, 'sign True is invalid'),
    ({'absent': True}, 'absent True is invalid'),
    ({'absent': 3}, 'absent 3 is invalid'),
])
def test_channel_map_values_of_the_wrong_kind_are_one_line(change, expect):
    doc = {'channels': {'force_moving_n': {'source': 'Load cell', 'unit': 'V', 'sensitivity': '0.225 mV/N'},
                        'accel_axial_m_s2': 'Accel'}, 'absent': ['force_stationary_n', 'encoder_position_m']}
    if 'absent' in change:
        doc.update(change)
    else:
        doc['channels']['force_moving_n'].update(change)
    with pytest.raises(BagError, match=expect.replace('{', r'\{').replace('}', r'\}')):
        load_channel_map(doc)


def test_a_channel_map_that_is_not_utf8_is_one_line(tmp_path):
    m = tmp_path / 'map.yaml'
    m.write_bytes(b'channels:\n  force_moving_n: \xff\xfe\n')
    with pytest.raises(BagError, match='map.yaml is not UTF-8 text'):
        load_channel_map(m)


def test_a_campaign_file_name_too_long_for_the_file_system_is_bad_input(tmp_path):
    """A pull file name over 255 bytes: the file system refuses it (OSError ENAMETOOLONG), which the CLI reported as
    an I/O failure, exit 1; it is bad input: exit 2, one line."""
    (tmp_path / 'lab').mkdir()
    (tmp_path / 'lab' / 'campaign.yaml').write_text(yaml.safe_dump({'pulls': [{'file': 'a' * 300 + '.csv'}]}))
    r = run_cli('--verbose', 'import', tmp_path / 'lab', '--dry-run')
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'does not exist' in r.stderr, r.stderr


@pytest.mark.slow
def test_the_fuzz_benchmark_prints_its_table_and_refuses_an_unknown_format():
    r = subprocess.run([str(ROOT / 'ft'), 'bench', 'fuzz', '--inputs', '20', '--cli', '1', '--formats', 'csv,uff'],
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    rows = {line.split()[0]: line.split()[1:] for line in r.stdout.splitlines() if line.startswith(('csv ', 'uff '))}
    assert set(rows) == {'csv', 'uff'} and all(v[0] == '20' for v in rows.values())
    assert all(int(v[1]) + int(v[2]) == 20 and v[3:6] == ['0', '0', '0'] for v in rows.values()), rows
    assert 'csv          1/1 ok' in r.stdout and 'defects: 0' in r.stdout
    r = subprocess.run([str(ROOT / 'ft'), 'bench', 'fuzz', '--formats', 'xls'], capture_output=True, text=True,
                       timeout=120, cwd=ROOT)
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and "format 'xls' is unknown" in r.stderr


def test_a_time_column_whose_rate_is_infinite_is_one_line(tmp_path):
    """An MDF4 time channel stepping by a subnormal number: its rate is inf (before: OverflowError in snap_rate,
    an internal error); now the pull's time check says what is wrong."""
    from bag_tools.core.channel_map import apply_map
    from bag_tools.core.daq import check_channels
    from bag_tools.core.daqfiles import Record, snap_rate
    assert snap_rate(float('inf')) == float('inf') and snap_rate(25_000.0000001) == 25_000.0
    n = 5
    rec = Record({'force_moving_n': [1.0] * n, 'accel_axial_m_s2': [0.0] * n}, {}, snap_rate(float('inf')),
                 None)
    raw, absent, _used = apply_map(rec, load_channel_map({'channels': {}, 'absent': [
        'force_stationary_n', 'encoder_position_m']}), 'x.mf4')
    with pytest.raises(BagError, match='time_s is not increasing'):
        check_channels(raw, 'x.mf4', None, [], absent)


@pytest.mark.slow
@pytest.mark.parametrize('fmt, i, expect', [
    ('metadata', 1103, 'relative_file_paths -9223372036854775808 is invalid; expected a list'),   # was TypeError
    ('mcap', 1366, 'PullEvent message on /pull_event is not what the type says'),   # was AttributeError
    # an infinite rate: was OverflowError. asammdf stamps the seed file's history with the time it was written, so
    # the mutated bytes differ from run to run: some runs read a NaN time before the infinite rate (two fresh clones
    # of ~20 said 'time_s is np.float64(nan) at row 2996; expected finite times'): either is the time check's line
    ('mf4', 1001, 'time_s is '),
])
def test_inputs_the_fuzz_benchmark_found(fmt, i, expect, fuzzed):
    """Inputs of `./ft bench fuzz` (seed 0) that ended in another exception; each is now a one-line BagError: a bag
    whose metadata.yaml lists its files as a number, an MCAP whose embedded PullEvent definition lost test_set, an
    MDF4 time channel spanning a subnormal interval."""
    _root, seeds, readers = fuzzed
    try:
        outcome, detail = readers.feed(fmt, mutate(fmt, seeds[fmt], 0, i))
    finally:
        readers.path(fmt).write_bytes(seeds[fmt])
    assert outcome == 'clean' and expect in detail, (outcome, detail)
