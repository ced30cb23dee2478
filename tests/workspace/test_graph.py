"""Acceptance: the live graph as separate processes over Fast DDS, and the bag it records.

The main job (./ft demo) runs sim, correction, validator and recorder as four processes; the
scores come back over DDS. The recorded bag is then played back by the player process into a
fresh correction + validator pair, which must reproduce the live scores.
"""
import subprocess

import pytest

from force_tester_common.core.blocks import BLOCK_SAMPLES
from ft_cli.commands import demo
from ft_cli.graph import SCORE_KEYS, Graph, ScoreCollector
from ft_cli.paths import executable
from ft_cli.peak_inputs import validator_params

pytestmark = pytest.mark.slow


# the demo's extension column, wired with a hand-written extension (what discover finds is tested in
# force_discovery; here: the second correction + validator pair runs live and equals offline correct with it)
EXTENSION = {'correction': {'mass_kg': 1.3, 'moving_cell_gain': 1.015, 'accel_delay_s': 4e-5}}


@pytest.fixture(scope='module')
def live(tmp_path_factory, module_ros_domain):
    import yaml
    out = tmp_path_factory.mktemp('demo')
    (out / 'extension.yaml').write_text(yaml.safe_dump(EXTENSION))
    # the truth reference rig: it departs from the datasheet like the thesis's real rig did
    scores = demo.run_live(out, sets=[1, 2, 3, 4, 5], pulls=1, seed=3, rate=1.0, timeout=180, rig='truth',
                           extension=out / 'extension.yaml')
    return out, scores


def test_live_graph_scores_every_pull_without_drops(live):
    _, scores = live
    assert [s['test_set'] for s in scores] == [1, 2, 3, 4, 5]
    assert all(s['dropped_blocks'] == 0 for s in scores)
    assert all(s['stationary_peak_n'] > 0 for s in scores)


def pull_from_bag(bag_path, pull_id):
    """The /force and /accel samples of one pull, read back from the recorded bag."""
    import numpy as np

    from bag_tools.core.reader import open_bag
    chunks = {'/force': {}, '/accel': {}}
    with open_bag(bag_path) as bag:
        for m in bag.messages(['/pull_event', '/force', '/accel']):
            msg = bag.deserialize(m.cdr, m.type_name)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            if m.topic == '/pull_event' and msg.pull_id == pull_id:
                if msg.event == 0:
                    start = stamp
                else:
                    end = stamp
            elif m.topic != '/pull_event':
                chunks[m.topic][stamp] = msg
    stamps = sorted(t for t in chunks['/force'] if start <= t < end)
    assert stamps == sorted(t for t in chunks['/accel'] if start <= t < end)
    force = [chunks['/force'][t] for t in stamps]
    return (np.concatenate([f.stationary_n for f in force]), np.concatenate([f.moving_n for f in force]),
            np.concatenate([chunks['/accel'][t].axial_m_s2 for t in stamps]))


