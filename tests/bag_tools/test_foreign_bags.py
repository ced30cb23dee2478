"""Bags from anywhere (docs/reliability.md, "Bags from elsewhere"): bags that look like other people's
(tests/bag_tools/foreign.py writes them with the mcap library and rosbags) go through every `./ft bag`
command. A traceback or an "internal error" anywhere is a failure; errors are one short line; what is read is compared
with what was written."""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter

import pytest
import yaml
from daq_data import SRC_DIRS
from foreign import (
    CHATTER_TOPIC,
    CHATTER_TYPE,
    SERVICE_EVENT_TYPE,
    SERVICE_TOPIC,
    SPECS,
    UNPLAYABLE,
    VENDOR_TOPIC,
    Spec,
    campaign_messages,
    message_counts,
    write_foreign_bag,
)

from bag_tools.cli import MAX_LINE, build_parser
from bag_tools.core.info import bag_info, format_info
from bag_tools.core.reader import open_bag
from force_correction.offline.cli import COMMANDS
from force_correction.offline.cli import main as ft_bag
from force_tester_common.core.channels import FORCE_TYPE

BY_NAME = {s.name: s for s in SPECS}
OWN_TOPICS = ('/force', '/accel', '/encoder', '/motor', '/pull_event')


@pytest.fixture(scope='module')
def foreign(tmp_path_factory):
    """(campaign messages, {spec name: bag path}), written once for the module."""
    work = tmp_path_factory.mktemp('foreign')
    base = campaign_messages(work)
    return base, {s.name: write_foreign_bag(s, work / 'bags', base) for s in SPECS}


def clean(text: str) -> None:
    """No traceback, no internal error, every line short."""
    assert 'Traceback' not in text and 'internal error' not in text, text
    assert all(len(line) <= MAX_LINE for line in text.splitlines()), text


def error_lines(err: str) -> int:
    return sum(': error: ' in line for line in err.splitlines())


def run(capsys, *args) -> tuple:
    """`./ft bag ARGS` in this process: (exit code, stdout, stderr)."""
    try:
        code = ft_bag([str(a) for a in args])
    except SystemExit as exc:  # argparse: --help or a usage error
        code = exc.code
    out, err = capsys.readouterr()
    clean(out + err)
    return code, out, err


# --------------------------------------------------------------------------- reading
@pytest.mark.parametrize('name', [s.name for s in SPECS if not s.refused])
def test_info_reads_every_message_of_every_foreign_bag(foreign, name):
    base, bags = foreign
    spec, bag = BY_NAME[name], bags[name]
    want = {} if spec.empty else message_counts(base)
    info = bag_info(bag)
    assert info['message_count'] == sum(want.values())
    assert {t: v['count'] for t, v in info['topics'].items() if v['count']} == want
    assert set(info['topics']) == set(message_counts(base))  # listed even when empty
    files = sorted(p.name for p in bag.iterdir() if p.name != 'metadata.yaml')
    assert sorted(info['storage_files']) == files and len(files) == spec.split
    assert info['pulls']['count'] == (0 if spec.empty else 3)
    assert info['count_differences'] == ([(CHATTER_TOPIC, 5 + spec.counts_off, 5)]
                                         if spec.counts_off else [])
    if not spec.empty:  # our topics come back byte for byte, in time order
        with open_bag(bag) as b:
            got = [(m.topic, m.stamp_ns, m.cdr) for m in b.messages(list(OWN_TOPICS))]
            assert all(m.type_name.count('/') == 2 for m in b.messages(CHATTER_TOPIC))
        assert [s for _t, s, _c in got] == sorted(s for _t, s, _c in got)
        assert sorted(got) == sorted((t, s, c) for t, _ty, s, c in base)


def test_count_differences_are_said_once(foreign):
    base, bags = foreign
    info = bag_info(bags['counts_differ'])
    total = sum(message_counts(base).values())
    assert (info['message_count'], info['metadata_message_count']) == (total, total + 3)
    text = format_info(info)
    assert text.count('Messages:') == 1 and f'Messages:  {total}\n' in text
    assert f'metadata.yaml says {total + 3}' in text
    assert f'{CHATTER_TOPIC}: storage holds 5, metadata.yaml says 8' in text


def test_service_events_decode_as_rosidl_event_messages(foreign):
    _base, bags = foreign
    for name in ('jazzy_mcap_services', 'old_names', 'message_zstd_sqlite3'):
        with open_bag(bags[name]) as b:
            events = [b.deserialize(m.cdr, m.type_name) for m in b.messages(SERVICE_TOPIC)]
            want = SERVICE_EVENT_TYPE.replace('/srv/', '/msg/') if BY_NAME[name].old_names \
                else SERVICE_EVENT_TYPE  # an old 'pkg/Type' name reads as pkg/msg/Type
            assert b.topics()[SERVICE_TOPIC].type_name == want
        assert [len(e.request) for e in events] == [1, 0], name
        assert events[0].request[0].gain == 1.5 and events[1].response[0].message == 'done'
        assert [e.info.event_type for e in events] == [0, 1]


