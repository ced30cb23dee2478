"""The launch files (src/force_tester_common/launch/*.launch.xml) against the nodes, without launch installed:
every node is an executable its package installs, every parameter it is given is one the node declares, every
`$(var ...)` is an argument, and the extension pair is remapped exactly as ./ft demo remaps it. (Run for real with
launch and launch_ros from their sources, the three graphs started and scored their pulls: docs/nodes.md.)"""
import importlib
import re
import xml.etree.ElementTree as ET
from importlib.metadata import distribution

import pytest
import yaml

from ft_cli.commands.demo import extension_args
from ft_cli.paths import INSTALL, executable

SHARE = INSTALL / 'force_tester_common' / 'share' / 'force_tester_common'
LAUNCH_FILES = sorted((SHARE / 'launch').glob('*.launch.xml'))
PKG_SHARE = '$(find-pkg-share force_tester_common)'


def declared(package: str, exe: str) -> set:
    """The parameter names the executable's node declares (its module's SPECS), found through its entry point."""
    dist = package.replace('_', '-')
    (ep,) = [e for e in distribution(dist).entry_points if e.group == 'console_scripts' and e.name == exe]
    return {spec.name for spec in importlib.import_module(ep.module).SPECS}


def args_of(root) -> dict:
    return {a.get('name'): a.get('default') for a in root.iter('arg') if a.get('name')}


def resolve(text: str, args: dict) -> str:
    text = re.sub(r'\$\(var (\w+)\)', lambda m: args[m.group(1)], text)
    return text.replace(PKG_SHARE, str(SHARE))


def test_both_launch_files_are_installed():
    assert [p.name for p in LAUNCH_FILES] == ['graph.launch.xml', 'rig.launch.xml']


@pytest.mark.parametrize('path', LAUNCH_FILES, ids=lambda p: p.name)
def test_every_var_is_an_argument_and_every_node_an_installed_executable(path):
    root = ET.parse(path).getroot()
    args = args_of(root)
    text = path.read_text()
    used = set(re.findall(r'\$\(var (\w+)\)', text))
    assert used and used <= set(args), used - set(args)
    for node in root.iter('node'):
        assert executable(node.get('pkg'), node.get('exec')).is_file()
        names = declared(node.get('pkg'), node.get('exec'))
        given = {p.get('name') for p in node.iter('param') if p.get('name')}
        assert given <= names, (node.get('name'), given - names)
        for p in node.iter('param'):
            if p.get('from'):   # the default parameter file: only declared parameters, for this node's name
                data = yaml.safe_load(open(resolve(p.get('from'), args)))
                for key, section in data.items():
                    if key.rsplit('/', 1)[-1] in (node.get('name'), '**'):
                        assert set(section['ros__parameters']) <= names, (key, node.get('name'))
    for inc in root.iter('include'):   # rig.launch.xml includes graph.launch.xml with arguments it has
        target = ET.parse(resolve(inc.get('file'), args)).getroot()
        passed = {a.get('name') for a in inc.iter('arg')}
        assert passed <= set(args_of(target)), passed - set(args_of(target))
        for a in inc.iter('arg'):
            if a.get('name') == 'params_file':
                for rig in ('rig1', 'rig2'):   # the rig files the recipe uses are installed where it looks
                    assert (SHARE / 'config' / 'rigs' / f'{rig}.yaml').is_file()
                    assert resolve(a.get('value'), {**args, 'rig': rig}).endswith(f'config/rigs/{rig}.yaml')


