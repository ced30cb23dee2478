"""The nodes as the real ROS 2 tools run them (issue 30): each a process over Fast DDS.

A node that cannot start says why in one line and exits non-zero; Ctrl-C of a sim (SIGINT to the
terminal's whole process group, its worker process included) is quiet; a late joiner asking for
one score gets the newest.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from ft_cli.paths import executable  # noqa: E402

# every node process; the player needs a bag to get as far as starting ROS
NODES = [('force_tester_sim', 'sim_node'), ('force_correction', 'correction_node'),
         ('force_correction', 'validator_node'), ('force_correction', 'correction_graph'),
         ('bag_tools', 'recorder_node'), ('force_tester_monitor', 'monitor_node'), ('bag_tools', 'player')]


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory):
    from daq_data import T0, make_pulls

    from bag_tools.core.convert import campaign_to_bag
    from bag_tools.core.daq import write_campaign
    tmp = tmp_path_factory.mktemp('bag')
    return campaign_to_bag(write_campaign(tmp / 'camp', make_pulls(1, start=T0)), tmp / 'bag')


def one_error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, stderr
    return lines[0]


@pytest.mark.parametrize('package, name', NODES, ids=[n for _p, n in NODES])
def test_a_node_that_cannot_start_says_why_in_one_line(ros_domain, tmp_path, small_bag, package, name):
    """A parameter file that does not exist (rclpy.init refuses the --ros-args): before, a
    26-line RCLError traceback and rcl's own log line; now one line and exit code 1."""
    args = [str(small_bag)] if name == 'player' else []
    res = subprocess.run([str(executable(package, name)), *args, '--ros-args', '--params-file',
                          str(tmp_path / 'missing.yaml')], capture_output=True, text=True, timeout=120,
                         stdin=subprocess.DEVNULL, cwd=tmp_path)
    line = one_error_line(res.stderr)
    assert res.returncode == 1, (res.returncode, res.stderr)
    assert line.startswith(f'{name}: error: RCLError: failed to initialize rcl: ') and 'missing.yaml' in line, line