def test_a_definition_that_does_not_parse_is_one_short_line(tmp_path, foreign, capsys):
    """Only the type a command needs is built; when that one does not parse, one short line."""
    base, _bags = foreign
    garbage = 'float64[ moving_n ' + 'x' * 1000  # the parser quotes all of it
    bag = write_foreign_bag(Spec('bad_def'), tmp_path, base, {FORCE_TYPE: garbage})
    code, out, _err = run(capsys, 'info', bag)  # info does not need ForceBlock's fields to list it
    assert code == 0 and 'force_tester_msgs/msg/ForceBlock' in out
    code, _out, err = run(capsys, 'export', bag, tmp_path / 'c')
    assert code == 2 and error_lines(err) == 1, err
    assert 'ForceBlock' in err and 'does not parse' in err


def test_error_lines_are_short_unless_verbose(tmp_path, capsys):
    missing = tmp_path / ('d' * 100) / ('e' * 100) / ('f' * 100)
    code, _out, err = run(capsys, 'info', missing)
    assert code == 2 and len(err.strip()) <= MAX_LINE and err.strip().endswith(
        '(--verbose: whole message)')
    try:
        code = ft_bag(['--verbose', 'info', str(missing)])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and str(missing) in err and 'does not exist' in err
    # a long path loses its leading folders before the reason after it is cut
    deep = tmp_path / ('g' * 60) / ('h' * 60) / 'campaign'
    code, _out, err = run(capsys, 'info', deep)
    assert code == 2 and len(err.strip()) <= MAX_LINE and 'does not exist' in err, err
    assert f"'.../{'h' * 60}/campaign'" in err, err


# --------------------------------------------------------------------------- every command
#: What each `./ft bag` command is given, for a bag `b` and a new output path `o` (record and
#: import make bags rather than read them). A new command must be added here.
ARGS = {
    'info': lambda b, o: [b],
    'play': lambda b, o: [b, '--rate', '1000'],
    'export': lambda b, o: [b, o],
    'correct': lambda b, o: [b, o],
    'plot': lambda b, o: [b, '--pull', '1', '--out', f'{o}.png'],
    'reindex': lambda b, o: [shutil.copytree(b, o)],  # on a copy: it may rewrite the bag
    'record': None,
    'import': None,
}


def commands() -> list:
    sub = next(a for a in build_parser(COMMANDS)._actions if a.dest == 'command')
    return sorted(sub.choices)


def test_the_command_table_covers_every_command():
    assert set(commands()) <= set(ARGS)


@pytest.mark.parametrize('name', [s.name for s in SPECS])
def test_every_command_on_every_foreign_bag(foreign, name, tmp_path, capsys, ros_domain):
    spec, bag = BY_NAME[name], foreign[1][name]
    for cmd in commands():
        if ARGS.get(cmd) is None:
            continue
        code, out, err = run(capsys, cmd, *ARGS[cmd](bag, tmp_path / cmd))
        if cmd == 'reindex':
            assert code in (0, 2), (cmd, err)  # a complete bag: nothing to do, or refused
        elif spec.refused:  # lz4 file compression: rosbag2 cannot read it either
            assert code == 2 and "'lz4' file compression" in err, (cmd, err)
        elif spec.empty:
            if cmd == 'play':
                assert code == 0 and 'nothing to play' in err, err
            else:
                assert code == (0 if cmd == 'info' else 2), (cmd, out, err)
        else:
            assert code == 0, (cmd, out, err)
            if cmd == 'play':
                assert 'played' in err and all(f'skipping {t}:' in err for t in UNPLAYABLE)
            if cmd == 'export':
                assert 'exported 3 pull(s)' in out
            if cmd == 'correct':
                with open_bag(tmp_path / 'correct') as b:  # foreign topics copied through
                    assert b.topics()[VENDOR_TOPIC].count == 4
                    assert b.topics()[SERVICE_TOPIC].count == 2
        if code:
            assert error_lines(err) == 1, (cmd, err)


# --------------------------------------------------------------------------- play
def test_play_options_anywhere_and_help(foreign, capsys, ros_domain):
    bag = foreign[1]['jazzy_mcap_services']
    for flag in ('-h', '--help'):
        code, out, _err = run(capsys, 'play', flag)
        assert code == 0 and 'usage: ./ft bag play' in out and '--wait-for-subscribers' in out
    code, out, _err = run(capsys, '--help')
    assert code == 0 and '(./ft bag play --help)' in out
    code, _out, err = run(capsys, 'play', '--rate', '1000', '--topics', CHATTER_TOPIC, '--', bag)
    assert code == 0 and 'played 5 messages on 1 topic(s)' in err, err
    code, _out, err = run(capsys, 'play', bag, '--rate', '1000', '--topics', CHATTER_TOPIC,
                          '--ros-args', '-r', '__node:=other_player')
    assert code == 0 and 'played 5 messages' in err, err
    code, _out, err = run(capsys, 'info', bag, '--ros-args', '-r', 'a:=b')
    assert code == 2 and '--ros-args applies to play' in err


