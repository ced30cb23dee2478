"""./ft's set-up: the lock is installed exactly (by uv, itself pinned and hash-checked), whatever the registry
serves next; an air-gapped machine installs from a folder; a failing step says why in one line; a change builds
only the packages it touched.

The packages here are real wheels built by the test: `alpha` requires `beta[fast]>=1.0` (a
requirement with an extra, as pytest-cov requires `coverage[toml]`), and the wheel folder holds
a *newer* beta than the lock pins, as the registry did when coverage 7.17.4 came out.
"""
from __future__ import annotations

import base64
import hashlib
import os
import shutil
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

from ft_cli import bootstrap
from ft_cli.commands import lock

PACKAGES = {  # name -> (version, Requires-Dist lines, Provides-Extra)
    'alpha': ('1.0', ['beta[fast]>=1.0'], []),
    'beta': ('1.0', ['gamma>=1.0; extra == "fast"'], ['fast']),
    'gamma': ('1.0', [], []),
}
NEWER_BETA = '1.1'


def _record_hash(data: bytes) -> str:
    return 'sha256=' + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b'=').decode()


def build_wheel(folder: Path, name: str, version: str, requires: list, extras: list) -> Path:
    """A pure-Python wheel (PEP 427) with one module that knows its version."""
    dist_info = f'{name}-{version}.dist-info'
    metadata = ['Metadata-Version: 2.1', f'Name: {name}', f'Version: {version}']
    metadata += [f'Provides-Extra: {e}' for e in extras] + [f'Requires-Dist: {r}' for r in requires]
    files = {
        f'{name}/__init__.py': f'VERSION = {version!r}\n'.encode(),
        f'{dist_info}/METADATA': ('\n'.join(metadata) + '\n').encode(),
        f'{dist_info}/WHEEL': b'Wheel-Version: 1.0\nGenerator: test_setup\nRoot-Is-Purelib: true\nTag: py3-none-any\n',
    }
    record = ''.join(f'{path},{_record_hash(data)},{len(data)}\n' for path, data in files.items())
    files[f'{dist_info}/RECORD'] = (record + f'{dist_info}/RECORD,,\n').encode()
    path = folder / f'{name}-{version}-py3-none-any.whl'
    with zipfile.ZipFile(path, 'w') as z:
        for arc, data in files.items():
            z.writestr(arc, data)
    return path


def write_lock(path: Path, wheels: dict) -> Path:
    """A lock as `./ft lock` writes it: one pin per package, with the wheel's hash."""
    lines = []
    for name, wheel in wheels.items():
        digest = hashlib.sha256(wheel.read_bytes()).hexdigest()
        lines.append(f'{name}=={PACKAGES[name][0]} \\\n    --hash=sha256:{digest}\n')
    path.write_text(''.join(lines))
    return path


@pytest.fixture(scope='module')
def registry(tmp_path_factory):
    """A wheel folder standing in for the registry (with the newer beta) and a lock of the older ones."""
    root = tmp_path_factory.mktemp('registry')
    folder = root / 'wheels'
    folder.mkdir()
    wheels = {name: build_wheel(folder, name, *spec) for name, spec in PACKAGES.items()}
    version, requires, extras = PACKAGES['beta']
    build_wheel(folder, 'beta', NEWER_BETA, requires, extras)
    return folder, write_lock(root / 'requirements.lock', wheels)


@pytest.fixture(scope='module')
def uv(tmp_path_factory):
    """The workspace's uv (requirements-uv.lock, in .ft/uv: ./ft installed it to set this workspace up)."""
    return bootstrap.ensure_uv(tmp_path_factory.mktemp('uv') / 'uv.log')


@pytest.fixture(scope='module')
def uv_wheel(tmp_path_factory):
    """A folder with the uv wheel that requirements-uv.lock pins (hash checked; FT_WHEELS if set, else PyPI)."""
    folder = tmp_path_factory.mktemp('uv_wheel')
    wheels = os.environ.get('FT_WHEELS')
    subprocess.run([str(Path(bootstrap.ensure_uv(folder / 'log').parent / 'python')), '-m', 'pip', 'download',
                    '--no-deps', '--require-hashes', '--no-input', '-q', '-d', str(folder),
                    *bootstrap.source_args(Path(wheels) if wheels else None), '-r', str(bootstrap.UV_LOCK)],
                   check=True)
    return next(folder.glob('uv-*.whl'))


