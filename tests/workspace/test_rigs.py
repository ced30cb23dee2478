"""Several rigs on one machine (README, "Running nodes by hand"): each rig's sim, correction and validator under its own
namespace, as separate processes or with every rig's correction and validator composed in one
process, through `./ft bench rigs` (real processes over Fast DDS)."""
import json
import subprocess
import sys

import pytest
from conftest import ROOT


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