def _bag_process(*args):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [*map(str, SRC_DIRS), os.environ.get('PYTHONPATH', '')]))
    return subprocess.Popen([sys.executable, '-m', 'force_correction.offline.cli', *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _wait(cond, timeout, proc=None) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        if proc is not None and proc.poll() is not None:
            return cond()
        time.sleep(0.05)
    return False


def test_play_names_the_topics_short_of_subscribers(foreign, ros_domain):
    """--wait-for-subscribers that times out: exit 2 with one line naming each topic that fell short and its
    subscriber count (issue 41, Low: before, 'fewer than 1 subscriber(s) after 1.0 s' named none)."""
    bag = foreign[1]['old_names_mcap']
    p = _bag_process('play', '--wait-for-subscribers', '1', '--wait-timeout', '1', '--topics', CHATTER_TOPIC, bag)
    out, err = p.communicate(timeout=90)
    assert p.returncode == 2, err
    assert f'error: fewer than 1 subscriber(s) after 1 s on {CHATTER_TOPIC} (0)' in err, err


def test_play_skips_what_it_cannot_import_and_plays_the_rest(foreign, ros_domain):
    """A real subscriber gets every /chatter message while the topics of types that are not
    installed are listed as skipped; then Ctrl-C in a looping play ends it with 130."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    from force_tester_common.ros import BLOCK_QOS
    bag = foreign[1]['old_names_mcap']  # pkg/Type names too
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    got: list = []
    node = rclpy.create_node('chatter_listener', context=ctx)
    node.create_subscription(String, CHATTER_TOPIC, lambda m: got.append(m.data), BLOCK_QOS)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    procs = []
    try:
        topics = ('--topics', CHATTER_TOPIC, *UNPLAYABLE)
        p = _bag_process('play', '--wait-for-subscribers', '1', *topics, bag)
        procs.append(p)
        out, err = p.communicate(timeout=90)
        clean(out + err)
        assert p.returncode == 0, err
        assert _wait(lambda: len(got) == 5, 10), got
        assert got == [f'hello {i}' for i in range(5)]
        assert f"skipping {VENDOR_TOPIC}: type vendor_msgs/msg/Status is not installed " \
               "(no Python package 'vendor_msgs')" in err, err
        assert f'skipping {SERVICE_TOPIC}: type vendor_srvs/msg/SetGain_Event is not ' \
               "installed (no Python package 'vendor_srvs')" in err  # its old name, made full
        assert 'played 5 messages on 1 topic(s)' in err and 'skipped 2 topic(s)' in err

        before = len(got)
        p = _bag_process('play', '--loop', '--rate', '0.5', *topics, bag)
        procs.append(p)
        assert _wait(lambda: len(got) > before + 2, 60, p), (len(got), p.poll())
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
        clean(out + err)
        assert p.returncode == 130, err
        assert 'interrupted; stopped after' in err

        # interrupted in its first pass (the 5 messages 1 s apart), it says what it published
        # (before: 0, the count was made when a pass ended)
        before = len(got)
        p = _bag_process('play', '--wait-for-subscribers', '1', '--rate', '0.002', *topics, bag)
        procs.append(p)
        assert _wait(lambda: len(got) >= before + 2, 60, p), (len(got), p.poll())
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
        clean(out + err)
        assert p.returncode == 130, err
        stopped = re.search(r'interrupted; stopped after (\d+) messages', err)
        assert stopped and 5 > int(stopped.group(1)) >= len(got) - before >= 2, (err, len(got) - before)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        spinner.join(timeout=5)
    assert Counter(got)['hello 0'] >= 2  # the loop played the bag again


# --------------------------------------------------------------------------- our own bags
def test_our_bags_say_jazzy(foreign, tmp_path):
    from daq_data import T0, make_pulls
    from mcap.reader import make_reader

    from bag_tools.core.convert import campaign_to_bag
    from bag_tools.core.daq import write_campaign
    from bag_tools.core.split_writer import open_bag_writer
    from bag_tools.core.typestore import default_typestore
    bag = campaign_to_bag(write_campaign(tmp_path / 'camp', make_pulls(1, start=T0)),
                          tmp_path / 'own')
    store = default_typestore()
    with open_bag_writer(tmp_path / 'split', store, max_bytes=2000) as w:
        w.add_topic(CHATTER_TOPIC, CHATTER_TYPE)
        for i in range(50):
            w.write(CHATTER_TOPIC, T0 + i, store.serialize_cdr(
                store.types[CHATTER_TYPE](data='x' * 100), CHATTER_TYPE))
    for path in (bag, tmp_path / 'split'):
        meta = yaml.safe_load((path / 'metadata.yaml').read_text())
        assert meta['rosbag2_bagfile_information']['ros_distro'] == 'jazzy'
    with next(bag.glob('*.mcap')).open('rb') as f:
        records = list(make_reader(f).iter_metadata())
    embedded = yaml.safe_load(records[0].metadata['serialized_metadata'])
    assert embedded['ros_distro'] == 'jazzy'
