"""DAQ files as other labs write them (issue 26): LabVIEW LVM text, ASAM MDF4, UFF 58, through a channel
map, from a rig unlike ours: a drop impactor in volts, no stationary cell, no encoder, compression impacts,
100 kHz and 25 kHz. The files are written with the libraries' own writers (asammdf, pyuff) and, for LVM,
as LabVIEW writes its text format (the header layout of lvm-read's sample files)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import yaml
from daq_data import (
    ACCEL_MV_PER_G,
    FORCE_MV_PER_N,
    IMPACTOR_CHANNEL_MAP,
    SRC_DIRS,
    run_cli,
    write_lvm,
    write_mf4,
    write_uff,
)

for _d in reversed(SRC_DIRS):
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))

from bag_tools.core.channel_map import load_channel_map  # noqa: E402
from bag_tools.core.convert import bag_to_campaign, campaign_to_bag  # noqa: E402
from bag_tools.core.daq import read_campaign  # noqa: E402
from bag_tools.core.daqfiles import read_records  # noqa: E402
from bag_tools.core.errors import BagError  # noqa: E402
from force_tester_common.core.units import G_M_S2  # noqa: E402


def impact_record(rate: float, n: int, seed: int, width_s: float = 1e-3, peak_n: float = 2000.0):
    """SI channels of one drop-impact record (tension positive: a compression impact is negative force)
    and the volts the rig's DAQ saw (its convention: compression positive)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    t0 = (0.3 + 0.1 * rng.random()) * n / rate
    s = np.clip((t - t0) / width_s, 0.0, 1.0)
    pulse = np.where((t >= t0) & (t <= t0 + width_s), np.sin(np.pi * s), 0.0)
    force = -peak_n * (1 + 0.1 * seed) * pulse + rng.normal(0, 2.0, n)
    accel = -0.9 * force / 1.5 + rng.normal(0, 5.0, n)            # the mass in front of the cell, about 1.5 kg
    volts = {'Load cell': -force * FORCE_MV_PER_N * 1e-3, 'Accel': -accel / G_M_S2 * ACCEL_MV_PER_G * 1e-3}
    return {'force_moving_n': force, 'accel_axial_m_s2': accel}, volts


CHANNEL_MAP = IMPACTOR_CHANNEL_MAP


def write_map(path, doc=None, **changes):
    doc = yaml.safe_load(yaml.safe_dump(doc or CHANNEL_MAP))
    for key, value in changes.items():
        ch, field = key.split('__')
        doc['channels'][ch][field] = value
    path.write_text(yaml.safe_dump(doc))
    return path


def lvm_campaign(tmp_path, rate=100_000.0, n=20_000, records=4):
    folder = tmp_path / 'lab'
    folder.mkdir()
    write_map(folder / 'channels.yaml')
    truth, entries = [], []
    for i in range(records):
        si, volts = impact_record(rate, n, i)
        write_lvm(folder / f'rec{i + 1}.lvm', volts, rate)
        truth.append(si)
        entries.append({'file': f'rec{i + 1}.lvm', 'set': 0, 'coupon_lbf': 0.0, 'velocity_fps': 0.0,
                        'decel_g': 0.0})
    (folder / 'campaign.yaml').write_text(yaml.safe_dump({'channels': 'channels.yaml', 'pulls': entries}))
    return folder, truth


# --------------------------------------------------------------------------- reading
def test_lvm_campaign_through_channel_map_equals_generator(tmp_path):
    folder, truth = lvm_campaign(tmp_path)
    camp = read_campaign(folder)
    assert camp.sample_rate_hz == 100_000.0
    assert camp.absent == ('encoder_position_m', 'force_stationary_n')
    assert len(camp.pulls) == 4
    for pull, si in zip(camp.pulls, truth):
        assert 'force_stationary_n' not in pull.channels and 'encoder_position_m' not in pull.channels
        for ch, v in si.items():   # %.9E in the file: 10 significant digits
            np.testing.assert_allclose(pull.channels[ch], v, rtol=1e-9, atol=1e-9 * np.abs(v).max())
        assert pull.channels['force_moving_n'].min() < -1000   # compression came out negative