def test_a_recorder_whose_bag_directory_does_not_exist_says_so_in_one_line(ros_domain, tmp_path):
    """Before: a 27-line BagError traceback, exit 1."""
    bag = tmp_path / 'no' / 'such' / 'bag'
    res = subprocess.run([str(executable('bag_tools', 'recorder_node')), '--ros-args', '-p', f'bag_path:={bag}'],
                         capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    line = one_error_line(res.stderr)
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert line.startswith('recorder_node: error: ') and str(bag) in line and str(bag.parent) in line, line


def test_any_error_while_starting_is_one_line_and_a_non_zero_exit(ros_domain, capfd):
    """spin_nodes, for an error of any type a node raises while it is made (the seam every node's
    main() goes through): one line quoting it, exit 1 (2 for bad input: a ValueError, the type
    each package's own error derives from); the nodes made before are destroyed."""
    from force_tester_common.ros import spin_nodes

    class Boom(RuntimeError):
        pass

    made = []

    def fine():
        made.append(rclpy.create_node('fine_node'))
        return made[-1]

    def fails(exc):
        def factory():
            raise exc
        return factory
    for exc, code, text in ((Boom('the hardware is not there'), 1, 'Boom: the hardware is not there'),
                            (ValueError('port 8765 is in use;\n expected a free port'), 2,
                             'port 8765 is in use; expected a free port')):
        capfd.readouterr()
        got = spin_nodes(fine, fails(exc), args=['prog'])
        err = capfd.readouterr().err
        assert got == code, err
        assert err.endswith(f': error: {text}\n') and len(err.splitlines()) == 1, err
        assert not rclpy.ok()
    assert len(made) == 2
    for node in made:   # destroyed: no half-started node left behind
        with pytest.raises(Exception, match='(?i)invalid|destr'):
            node.get_name()


def worker_processes(pid: int) -> list:
    """The sim's spawned worker processes (its publishing thread starts them)."""
    out = []
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            children = open(f'/proc/{pid}/task/{tid}/children').read().split()
        except OSError:
            continue
        for child in children:
            try:
                if b'spawn_main' in open(f'/proc/{child}/cmdline', 'rb').read():
                    out.append(int(child))
            except OSError:
                pass
    return out


def process_state(pid: int) -> str:
    try:
        return open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()[0]
    except OSError:
        return ''


@pytest.mark.parametrize('when', ['worker_starting', 'publishing'])
def test_ctrl_c_of_a_publishing_sim_is_quiet_and_exits_0(ros_domain, when):
    """SIGINT to the whole process group, as a terminal's Ctrl-C sends it, while the sim's worker
    process is still starting (importing its modules), or while the sim publishes and the worker
    simulates the next pull: no traceback (before: the worker's `SpawnProcess-1 ...
    KeyboardInterrupt`, or `Traceback ... KeyboardInterrupt` from its imports), exit code 0, and
    the worker goes with its sim."""
    from force_tester_msgs.msg import PullEvent
    from rclpy.executors import SingleThreadedExecutor

    from force_tester_common.ros import EVENT_QOS
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('event_listener', context=ctx)
    events = []
    node.create_subscription(PullEvent, '/pull_event', events.append, EVENT_QOS)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    proc = subprocess.Popen([str(executable('force_tester_sim', 'sim_node')), '--ros-args',
                             '-p', 'test_sets:=[1, 2, 3]', '-p', 'pulls_per_set:=3', '-p', 'wait_for_subscribers:=0'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL,
                            start_new_session=True,   # its own process group, as a terminal's job is
                            # and SIGINT not ignored, as in a terminal (a shell's background job, as
                            # this test may be, ignores it, and so would the node and its worker)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 120
        # 'publishing': a pull event came, so the worker simulated that pull; and it simulated the next
        # one too and waits for work (a worker busy in numpy when its sim exits is ended by its
        # watchdog before it could say anything)
        while not (worker_processes(proc.pid) and (when == 'worker_starting' or events and all(
                process_state(w) == 'S' for w in worker_processes(proc.pid)))):
            assert proc.poll() is None and time.monotonic() < deadline, (len(events), proc.poll())
            time.sleep(0.01)
        workers = worker_processes(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        spinner.join(timeout=5)
    assert 'Traceback' not in err and 'KeyboardInterrupt' not in err, err
    assert 'simulation stopped' not in err, err   # nor a worker killed under its sim (BrokenProcessPool)
    assert proc.returncode == 0, (proc.returncode, err)
    deadline = time.monotonic() + 10
    while any(os.path.exists(f'/proc/{w}') and 'zombie' not in open(f'/proc/{w}/status').read()
              for w in workers):
        assert time.monotonic() < deadline, 'the worker outlived its sim'
        time.sleep(0.1)


LATE_JOINER = r'''
import sys, time
import rclpy
from force_tester_msgs.msg import PullScore
from force_tester_common.core.channels import PULL_SCORE_LATEST_TOPIC, PULL_SCORE_TOPIC
from force_tester_common.ros import LATEST_SCORE_QOS, SCORE_QOS
rclpy.init()
node = rclpy.create_node('late_joiner')
latest, history = [], []
node.create_subscription(PullScore, PULL_SCORE_LATEST_TOPIC, lambda m: latest.append(m.pull_id), LATEST_SCORE_QOS)
node.create_subscription(PullScore, PULL_SCORE_TOPIC, lambda m: history.append(m.pull_id), SCORE_QOS)
deadline = time.monotonic() + 60
while (not latest or len(history) < int(sys.argv[1])) and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print('latest', *latest)
print('history', *history)
'''


def test_a_late_joiner_asking_for_one_score_gets_the_newest(ros_domain, tmp_path):
    """A validator restarted with 5 scores in its state file republishes them; a subscriber in
    another process that joins afterwards gets the newest on /pull_score_latest (depth 1,
    transient local: what `ros2 topic echo /pull_score_latest --once` prints) and the whole
    history on /pull_score. The state file is relative: it is read under $ROS_HOME."""
    from force_correction.core.score_log import LoggedScore, ScoreLog
    from force_correction.core.scoring import PullScoreResult
    result = PullScoreResult(*[1.0] * 10, n_samples=10, n_loaded=5, loaded_fraction=0.1)
    home = tmp_path / 'ros_home'
    log = ScoreLog(home / 'rig' / 'scores.jsonl')
    for pull in range(5):
        log.append(LoggedScore(pull, 1, 10**18 + pull, 0, '', result))
    env = dict(os.environ, ROS_HOME=str(home))
    validator = subprocess.Popen([str(executable('force_correction', 'validator_node')), '--ros-args',
                                  '-p', 'state_file:=rig/scores.jsonl'], env=env, cwd=tmp_path,
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                 stdin=subprocess.DEVNULL)
    try:
        said = ''
        while 'earlier score(s) restored' not in said:   # the scores are published
            line = validator.stdout.readline()
            assert line, said
            said += line
        assert f'5 earlier score(s) restored from {home}/rig/scores.jsonl' in said, said
        res = subprocess.run([sys.executable, '-c', LATE_JOINER, '5'], capture_output=True, text=True,
                             timeout=120, cwd=tmp_path)
    finally:
        validator.send_signal(signal.SIGINT)
        validator.communicate(timeout=30)
    assert res.returncode == 0, res.stderr
    got = dict((ln.split()[0], [int(x) for x in ln.split()[1:]]) for ln in res.stdout.splitlines())
    assert got['latest'] == [4], got
    assert got['history'] == [0, 1, 2, 3, 4], got
    assert validator.returncode == 0