def test_the_extension_pair_is_remapped_as_the_demo_remaps_it(tmp_path):
    root = ET.parse(SHARE / 'launch' / 'graph.launch.xml').getroot()
    nodes = {n.get('name'): n for n in root.iter('node')}
    extension = tmp_path / 'extension.yaml'
    extension.write_text('correction:\n  moving_cell_gain: 1.01\n')
    demo = extension_args(extension)
    for exe, kw in demo.items():
        ros_args = kw['extra']
        pairs = [ros_args[i + 1] for i, a in enumerate(ros_args) if a == '-r']
        node_name = [p.split(':=')[1] for p in pairs if p.startswith('__node:=')][0]
        rules = sorted(p for p in pairs if not p.startswith('__node:='))
        node = nodes[node_name]
        assert node.get('exec') == f'{exe}_node'
        assert sorted(f"{r.get('from')}:={r.get('to')}" for r in node.iter('remap')) == rules
        # the launch file gives what the demo gives, but the validator's peak_u_* inputs, which the demo derives
        # from the rig YAML (ft_cli.peak_inputs); a launched validator takes them from its parameter file
        given = {p.get('name') for p in node.iter('param') if p.get('name')}
        assert given == {k for k in kw.get('params', {}) if not k.startswith('peak_u_')}


def test_the_extension_validator_follows_the_extension_correction(tmp_path):
    """Its correction_node names the extension pair's correction (in the launch file and in ./ft demo alike): a
    change to /correction must not mark the extension's pulls RECONFIGURED (issue 41, item 1)."""
    root = ET.parse(SHARE / 'launch' / 'graph.launch.xml').getroot()
    nodes = {n.get('name'): n for n in root.iter('node')}
    extension = tmp_path / 'extension.yaml'
    extension.write_text('correction:\n  moving_cell_gain: 1.01\n')
    demo = extension_args(extension)
    followed = demo['validator']['params']['correction_node']
    assert followed == demo['correction']['key'] != 'correction'
    launched = {p.get('name'): p.get('value') for p in nodes[demo['validator']['key']].iter('param')}
    assert launched.get('correction_node') == followed, launched
    assert nodes[followed].get('exec') == 'correction_node'
    assert nodes[followed].get('if') == nodes[demo['validator']['key']].get('if') == '$(var extension)'


def test_the_monitor_s_port_and_host_are_arguments_with_the_node_s_defaults():
    """Issue 41 (low): graph.launch.xml monitor:=true port:=8766 host:=0.0.0.0; the defaults are the node's."""
    from force_tester_monitor.core.params import HOST, PORT
    root = ET.parse(SHARE / 'launch' / 'graph.launch.xml').getroot()
    args = args_of(root)
    assert (int(args['port']), args['host']) == (PORT, HOST)
    (monitor,) = [n for n in root.iter('node') if n.get('exec') == 'monitor_node']
    given = {p.get('name'): p.get('value') for p in monitor.iter('param') if p.get('name')}
    assert given == {'port': '$(var port)', 'host': '$(var host)'}


def test_the_docs_say_what_a_status_s_hardware_id_is():
    """Issue 41 (low): docs/nodes.md described hardware_id as the node (`/rig1/correction`); it is the rig."""
    from force_tester_common.core.health import hardware_id_of
    from ft_cli.paths import ROOT
    text = ' '.join((ROOT / 'docs' / 'nodes.md').read_text().split())
    rig = hardware_id_of('/rig1')
    assert f"`hardware_id` is the node's namespace without its slashes, the rig: `{rig}` for" in text
    assert "`hardware_id` names the node" not in text


def test_a_rig_without_a_parameter_file_is_refused():
    """rig:=rig3 (a typo) ran a default rig with three warnings (issue 41, Low): the rig argument's choices are the
    installed parameter files config/rigs/*.yaml, so launch refuses any other value before it starts a node."""
    root = ET.parse(SHARE / 'launch' / 'rig.launch.xml').getroot()
    (rig,) = [a for a in root.iter('arg') if a.get('name') == 'rig']
    choices = [c.get('value') for c in rig.iter('choice')]
    assert choices and sorted(choices) == sorted(p.stem for p in (SHARE / 'config' / 'rigs').glob('*.yaml'))
    assert rig.get('default') in choices