def test_mf4_written_by_asammdf_and_uff_by_pyuff(tmp_path):
    si, volts = impact_record(25_000.0, 5000, 7)
    for writer, name, rtol in ((write_mf4, 'x.mf4', 1e-15), (write_uff, 'x.uff', 1e-10)):   # UFF: %20.11e
        rec, = read_records(writer(tmp_path / name, volts, 25_000.0))
        assert rec.rate_hz == 25_000.0 and set(rec.channels) >= {'Load cell', 'Accel'}
        assert rec.units['Load cell'] == 'V'
        from bag_tools.core.channel_map import apply_map
        out, absent, _used = apply_map(rec, load_channel_map(CHANNEL_MAP), name)
        assert absent == ('encoder_position_m', 'force_stationary_n')
        for ch, v in si.items():
            np.testing.assert_allclose(out[ch], v, rtol=rtol, atol=rtol * np.abs(v).max())
        np.testing.assert_array_equal(out['time_s'], np.arange(5000) / 25_000.0)


def test_absent_survives_bag_round_trip(tmp_path):
    folder, truth = lvm_campaign(tmp_path, n=4000, records=2)
    bag = campaign_to_bag(folder, tmp_path / 'bag')
    back = read_campaign(bag_to_campaign(bag, tmp_path / 'back'))
    assert back.absent == ('encoder_position_m', 'force_stationary_n')
    assert yaml.safe_load((tmp_path / 'back' / 'campaign.yaml').read_text())['absent'] == list(back.absent)
    for pull, si in zip(back.pulls, truth):
        np.testing.assert_allclose(pull.channels['force_moving_n'], si['force_moving_n'], rtol=1e-9,
                                   atol=1e-6)


def test_dry_run_prints_channels_rate_duration_events(tmp_path):
    si, volts = impact_record(25_000.0, 10_000, 3)
    f = write_mf4(tmp_path / 'drop.mf4', volts, 25_000.0)
    m = write_map(tmp_path / 'map.yaml')
    r = run_cli('import', f, '--channels', m, '--dry-run')
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert '1 pull(s) at 25000 Hz' in out
    assert "force_moving_n [N] <- 'Load cell' in V, sensitivity 0.225 mV/N compression positive" in out
    assert "accel_axial_m_s2 [m/s^2] <- 'Accel' in V" in out
    assert 'absent: encoder_position_m, force_stationary_n' in out
    assert 'duration 0.4 s, 1 event(s)' in out
    assert not (tmp_path / 'bag').exists()
    r = run_cli('import', f, tmp_path / 'bag', '--channels', m)
    assert r.returncode == 0, r.stderr
    assert 'imported 1 pull(s) at 25000 Hz' in r.stdout


def test_dry_run_of_lvm_campaign_counts_events(tmp_path):
    folder, _truth = lvm_campaign(tmp_path, n=10_000)
    r = run_cli('import', folder, '--dry-run')
    assert r.returncode == 0, r.stderr
    assert '4 pull(s) at 100000 Hz' in r.stdout and 'duration 0.4 s, 4 event(s)' in r.stdout


# --------------------------------------------------------------------------- bad input: one line, key and value
@pytest.mark.parametrize('change, expect', [
    ({'force_moving_n__source': 'Kraft'}, "source 'Kraft' is not a channel of the file"),
    ({'force_moving_n__unit': 'furlong'}, "unit 'furlong' is not a unit I can convert"),
    ({'accel_axial_m_s2__sensitivity': '0 mV/g'}, "sensitivity '0 mV/g' is invalid"),
    ({'force_moving_n__sensitivity': '0.225 mV/g'}, "sensitivity '0.225 mV/g' is in mV/g"),
    ({'force_moving_n__sign': 'up'}, "sign 'up' is invalid"),
    ({'accel_axial_m_s2__range': '0 g'}, "range '0 g' is invalid"),
    ({'accel_axial_m_s2__range': '50 kN'}, "range '50 kN' is in kN; expected a unit of acceleration"),
    ({'accel_axial_m_s2__range': '50 furlong'}, "range unit 'furlong' is not a unit I can convert"),
])
def test_bad_channel_map_is_one_line(tmp_path, change, expect):
    _si, volts = impact_record(25_000.0, 2000, 1)
    f = write_mf4(tmp_path / 'drop.mf4', volts, 25_000.0)
    r = run_cli('import', f, tmp_path / 'bag', '--channels', write_map(tmp_path / 'map.yaml', **change))
    assert r.returncode == 2
    assert r.stderr.count('\n') == 1 and expect in r.stderr and 'Traceback' not in r.stderr, r.stderr
    assert not (tmp_path / 'bag').exists()


