"""Several rigs on one machine (docs/nodes.md): each rig's sim, correction and validator under its own
namespace, as separate processes or with every rig's correction and validator composed in one
process, through `./ft bench rigs` (real processes over Fast DDS)."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from ft_cli.paths import ROOT


@pytest.mark.slow
def test_two_rigs_each_score_their_own_pulls(tmp_path, ros_domain):
    out = tmp_path / 'rigs.json'
    res = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / 'bench_rigs.py'), '--rigs', '2',
                          '--seconds', '4', '--block', '250', '--layout', 'process,composed',
                          '--domain', str(ros_domain), '--json', str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    runs = json.loads(out.read_text())['runs']
    assert [r['compose'] for r in runs] == [False, True]
    for r in runs:
        assert (r['rigs'], r['dropped'], r['unscored']) == (2, 0, 0)
        for rig in r['per_rig']:
            # one pull of each set (2 s each) at 50 kHz in 250-sample blocks; a rig that heard the
            # other's topics would pair and score twice as much
            assert rig['scored'] == rig['scored_ok'] == rig['pulls'] == 5
            assert rig['sent'] == rig['corrected'] == 5 * 2 * 50_000 // 250
        assert r['p99_added_ms'] is not None and r['correction_cpu_per_rig'] > 0


def test_the_rig_parameter_files_set_only_declared_parameters():
    """config/rigs/*.yaml (docs/nodes.md, "Several rigs on one machine"): every node they name is one of a
    rig's nodes under the file's namespace, and every parameter is one that node declares."""
    import yaml

    from force_correction import correction_node, validator_node
    from force_tester_sim import sim_node
    declared = {name: {spec.name for spec in module.SPECS}
                for name, module in (('sim', sim_node), ('correction', correction_node),
                                     ('validator', validator_node))}
    files = sorted((ROOT / 'config' / 'rigs').glob('*.yaml'))
    assert len(files) >= 2
    for f in files:
        for node, section in yaml.safe_load(f.read_text()).items():
            namespace, name = node.rsplit('/', 1)
            assert namespace == f'/{f.stem}' and name in declared, (f.name, node)
            assert set(section['ros__parameters']) <= declared[name], (f.name, node)


@pytest.mark.slow
def test_null_rigs_of_the_floor_benchmark_deliver_every_block(tmp_path, ros_domain):
    """./ft bench floor: two null rigs (null sim, relay, null validator under /rig1 and /rig2) deliver
    every block from the first each validator received, and the CPU is measured."""
    out = tmp_path / 'floor.json'
    res = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / 'bench_floor.py'), '--rigs', '2',
                          '--seconds', '2', '--json', str(out)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    (run,) = json.loads(out.read_text())
    assert run['rigs'] == 2 and run['lost'] == 0
    assert run['received'] >= 2 * 150   # 2 s at 100 blocks/s per rig, from the first block received
    assert run['cpu_total'] > 0 and run['us_per_op'] > 0


# ----------------------------------------------------------------------------- the rig recipe
def readme_rig_recipe() -> list:
    """The commands of the "Several rigs on one machine" recipe in docs/nodes.md, as written there."""
    text = (ROOT / 'docs' / 'nodes.md').read_text()
    section = text[text.index('**Several rigs on one machine.**'):]
    block = section[section.index('```') + 3:]
    block = block[:block.index('```')]
    return [line.split() for line in block.splitlines() if line.startswith('./ft run ')]


def test_the_readme_rig_recipe_scores_its_pulls(tmp_path, ros_domain):
    """The recipe of docs/nodes.md, as written (correction, validator, then the sim, each a process with
    -r __ns:=/rig1 --params-file config/rigs/rig1.yaml, from the workspace root): the sim does not
    wait for a reader the recipe never starts, publishes, and the validator scores pull 0 into
    its state file under $ROS_HOME. Before, rig1.yaml made the sim wait for 2 readers of
    /rig1/pull_event, which only the validator reads: it waited for good."""
    import os
    import signal
    import time

    from ft_cli.paths import executable
    recipe = readme_rig_recipe()
    assert [cmd[2:4] for cmd in recipe] == [['force_correction', 'correction_node'],
                                             ['force_correction', 'validator_node'],
                                             ['force_tester_sim', 'sim_node']], recipe
    env = dict(os.environ, ROS_HOME=str(tmp_path / 'ros_home'))
    procs, logs = [], []
    try:
        for cmd in recipe:
            log = tmp_path / f'{cmd[3]}.log'
            logs.append(log)
            # `./ft run PKG EXE ARGS` runs install/PKG/lib/PKG/EXE ARGS (as `ros2 run` does), here from the root
            procs.append(subprocess.Popen([str(executable(cmd[2], cmd[3])), *cmd[4:]], cwd=ROOT, env=env,
                                          stdout=log.open('w'), stderr=subprocess.STDOUT,
                                          stdin=subprocess.DEVNULL))
        state = tmp_path / 'ros_home' / 'force_tester' / 'rig1_scores.jsonl'
        deadline = time.monotonic() + 240
        while not (state.exists() and state.read_text().count('\n') >= 1):
            assert all(p.poll() is None for p in procs), [log.read_text()[-2000:] for log in logs]
            assert time.monotonic() < deadline, [log.read_text()[-2000:] for log in logs]
            time.sleep(0.2)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        codes = []
        for p in procs:
            try:
                codes.append(p.wait(30))
            except subprocess.TimeoutExpired:
                p.kill()
                codes.append(p.wait())
    sim_log = logs[2].read_text()
    assert 'matched subscribers: /rig1/pull_event 1, /rig1/force 2' in sim_log, sim_log[-2000:]
    assert 'publishing 10 pull(s)' in sim_log, sim_log[-2000:]
    first = json.loads(state.read_text().splitlines()[0])
    assert (first['pull_id'], first['set_id'], first['status']) == (0, 1, 0), first   # PULL_OK
    assert codes == [0, 0, 0], (codes, [log.read_text()[-2000:] for log in logs])


def test_a_sim_whose_readers_never_come_gives_up_with_one_line(ros_domain):
    """wait_timeout_s: one line naming the resolved topics, the readers they have (and whose),
    the readers wanted and what to start; exit code 2. A reader of /rig1/force only is here."""
    import rclpy
    from force_tester_msgs.msg import ForceBlock

    from force_tester_common.ros import BLOCK_QOS
    from ft_cli.paths import executable
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('listener', namespace='/rig1', context=ctx)
    try:
        node.create_subscription(ForceBlock, '/rig1/force', lambda m: None, BLOCK_QOS)
        res = subprocess.run([str(executable('force_tester_sim', 'sim_node')), '--ros-args', '-r', '__ns:=/rig1',
                              '-p', 'wait_for_subscribers:=1', '-p', 'wait_timeout_s:=3.0'],
                             capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert res.returncode == 2, (res.returncode, res.stderr)
    errors = [ln for ln in res.stderr.splitlines() if 'error' in ln.lower()]
    assert len(errors) == 1 and errors[0].startswith('sim_node: error: no readers after 3 s'), res.stderr
    line = errors[0]
    for text in ('/rig1/pull_event has 0 (no reader)', '/rig1/force has 1 (/rig1/listener)',
                 'waiting for 1 on each (wait_for_subscribers 1)', 'with -r __ns:=/rig1',
                 '/rig1/pull_event: a validator_node or a recorder_node'):
        assert text in line, line
    assert '/rig1/force:' not in line   # it has its reader


def test_the_rig_files_are_installed_where_ros_finds_them():
    """colcon installs each package's config files into share/<pkg>/config, where
    get_package_share_directory (ros2 pkg prefix, launch files) finds them: the rig files too.
    Before, the rig files were not installed, and two packages' config folders were empty (their
    setup.py globs matched nothing)."""
    from ament_index_python.packages import get_package_share_directory

    from ft_cli.paths import INSTALL
    installed_any = False
    for pkg in sorted(p.name for p in (ROOT / 'src').iterdir() if (p / 'setup.py').is_file()):
        config = INSTALL / pkg / 'share' / pkg / 'config'
        sources = sorted(str(f.relative_to(ROOT / 'src' / pkg / 'config')) for f in
                         (ROOT / 'src' / pkg / 'config').rglob('*.yaml'))
        sources += sorted(f'{f.name}' for f in (ROOT / 'src' / pkg / pkg / 'config').glob('*.yaml'))
        if sources or config.exists():   # no empty config folder, nothing left out
            have = sorted(str(f.relative_to(config)) for f in config.rglob('*.yaml')) if config.exists() else []
            assert have and have == sorted(sources), (pkg, have, sources)
            installed_any = True
    assert installed_any
    share = Path(get_package_share_directory('force_tester_common'))
    for f in (ROOT / 'config' / 'rigs').glob('*.yaml'):
        assert (share / 'config' / 'rigs' / f.name).read_text() == f.read_text(), f.name
    assert sorted(f.name for f in (share / 'config' / 'rigs').glob('*.yaml')) == ['rig1.yaml', 'rig2.yaml']


@pytest.mark.slow
def test_the_recorder_and_the_monitor_follow_their_namespace_and_remaps(tmp_path, ros_domain):
    """A rig under /rig2 (issue 41, item 2): a recorder started with -r __ns:=/rig2 and its default topics records
    /rig2/force, /rig2/pull_event, ... (before: it looked for /force, ... and closed the bag with 0 messages);
    a recorder in the root namespace told `-r force:=/rig2/force` records /rig2/force (before: the
    un-remapped /force); a monitor under /rig2 watches the rig's topics and publishes /rig2/monitor/*, none in
    the root namespace."""
    from diagnostic_msgs.msg import DiagnosticArray
    from force_tester_msgs.msg import MonitorHealth

    from bag_tools.core.info import bag_info
    from force_tester_common.ros import EVENT_QOS
    from ft_cli.graph import Graph, ScoreCollector
    ns = ['--ros-args', '-r', '__ns:=/rig2']
    graph = Graph(tmp_path / 'logs')
    collector = ScoreCollector()
    recorded, health = {}, []
    collector.node.create_subscription(
        DiagnosticArray, '/diagnostics', lambda m: recorded.update(
            {s.name.split(':')[0]: {kv.key: kv.value for kv in s.values} for s in m.status
             if s.hardware_id == 'rig2' or s.name.startswith('recorder_remap:')}), EVENT_QOS)
    collector.node.create_subscription(MonitorHealth, '/rig2/monitor/health', health.append, EVENT_QOS)

    def received(topic):
        return max((t.received for h in health[-1:] for t in h.topics if t.topic == topic), default=0)

    def done():
        return (int(recorded.get('recorder', {}).get('/rig2/pull_event', 0)) >= 2
                and int(recorded.get('recorder_remap', {}).get('/rig2/force', 0)) > 0
                and received('/pull_event') >= 2)
    try:
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(tmp_path / 'ns_bag')}, extra=ns)
        graph.start('bag_tools', 'recorder_node', {'bag_path': str(tmp_path / 'remap_bag'), 'topics': "['force']"},
                    extra=['--ros-args', '-r', '__node:=recorder_remap', '-r', 'force:=/rig2/force'],
                    key='recorder_remap')
        graph.start('force_tester_monitor', 'monitor_node', {'port': 0}, extra=ns)
        graph.start('force_tester_sim', 'sim_node', {'test_sets': '[1]', 'pulls_per_set': 1,
                                                      'wait_for_subscribers': 2}, extra=ns)
        assert collector.spin_until(lambda: done() or graph.dead(), 120) and not graph.dead(), (
            recorded, graph.tail('sim_node'), graph.tail('recorder_node'))
        root_publishers = collector.node.count_publishers('/monitor/health')
    finally:
        codes = graph.stop()
        collector.close()
    assert codes['recorder_node'] == codes['recorder_remap'] == 0, codes
    assert root_publishers == 0
    topics = bag_info(tmp_path / 'ns_bag')['topics']
    assert {'/rig2/force', '/rig2/motor', '/rig2/accel', '/rig2/encoder', '/rig2/pull_event'} <= set(topics), topics
    assert all(topics[t]['count'] > 0 for t in ('/rig2/force', '/rig2/pull_event')), topics
    remapped = bag_info(tmp_path / 'remap_bag')['topics']
    assert list(remapped) == ['/rig2/force'] and remapped['/rig2/force']['count'] > 0, remapped
