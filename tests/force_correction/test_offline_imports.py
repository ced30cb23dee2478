"""`./ft bag correct` on a bag starts without what it does not use: rosbags' rosbag2 reader and writer (sqlite3,
apsw, lz4), sockets, uuid. A new process imports the command's modules and lists what got loaded."""
import json
import subprocess
import sys

NOT_LOADED = ('rosbags.rosbag2', 'sqlite3', 'apsw', 'socket', 'uuid', 'rclpy', 'scipy', 'matplotlib', 'dask')


def test_bag_correct_imports_nothing_it_does_not_use():
    code = ('import json, sys\n'
            'import ft_cli.main, ft_cli.commands.bag, force_correction.offline.cli, force_correction.offline.pipeline\n'
            'import force_correction.offline.bag\n'
            f'print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in {[m.split(".")[0] for m in NOT_LOADED]!r}'
            '                        or m in sys.modules and m.startswith("rosbags.rosbag2"))))')
    out = subprocess.run([sys.executable, '-c', code], check=True, capture_output=True, text=True).stdout
    loaded = json.loads(out)
    bad = [m for m in loaded if any(m == n or m.startswith(n + '.') for n in NOT_LOADED)]
    assert not bad, f'loaded by the bag correct command at start-up: {bad}'