def fresh_python(path: Path) -> Path:
    """A new venv with the pip that `python -m venv` bundles, as ./ft's first step makes one."""
    venv.EnvBuilder(with_pip=True).create(path)
    return path / 'bin' / 'python'


def offline_env() -> dict:
    """No pip configuration from this machine: no extra index, no find-links of its own."""
    env = {k: v for k, v in os.environ.items() if not k.startswith('PIP_')}
    return dict(env, PIP_CONFIG_FILE=os.devnull, PIP_NO_INDEX='1')


def installed_version(python: Path, name: str) -> str:
    out = subprocess.run([str(python), '-c', f'import importlib.metadata as m; print(m.version({name!r}))'],
                         capture_output=True, text=True, check=True)
    return out.stdout.strip()


@pytest.mark.slow
def test_a_newer_release_of_a_dependency_required_with_an_extra_does_not_change_the_install(
        registry, uv, tmp_path, monkeypatch):
    folder, lock_file = registry
    for k in [k for k in os.environ if k.startswith('PIP_')]:
        monkeypatch.delenv(k)
    monkeypatch.setenv('PIP_CONFIG_FILE', os.devnull)
    python = fresh_python(tmp_path / 'venv')
    log = tmp_path / 'venv.log'
    bootstrap.install_lock(python, lock_file, log, wheels=folder, uv=uv)
    assert installed_version(python, 'beta') == PACKAGES['beta'][0]
    assert installed_version(python, 'gamma') == PACKAGES['gamma'][0]
    assert 'All installed packages are compatible' in log.read_text()   # uv pip check


@pytest.mark.slow
def test_the_resolving_install_of_before_fails_on_the_same_folder(registry, tmp_path):
    """What broke every fresh machine: pip resolves `beta[fast]` on its own, takes the newer beta and
    refuses it for having no hash. Kept so that the test above is known to test something."""
    folder, lock_file = registry
    python = fresh_python(tmp_path / 'venv')
    res = subprocess.run([str(python), '-m', 'pip', 'install', '--require-hashes', '--no-index', '--find-links',
                          str(folder), '-r', str(lock_file)], capture_output=True, text=True, env=offline_env())
    assert res.returncode != 0
    assert f'beta-{NEWER_BETA}' in res.stdout + res.stderr


@pytest.mark.slow
def test_a_failing_install_says_the_step_the_log_and_the_line_that_explains_it(registry, uv, tmp_path):
    folder, lock_file = registry
    text = lock_file.read_text()
    bad = tmp_path / 'requirements.lock'
    bad.write_text(text.replace(text.split('sha256:')[1][:64], '0' * 64, 1))   # alpha's hash is wrong
    python = fresh_python(tmp_path / 'venv')
    log = tmp_path / 'venv.log'
    with pytest.raises(bootstrap.SetupError) as err:
        bootstrap.install_lock(python, bad, log, wheels=folder, uv=uv)
    message = str(err.value)
    assert message.startswith('uv pip install failed: ') and str(log) in message
    assert '\n' not in message and 'hash' in message.lower()


