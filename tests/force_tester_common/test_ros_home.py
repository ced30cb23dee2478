"""A node's relative file parameters (the validator's state_file) resolve under ROS_HOME, as ROS
resolves its own files: the same file whatever directory the node was started from (issue 30)."""
from pathlib import Path

from force_tester_common.core.ros_home import ros_home, under_ros_home


def test_a_relative_path_is_under_ros_home_and_an_absolute_one_stays(tmp_path, monkeypatch):
    env = {'ROS_HOME': str(tmp_path / 'rh'), 'HOME': str(tmp_path / 'home')}
    want = tmp_path / 'rh' / 'force_tester' / 'rig1_scores.jsonl'
    assert under_ros_home('force_tester/rig1_scores.jsonl', env) == want
    assert under_ros_home(tmp_path / 'abs.jsonl', env) == tmp_path / 'abs.jsonl'
    monkeypatch.chdir(tmp_path)   # the working directory plays no part
    assert under_ros_home('s.jsonl', env) == tmp_path / 'rh' / 's.jsonl'


def test_without_ros_home_it_is_dot_ros_in_the_home_directory(tmp_path, monkeypatch):
    monkeypatch.setenv('HOME', str(tmp_path))
    assert ros_home({}) == tmp_path / '.ros'
    assert ros_home({'ROS_HOME': ''}) == tmp_path / '.ros'
    assert under_ros_home('s.jsonl', {}) == tmp_path / '.ros' / 's.jsonl'
    assert under_ros_home('~/x.jsonl', {}) == Path(tmp_path) / 'x.jsonl'


def test_the_shipped_rig_files_keep_their_scores_under_ros_home():
    """A relative state_file in config/rigs (the README recipe runs from any directory)."""
    import yaml

    from ft_cli.paths import ROOT
    for f in sorted((ROOT / 'config' / 'rigs').glob('*.yaml')):
        for node, section in yaml.safe_load(f.read_text()).items():
            state = section['ros__parameters'].get('state_file')
            if state is not None:
                assert not Path(state).is_absolute() and under_ros_home(state, {'ROS_HOME': '/rh'}) == \
                    Path('/rh') / state, (f.name, node, state)
