"""`./ft bag correct` on a bag starts without what it does not use: rosbags' rosbag2 reader and writer (sqlite3,
apsw, lz4), sockets, uuid. A new process imports the command's modules and lists what got loaded."""
import json
import subprocess
import sys

NOT_LOADED = ('rosbags.rosbag2', 'sqlite3', 'apsw', 'socket', 'uuid', 'rclpy', 'scipy', 'matplotlib', 'dask')

CODE = """import json, sys
import ft_cli.main, ft_cli.commands.bag, force_correction.offline.cli, force_correction.offline.pipeline
import force_correction.offline.bag
print(json.dumps(sorted(sys.modules)))
"""


def test_bag_correct_imports_nothing_it_does_not_use():
    loaded = json.loads(subprocess.run([sys.executable, '-c', CODE], check=True, capture_output=True,
                                       text=True).stdout)
    bad = [m for m in loaded if any(m == n or m.startswith(n + '.') for n in NOT_LOADED)]
    assert not bad, f'loaded by the bag correct command at start-up: {bad}'