def test_rated_range_in_physical_or_file_units(tmp_path):
    """A channel map's range: (the sensor's rated range) in a unit of the channel's kind or in the file's unit,
    to SI as the values are; --dry-run says it."""
    from force_tester_common.core.units import G_M_S2
    m = write_map(tmp_path / 'map.yaml', accel_axial_m_s2__range='500 g', force_moving_n__range='4.5 V')
    cmap = load_channel_map(m)
    assert cmap.specs['accel_axial_m_s2'].rated == pytest.approx(500 * G_M_S2)
    assert cmap.specs['force_moving_n'].rated == pytest.approx(4.5 / 0.225e-3)      # 0.225 mV/N: 20 kN
    assert cmap.specs['force_moving_n'].rated != cmap.specs['accel_axial_m_s2'].rated
    _si, volts = impact_record(25_000.0, 2000, 1)
    r = run_cli('import', write_mf4(tmp_path / 'drop.mf4', volts, 25_000.0), '--channels', m, '--dry-run')
    assert r.returncode == 0, r.stderr
    assert 'rated +/-20000 N' in r.stdout and f'rated +/-{500 * G_M_S2:.6g} m/s^2' in r.stdout, r.stdout


def test_unknown_format_lists_known(tmp_path):
    f = tmp_path / 'scope.wfm'
    f.write_bytes(b'\0' * 10)
    r = run_cli('import', f, tmp_path / 'bag')
    assert r.returncode == 2 and r.stderr.count('\n') == 1
    for known in ('.csv', '.tdms', '.lvm', '.mf4', '.uff'):
        assert known in r.stderr


def test_no_moving_cell_is_nothing_to_correct(tmp_path):
    _si, volts = impact_record(25_000.0, 2000, 1)
    f = write_mf4(tmp_path / 'drop.mf4', {'Accel': volts['Accel']}, 25_000.0)
    doc = yaml.safe_load(yaml.safe_dump(CHANNEL_MAP))
    del doc['channels']['force_moving_n']
    r = run_cli('import', f, tmp_path / 'bag', '--channels', write_map(tmp_path / 'map.yaml', doc))
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'there is nothing to correct' in r.stderr
    doc['absent'].append('force_moving_n')
    with pytest.raises(BagError, match='nothing to correct'):
        load_channel_map(doc)


def test_rate_from_the_map_when_the_file_has_none(tmp_path):
    si, volts = impact_record(100_000.0, 3000, 2)
    (tmp_path / 'a.csv').write_text('Load cell,Accel\n' + '\n'.join(
        f'{a!r},{b!r}' for a, b in zip(volts['Load cell'].tolist(), volts['Accel'].tolist())) + '\n')
    doc = yaml.safe_load(yaml.safe_dump(CHANNEL_MAP))
    m = write_map(tmp_path / 'map.yaml', doc)
    r = run_cli('import', tmp_path / 'a.csv', '--channels', m, '--dry-run')
    assert r.returncode == 2 and 'sample_rate_hz' in r.stderr
    doc['sample_rate_hz'] = 100_000
    m = write_map(tmp_path / 'map.yaml', doc)
    r = run_cli('import', tmp_path / 'a.csv', '--channels', m, '--dry-run')
    assert r.returncode == 0, r.stderr
    assert '1 pull(s) at 100000 Hz' in r.stdout and 'duration 0.03 s' in r.stdout


def test_example_channel_map_reads_the_lab_files(tmp_path):
    from pathlib import Path
    example = Path(__file__).resolve().parents[2] / 'config' / 'channel_maps' / 'drop_impactor.yaml'
    cmap = load_channel_map(example)
    assert cmap.absent == ('encoder_position_m', 'force_stationary_n') and cmap.sample_rate_hz == 100_000.0
    assert cmap.specs['force_moving_n'].rated == 20_000.0 and cmap.specs['accel_axial_m_s2'].rated > 4900.0
    si, volts = impact_record(100_000.0, 3000, 4)
    from bag_tools.core.channel_map import apply_map
    out, _absent, _used = apply_map(read_records(write_mf4(tmp_path / 'x.mf4', volts, 100_000.0))[0], cmap, 'x')
    np.testing.assert_allclose(out['force_moving_n'], si['force_moving_n'], rtol=1e-12, atol=1e-9)