def test_set3_live_scores_equal_the_core_on_the_recorded_samples(live):
    """Set 3 through three processes over DDS scores exactly as the ROS-free core does offline."""
    from force_correction.core.params import CorrectionParams
    from force_correction.core.scoring import score_pull
    from force_correction.core.streaming import correct_signal
    out, scores = live
    (s3,) = [s for s in scores if s['test_set'] == 3]
    stationary, moving, accel = pull_from_bag(out / 'bag', s3['pull_id'])
    assert len(stationary) == 100_000
    c = correct_signal(moving, accel, CorrectionParams())
    ref = score_pull(stationary, c.raw_n, c.corrected_n, c.filtered_n)
    for k in ('stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
              'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'raw_rms_n', 'corrected_rms_n'):
        assert s3[k] == pytest.approx(getattr(ref, k), rel=1e-9, abs=1e-9), k
    # what the correction did is visible in the score: m2*a2 was subtracted during the pull
    assert s3['corrected_rms_n'] != pytest.approx(s3['raw_rms_n'], rel=1e-3)


def test_set3_validator_puts_the_corrected_force_closer_to_the_stationary_cell(live):
    (s3,) = [s for s in live[1] if s['test_set'] == 3]
    assert s3['raw_diff_pct'] > 20.0, s3           # the moving cell reads high at 15 fps
    assert s3['corrected_diff_pct'] < s3['raw_diff_pct'], s3
    assert s3['filtered_diff_pct'] < s3['raw_diff_pct'], s3
    assert s3['corrected_rms_n'] < s3['raw_rms_n'], s3


def test_recorded_bag_is_complete(live):
    from bag_tools.core.info import bag_info
    out, _ = live
    info = bag_info(out / 'bag')
    for topic in ('/force', '/accel', '/motor', '/encoder', '/force_corrected'):
        t = info['topics'][topic]
        assert t['seq_gaps'] == 0, (topic, t)
        assert t['count'] == 5 * 100_000 // BLOCK_SAMPLES, (topic, t)   # 5 pulls x 100,000 samples
        assert t['sample_rate_hz'] == 50000.0
    assert info['pulls']['count'] == 5


@pytest.mark.parametrize('layout', ['two_processes', 'composed_in_one_process'])
def test_bag_playback_reproduces_live_scores(live, tmp_path, layout):
    out, live_scores = live
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    try:
        # the peak's uncertainty from the same rig YAML as the demo's validator
        if layout == 'two_processes':
            graph.start('force_correction', 'correction_node')
            graph.start('force_correction', 'validator_node', validator_params())
        else:  # both nodes in one executor
            graph.start('force_correction', 'correction_graph', validator_params())
        assert collector.wait_for_graph({'/force_corrected': 1, '/force': 2, '/pull_event': 1}, timeout=30)
        assert collector.spin_until(lambda: collector.node.count_publishers('/pull_score') >= 1, timeout=30)
        graph.start('bag_tools', 'player', extra=[
            str(out / 'bag'), '--topics', '/force', '/accel', '/pull_event', '--wait-for-subscribers', '1'])
        ok = collector.wait(len(live_scores), 120, alive=lambda: not graph.dead())
    finally:
        graph.stop()
        collector.close()
    assert ok, graph.tail('player')
    played = sorted(collector.scores, key=lambda s: s['pull_id'])
    for a, b in zip(live_scores, played):
        for k in SCORE_KEYS:
            assert b[k] == pytest.approx(a[k], rel=1e-9, abs=1e-9), (k, a, b)


def test_offline_correct_reproduces_the_live_recording(live, tmp_path):
    """`./ft bag correct` on the live bag (correction + validator output recorded) gives the live
    corrected blocks and scores: offline and live share one core."""
    import numpy as np

    from bag_tools.core.reader import open_bag
    from force_correction.offline import correct
    demo = live[0] / 'bag'
    with open_bag(demo) as b:
        live_scores = [b.deserialize(m.cdr, m.type_name) for m in b.messages('/pull_score')]
        live_blocks = {}
        for m in b.messages('/force_corrected'):
            msg = b.deserialize(m.cdr, m.type_name)
            live_blocks[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg.filtered_n
    res = correct(demo, tmp_path / 'out').as_dict()
    by_id = {p['pull_id']: p for p in res['pulls']}
    for s in live_scores:
        for k in ('raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'filtered_rms_n'):
            assert abs(by_id[s.pull_id][k] - getattr(s, k)) <= 1e-9
    with open_bag(tmp_path / 'out') as b:
        for m in b.messages('/force_corrected'):
            msg = b.deserialize(m.cdr, m.type_name)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert stamp in live_blocks
            np.testing.assert_allclose(msg.filtered_n, live_blocks[stamp], rtol=0, atol=1e-9)


@pytest.mark.parametrize('make_bad', ['missing', 'empty_dir', 'truncated'])
def test_player_rejects_a_bad_bag_with_one_line(live, tmp_path, make_bad):
    import shutil
    bad = tmp_path / 'bad'
    if make_bad == 'empty_dir':
        bad.mkdir()
    elif make_bad == 'truncated':
        shutil.copytree(live[0] / 'bag', bad)
        (mcap,) = bad.glob('*.mcap')
        data = mcap.read_bytes()
        mcap.write_bytes(data[: len(data) // 2])
    exe = executable('bag_tools', 'player')
    res = subprocess.run([str(exe), str(bad)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and 'error' in lines[0] and str(bad) in lines[0], res.stderr


def test_the_extension_pair_scores_every_pull_as_offline_correct_with_the_extension(live, tmp_path):
    """The demo's extension column: a second correction (extension_file) and validator, remapped under
    /extension, score every pull live exactly as `./ft bag correct --extension` does on the recorded bag,
    and the table shows it."""
    from force_correction.offline import CorrectionSetup, correct
    out, scores = live
    assert all(s['extension'] and s['extension']['pull_id'] == s['pull_id'] for s in scores), scores
    res = correct(out / 'bag', tmp_path / 'ext', CorrectionSetup.build(extension_file=out / 'extension.yaml'))
    by_id = {p['pull_id']: p for p in res.as_dict()['pulls']}
    for s in scores:
        for k in ('raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct'):
            assert abs(by_id[s['pull_id']][k] - s['extension'][k]) <= 1e-9, (k, s)
    # the two pairs corrected differently, and the table has the column
    assert any(abs(s['extension']['corrected_diff_pct'] - s['corrected_diff_pct']) > 0.1 for s in scores)
    table = demo.format_table(scores)
    assert 'ext + m*a' in table and 'diff ext' in table