@pytest.mark.slow
def test_the_wheels_folder_installs_with_no_network(registry, uv_wheel, tmp_path):
    """`./ft wheels DIR` fills DIR from the lock and requirements-uv.lock (hashes checked); FT_WHEELS=DIR installs
    uv and then the lock from it in a network namespace with no interface but loopback."""
    folder, lock_file = registry
    source = tmp_path / 'registry'
    shutil.copytree(folder, source)
    shutil.copy2(uv_wheel, source)
    carried = tmp_path / 'carried'
    env = dict(offline_env(), PIP_FIND_LINKS=str(source))
    res = subprocess.run([sys.executable, '-c', 'import sys; from ft_cli import bootstrap; sys.exit(0 if '
                          f'bootstrap.download(bootstrap.Path({str(lock_file)!r}), bootstrap.Path({str(carried)!r}), '
                          f'bootstrap.Path({str(tmp_path / "wheels.log")!r})) == 4 else 1)'],
                         env=dict(env, PYTHONPATH=str(Path(bootstrap.__file__).parents[1])))
    assert res.returncode == 0, (tmp_path / 'wheels.log').read_text()
    assert sorted(p.name for p in carried.iterdir()) == sorted(
        [uv_wheel.name, *(f'{n}-{v}-py3-none-any.whl' for n, (v, _, _) in PACKAGES.items())])
    python = fresh_python(tmp_path / 'venv')
    home = tmp_path / 'uv_home'   # a machine without uv: installed from the folder too
    script = ('import sys; from pathlib import Path; from ft_cli import bootstrap; '
              f'log = Path({str(tmp_path / "venv.log")!r}); wheels = Path({str(carried)!r}); '
              f'uv = bootstrap.ensure_uv(log, wheels, home=Path({str(home)!r})); '
              f'bootstrap.install_lock(Path({str(python)!r}), Path({str(lock_file)!r}), log, wheels=wheels, uv=uv)')
    cmd = [sys.executable, '-c', script]
    if shutil.which('unshare') and subprocess.run(['unshare', '-n', 'true']).returncode == 0:
        cmd = ['unshare', '-n', *cmd]  # no network at all
    res = subprocess.run(cmd, env=dict(offline_env(), PYTHONPATH=str(Path(bootstrap.__file__).parents[1])),
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr + (tmp_path / 'venv.log').read_text()
    assert (home / 'bin' / 'uv').exists()
    assert installed_version(python, 'beta') == PACKAGES['beta'][0]


def test_only_the_changed_packages_and_those_above_them_are_built(tmp_path):
    """The build's selection: a package whose files changed (names and times) or that install/ lacks."""
    src, install = tmp_path / 'src', tmp_path / 'install'
    for name in ('low', 'high'):
        (src / name / name).mkdir(parents=True)
        (src / name / 'package.xml').write_text(f'<package><name>{name}</name></package>')
        (src / name / name / '__init__.py').write_text('')
        (install / name).mkdir(parents=True)
    states = bootstrap.package_states(src)
    assert sorted(states) == ['high', 'low']
    assert bootstrap.changed_packages(states, states, install) == []
    (src / 'high' / 'high' / '__pycache__').mkdir()          # byte-code is not a change
    (src / 'high' / 'high' / '__pycache__' / 'x.pyc').write_text('')
    assert bootstrap.package_states(src) == states
    os.utime(src / 'low' / 'low' / '__init__.py', ns=(1, 1))    # touched
    assert bootstrap.changed_packages(bootstrap.package_states(src), states, install) == ['low']
    (src / 'high' / 'high' / 'new.py').write_text('')           # a file added
    shutil.rmtree(install / 'low')
    assert bootstrap.changed_packages(bootstrap.package_states(src), {}, install) == ['high', 'low']
    assert bootstrap.changed_packages(states, states, install) == ['low']   # install/ lacks it


def test_an_incomplete_closure_fails_the_lock_check(registry):
    _, lock_file = registry
    requires = {name: spec[1] for name, spec in PACKAGES.items()}
    assert lock.closure_problems(lock_file.read_text(), requires.get) == []
    without_gamma = lock_file.read_text().split('gamma==')[0]
    problems = lock.closure_problems(without_gamma, requires.get)
    assert problems == ['gamma (required by beta) is not pinned']   # reached only through beta's extra
    older = lock_file.read_text().replace('beta==1.0', 'beta==0.9')
    assert any("beta==0.9 does not satisfy alpha's" in p for p in lock.closure_problems(older, requires.get))


@pytest.mark.parametrize('args', [['--help'], ['demo', '--help'], ['bag', 'correct', '--help'], ['env'],
                                  ['wheels', '--help'], ['discover', '--help'], ['view', '--help']])
def test_help_and_env_answer_on_a_fresh_clone_without_setting_anything_up(tmp_path, args):
    """A copy of the workspace's tracked files, no .venv, no install/: nothing is installed or built."""
    root = Path(lock.ROOT)
    files = subprocess.run(['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'], cwd=root,
                           capture_output=True, check=True).stdout.split(b'\0')
    clone = tmp_path / 'clone'
    for rel in filter(None, files):
        src = root / rel.decode()
        if src.is_file():
            (clone / rel.decode()).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, clone / rel.decode())
    env = {k: v for k, v in os.environ.items() if k not in ('PYTHONPATH', 'VIRTUAL_ENV', 'AMENT_PREFIX_PATH')}
    res = subprocess.run([str(clone / 'ft'), *args], cwd=clone, env=env, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert (res.stdout.startswith('usage: ./ft') or 'export VIRTUAL_ENV=' in res.stdout), res.stdout[:200]
    assert not (clone / '.venv').exists() and not (clone / 'install').exists()


@pytest.mark.parametrize('log, expected', [
    ('Collecting x\nERROR: Could not find a version that satisfies the requirement x==9 (from versions: none)\n'
     'ERROR: No matching distribution found for x==9\n',
     'ERROR: Could not find a version that satisfies the requirement x==9 (from versions: none)'),
    ('Starting >>> force_tester_msgs\n-- Found ament_cmake\nCMake Error at CMakeLists.txt:12 (find_package):\n'
     '  By not providing "Findrosidl_default_generators.cmake"\n--- stderr: force_tester_msgs\n'
     'Failed   <<< force_tester_msgs [1.2s, exited with code 1]\n',
     'CMake Error at CMakeLists.txt:12 (find_package): By not providing "Findrosidl_default_generators.cmake"'),
    ('Resolved 3 packages in 3ms\nerror: Failed to download `alpha==1.0`\n  cause: Hash mismatch for `alpha==1.0`\n\n'
     '         Expected:\n           sha256:0000\n',
     'error: Failed to download `alpha==1.0`: Hash mismatch for `alpha==1.0`'),
    ('npm error code ENOTCACHED\nnpm error request to https://registry/x failed: cache mode is only-if-cached\n',
     'npm error code ENOTCACHED'),
])
def test_the_explaining_line_is_the_first_error(log, expected):
    assert bootstrap.explaining_line(log) == expected


def test_the_mend_never_edits_a_file_uv_linked_from_its_cache(tmp_path):
    """uv installs a wheel's files as hard links to its cache: the mend writes a new file instead of editing the
    linked one (an edit in place put one venv's numpy path into every later venv), and it rewrites such a foreign
    path, as it rewrites the wheel builder's."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'tools'))
    from fix_ros_wheels import mend
    line = '  INTERFACE_INCLUDE_DIRECTORIES "{py};{np}"\n'
    builder = line.format(py='/opt/python/cp311-cp311/include/python3.11',
                          np='/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include')
    foreign = line.format(py='/usr/include/python3.11',
                          np='/tmp/other/.venv/lib/python3.11/site-packages/numpy/_core/include')
    cache, prefix = tmp_path / 'cache', tmp_path / 'venv'
    cache.mkdir()
    for pkg, text in (('std_msgs', builder), ('rcl_interfaces', foreign)):
        (cache / pkg).write_text(text)
        (prefix / 'share' / pkg / 'cmake').mkdir(parents=True)
        os.link(cache / pkg, prefix / 'share' / pkg / 'cmake' / f'export_{pkg}__rosidl_generator_pyExport.cmake')
    want = line.format(py='/py/include/python3.11', np=str(prefix / 'lib/python3.11/site-packages/numpy/_core/include'))
    assert mend(prefix, '/py/include/python3.11', str(prefix / 'lib/python3.11/site-packages/numpy/_core/include')) == 2
    for pkg, text in (('std_msgs', builder), ('rcl_interfaces', foreign)):
        assert (prefix / 'share' / pkg / 'cmake' / f'export_{pkg}__rosidl_generator_pyExport.cmake').read_text() == want
        assert (cache / pkg).read_text() == text            # the cache's file as uv unpacked it
    assert mend(prefix, '/py/include/python3.11', str(prefix / 'lib/python3.11/site-packages/numpy/_core/include')) == 0