# --------------------------------------------------------------------------- campaign CSV at disk speed
def test_fast_csv_writer_writes_reprs_bytes(tmp_path):
    from bag_tools.core.daq import write_csv
    rng = np.random.default_rng(5)
    n = 40_000
    mag = 10.0 ** rng.uniform(-12, 18, n) * rng.choice([-1.0, 1.0], n) * rng.uniform(1, 10, n)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 5e-324, 1e-310, 1.7976931348623157e308, 1e-5, 1e-4,
                        9.999999999999999e-05, 1e16, 9999999999999998.0, 123456789012345.0, 2e-05, 1.0, -3.0])
    mag[:special.size] = special
    ch = {'time_s': np.arange(n) / 100_000.0, 'x': mag, 'whole': np.round(mag * 1e-10),
          'few': rng.choice([0.0, -0.0, 4.572, 1e-7, np.nan], n)}      # few distinct values: formatted once each
    write_csv(tmp_path / 'a.csv', ch)
    expect = 'time_s,x,whole,few\n' + ''.join(
        ','.join(map(repr, row)) + '\n' for row in zip(*(v.tolist() for v in ch.values())))
    assert (tmp_path / 'a.csv').read_text() == expect


def test_fast_csv_reader_reads_what_float_reads(tmp_path):
    from bag_tools.core.daq import read_csv
    rows = ['1.5,nan,', '-0.0,inf,2e-05', '5e-324,-inf,NaN', '0.1,1e+16,3']
    (tmp_path / 'a.csv').write_text('a,b,c\n' + '\n'.join(rows) + '\n')
    got = read_csv(tmp_path / 'a.csv')
    for j, name in enumerate('abc'):
        want = np.array([float(r.split(',')[j]) if r.split(',')[j] else np.nan for r in rows])
        assert got[name].tobytes() == want.tobytes(), name
    (tmp_path / 'b.csv').write_text('a,b\n1.0,2.0\n3.0,x\n')       # refused by pyarrow: the line is named
    with pytest.raises(BagError, match="line 3: value 'x' is not a number"):
        read_csv(tmp_path / 'b.csv')


def test_lvm_of_several_segments_imports_a_pull_each(tmp_path):
    records = [impact_record(100_000.0, 5000, k) for k in range(3)]
    one = write_lvm(tmp_path / 'one.lvm', records[0][1], 100_000.0).read_text()
    head, seg = one.split('***End_of_Header***\t\n', 1)      # the file header, then '\t' + a segment
    segs = [write_lvm(tmp_path / f's{k}.lvm', v, 100_000.0).read_text().split('***End_of_Header***\t\n', 1)[1]
            for k, (_si, v) in enumerate(records)]
    f = tmp_path / 'three.lvm'
    f.write_text(head + '***End_of_Header***\t\n' + ''.join(segs))
    assert len(read_records(f)) == 3
    r = run_cli('import', f, '--channels', write_map(tmp_path / 'map.yaml'), '--dry-run')
    assert r.returncode == 0, r.stderr
    assert '3 pull(s) at 100000 Hz' in r.stdout and 'duration 0.15 s, 3 event(s)' in r.stdout


