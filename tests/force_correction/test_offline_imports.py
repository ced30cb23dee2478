"""`./ft bag correct` on a bag starts without what it does not use: rosbags (its rosbag2 reader and writer load
sqlite3, apsw, lz4), sockets, uuid; and corrects a bag into a bag without the DAQ and conversion modules, numpy.ma or
tempfile. A new process imports the command's modules (or runs the command) and lists what got loaded."""
import json
import os
import subprocess
import sys

from daq_data import T0, make_pulls

from bag_tools.core.convert import campaign_to_bag
from bag_tools.core.daq import write_campaign
from force_tester_common.core.cache import CACHE_ENV

NOT_LOADED = ('rosbags.rosbag2', 'sqlite3', 'apsw', 'socket', 'uuid', 'rclpy', 'scipy', 'matplotlib', 'dask')
#: what correcting a bag into a bag does not need: the DAQ campaign's modules (bag_tools.core.sources tells a bag
#: from a campaign), the other commands' arguments, a staging folder's tempfile, and numpy.ma (np.median's NaN
#: check and np.unique load it: events.median and the bag writer do without)
NOT_RUN = ('bag_tools.core.daq', 'bag_tools.core.convert', 'bag_tools.core.channel_map', 'bag_tools.core.daqfiles',
           'bag_tools.core.playback', 'force_correction.offline.campaign', 'tempfile', 'numpy.ma')

CODE = """import json, sys
import ft_cli.main, ft_cli.commands.bag, force_correction.offline.cli, force_correction.offline.pipeline
import force_correction.offline.bag
print(json.dumps(sorted(sys.modules)))
"""

RUN = """import contextlib, io, json, sys
import ft_cli.main
with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.redirect_stderr(io.StringIO()):
    code = ft_cli.main.main(['bag', 'correct', sys.argv[1], sys.argv[2]])
print(json.dumps([code, out.getvalue(), sorted(sys.modules)]))
"""


def loaded_of(modules, names):
    return [m for m in modules if any(m == n or m.startswith(n + '.') for n in names)]


def test_bag_correct_imports_nothing_it_does_not_use():
    loaded = json.loads(subprocess.run([sys.executable, '-c', CODE], check=True, capture_output=True,
                                       text=True).stdout)
    bad = loaded_of(loaded, (*NOT_LOADED, 'rosbags'))   # rosbags: only when the cache lacks the message facts
    assert not bad, f'loaded by the bag correct command at start-up: {bad}'


def test_correcting_a_bag_loads_no_campaign_module(tmp_path):
    bag = campaign_to_bag(write_campaign(tmp_path / 'camp', make_pulls(3, start=T0)), tmp_path / 'bag')
    code, out, loaded = json.loads(subprocess.run([sys.executable, '-c', RUN, str(bag), str(tmp_path / 'out')],
                                                  check=True, capture_output=True, text=True).stdout)
    assert code == 0 and 'written to' in out and (tmp_path / 'out' / 'metadata.yaml').is_file(), out
    bad = loaded_of(loaded, NOT_LOADED + NOT_RUN)
    assert not bad, f'loaded by ./ft bag correct BAG OUT: {bad}'


def test_a_second_run_takes_normals_and_message_facts_from_the_cache_not_numpy_random_or_rosbags(tmp_path):
    """The Monte Carlo's normals (numpy.random) and the message types' definitions, hashes and layouts (rosbags's
    typestore) are computed by the first run and kept in the per-user cache; the second run imports neither."""
    bag = campaign_to_bag(write_campaign(tmp_path / 'camp', make_pulls(3, start=T0)), tmp_path / 'bag')
    env = {**os.environ, CACHE_ENV: str(tmp_path / 'cache')}
    runs = []
    for k in range(2):
        (tmp_path / f'run{k}').mkdir()
        code, out, loaded = json.loads(subprocess.run(
            [sys.executable, '-c', RUN, str(bag), str(tmp_path / f'run{k}' / 'out')], check=True, capture_output=True,
            text=True, env=env).stdout)
        assert code == 0, out
        runs.append(loaded_of(loaded, ('numpy.random', 'rosbags')))
        assert (tmp_path / f'run{k}' / 'out' / 'metadata.yaml').is_file()
    assert {'numpy.random', 'rosbags.typesys'} <= set(runs[0]) and not runs[1], runs   # made once, then read
    assert list((tmp_path / 'cache').glob('mc_normals-*.npy')) and list((tmp_path / 'cache').glob('msgfacts-*.json'))
    first, second = ((tmp_path / f'run{k}' / 'out' / 'out.mcap').read_bytes() for k in range(2))
    assert first == second   # the same numbers either way