# --------------------------------------------------------------------------- units as labs write them (issue 40)
def test_units_as_labs_write_them_import(tmp_path):
    """LADISK's LabVIEW files label force 'Newtons' and acceleration 'g'; others write 'G', 'Volts', 'm/s²'. A map
    that only names the sources imports them, and a map's units, sensitivities and ranges take the same
    spellings; an unknown label is still refused in one line that names the known units."""
    si, volts = impact_record(25_000.0, 5000, 2)
    accel_g = -si['accel_axial_m_s2'] / G_M_S2
    f = write_lvm(tmp_path / 'hammer.lvm', {'Force': -si['force_moving_n'], 'Accel': accel_g}, 25_000.0,
                  units={'Force': 'Newtons', 'Accel': 'G'})
    doc = {'channels': {'force_moving_n': {'source': 'Force', 'sign': 'compression'},
                        'accel_axial_m_s2': {'source': 'Accel', 'sign': 'compression', 'range': '500 G'}},
           'absent': ['force_stationary_n', 'encoder_position_m']}
    r = run_cli('import', f, '--channels', write_map(tmp_path / 'map.yaml', doc), '--dry-run')
    assert r.returncode == 0, r.stderr
    assert "force_moving_n [N] <- 'Force' in Newtons" in r.stdout and "<- 'Accel' in G" in r.stdout, r.stdout
    assert f'rated +/-{500 * G_M_S2:.6g} m/s^2' in r.stdout
    r = run_cli('import', f, tmp_path / 'bag', '--channels', tmp_path / 'map.yaml')
    assert r.returncode == 0, r.stderr
    back = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'back')).pulls[0].channels
    np.testing.assert_allclose(back['force_moving_n'], si['force_moving_n'], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(back['accel_axial_m_s2'], si['accel_axial_m_s2'], rtol=1e-9, atol=1e-6)

    spelled = write_map(tmp_path / 'volts.yaml', force_moving_n__unit='Volts',
                        force_moving_n__sensitivity=f'{FORCE_MV_PER_N} millivolts/newton',
                        accel_axial_m_s2__unit='volt', accel_axial_m_s2__sensitivity=f'{ACCEL_MV_PER_G} mv/G')
    rec, = read_records(write_lvm(tmp_path / 'volts.lvm', volts, 25_000.0))
    from bag_tools.core.channel_map import apply_map
    out, _absent, _used = apply_map(rec, load_channel_map(spelled), 'volts.lvm')
    for ch, v in si.items():
        np.testing.assert_allclose(out[ch], v, rtol=1e-9, atol=1e-9 * np.abs(v).max())

    f = write_lvm(tmp_path / 'odd.lvm', {'Force': si['force_moving_n'], 'Accel': accel_g}, 25_000.0,
                  units={'Force': 'Kilopond', 'Accel': 'G'})
    r = run_cli('--verbose', 'import', f, '--channels', tmp_path / 'map.yaml', '--dry-run')
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'Traceback' not in r.stderr, r.stderr
    assert "has unit 'Kilopond', not one I can convert" in r.stderr and 'known units: N, kN' in r.stderr


def test_bridge_output_in_mv_per_v_with_a_scale(tmp_path):
    """A strain-gauge amplifier that records mV/V: scale: 2500 N/(mV/V) is 2 mV/V at 5 kN."""
    si, _volts = impact_record(25_000.0, 3000, 5)
    f = write_lvm(tmp_path / 'bridge.lvm', {'Bridge': si['force_moving_n'] / 2500.0, 'Accel': si['accel_axial_m_s2']},
                  25_000.0, units={'Bridge': 'mV/V', 'Accel': 'm/s²'})
    doc = {'channels': {'force_moving_n': {'source': 'Bridge', 'unit': 'mV/V', 'scale': '2500 N/(mV/V)'},
                        'accel_axial_m_s2': {'source': 'Accel'}},
           'absent': ['force_stationary_n', 'encoder_position_m']}
    cmap = load_channel_map(doc)
    assert cmap.specs['force_moving_n'].factor == pytest.approx(2500.0)
    from bag_tools.core.channel_map import apply_map
    out, _absent, _used = apply_map(read_records(f)[0], cmap, 'bridge.lvm')
    np.testing.assert_allclose(out['force_moving_n'], si['force_moving_n'], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(out['accel_axial_m_s2'], si['accel_axial_m_s2'], rtol=1e-9, atol=1e-6)


@pytest.mark.slow
def test_campaign_yaml_with_only_file_keys_imports(tmp_path):
    """Issue 40 item 3: another lab's campaign.yaml names its files and nothing of our rig (set, coupon, speed,
    deceleration are 0: unknown); a key given is still checked."""
    folder, truth = lvm_campaign(tmp_path, n=4000, records=2)
    (folder / 'campaign.yaml').write_text(yaml.safe_dump({'channels': 'channels.yaml',
                                                          'pulls': [{'file': 'rec1.lvm'}, {'file': 'rec2.lvm'}]}))
    r = run_cli('import', folder, tmp_path / 'bag')
    assert r.returncode == 0, r.stderr
    back = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'back'))
    assert [p.meta['set'] for p in back.pulls] == [0, 0]
    assert {p.meta['coupon_lbf'] for p in back.pulls} == {p.meta['velocity_fps'] for p in back.pulls} == {0.0}
    np.testing.assert_allclose(back.pulls[1].channels['force_moving_n'], truth[1]['force_moving_n'], rtol=1e-9,
                               atol=1e-6)
    (folder / 'campaign.yaml').write_text(yaml.safe_dump({'channels': 'channels.yaml',
                                                          'pulls': [{'file': 'rec1.lvm', 'decel_g': 'fast'}]}))
    r = run_cli('import', folder, tmp_path / 'bag2')
    assert r.returncode == 2 and "decel_g 'fast' is invalid" in r.stderr and r.stderr.count('\n') == 1
    (folder / 'campaign.yaml').write_text(yaml.safe_dump({'pulls': [{'set': 1}]}))
    r = run_cli('import', folder, tmp_path / 'bag3')
    assert r.returncode == 2 and "lacks 'file'" in r.stderr and r.stderr.count('\n') == 1


# --------------------------------------------------------------------------- --init-map (issue 40)
@pytest.mark.slow
def test_init_map_writes_a_skeleton_that_imports_once_filled_in(tmp_path):
    """./ft bag import FILE --init-map MAP.yaml on a LabVIEW file in volts: the map names the file's channels with
    their units, the rate and the duration, guesses which is which, and leaves the sensitivities FILL_IN: refused
    in one line until they are filled in; then the file imports to the right SI values."""
    si, volts = impact_record(25_000.0, 5000, 4)
    f = write_lvm(tmp_path / 'drop.lvm', {'Accel': volts['Accel'], 'Load cell': volts['Load cell'],
                                          'Trigger': np.zeros(5000)}, 25_000.0)
    m = tmp_path / 'map.yaml'
    r = run_cli('import', f, '--init-map', m)
    assert r.returncode == 0, r.stderr
    assert 'fill in its 2 FILL_IN(s)' in r.stdout and not (tmp_path / 'bag').exists()
    text = m.read_text()
    assert '5000 samples at 25000 Hz, 0.2 s' in text
    assert '"Load cell" [Volts]' in text and '"Accel" [Volts]' in text and '"Trigger" [Volts]' in text
    doc = yaml.safe_load(text)
    assert doc['channels']['force_moving_n']['source'] == 'Load cell'        # by its name
    assert doc['channels']['accel_axial_m_s2']['source'] == 'Accel'
    assert doc['absent'] == ['encoder_position_m', 'force_stationary_n']
    r = run_cli('import', f, '--channels', m, '--dry-run')
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and "sensitivity 'FILL_IN mV/N'" in r.stderr, r.stderr
    filled = (text.replace('FILL_IN mV/N', f'{FORCE_MV_PER_N} mV/N').replace('FILL_IN mV/g', f'{ACCEL_MV_PER_G} mV/g')
              .replace('sign: tension', 'sign: compression'))
    m.write_text(filled)
    r = run_cli('import', f, tmp_path / 'bag', '--channels', m)
    assert r.returncode == 0, r.stderr
    back = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'back')).pulls[0].channels
    for ch, v in si.items():
        np.testing.assert_allclose(back[ch], v, rtol=1e-8, atol=1e-8 * np.abs(v).max())
    r = run_cli('import', f, '--init-map', m)                        # never overwritten
    assert r.returncode == 2 and 'exists already' in r.stderr and m.read_text() == filled
    r = run_cli('import', f, tmp_path / 'bag2', '--init-map', tmp_path / 'm2.yaml')
    assert r.returncode == 2 and r.stderr.count('\n') == 1 and 'writes the channel map only' in r.stderr


def test_init_map_of_a_csv_without_rate_or_units(tmp_path):
    """A CSV with no time column and no units: the map asks for the rate and the units (FILL_IN); the channels
    are guessed from their order."""
    (tmp_path / 'a.csv').write_text('ch0,ch1\n' + '\n'.join(f'{0.001 * k},{-0.002 * k}' for k in range(50)) + '\n')
    from bag_tools.core.channel_map import skeleton_map
    text = skeleton_map(tmp_path / 'a.csv')
    doc = yaml.safe_load(text)
    assert doc['sample_rate_hz'] == 'FILL_IN' and 'no sample rate in the file' in text
    chans = doc['channels']
    assert chans['force_moving_n']['source'] == 'ch0' and chans['accel_axial_m_s2']['source'] == 'ch1'
    assert doc['channels']['force_moving_n']['unit'] == 'FILL_IN' and 'guessed from the order' in text
    with pytest.raises(BagError, match="unit 'FILL_IN' is not a unit I can convert"):
        load_channel_map(doc)
