"""The workspace's set-up steps, run by ./ft before anything is installed (standard library only).

    python -m ft_cli.bootstrap venv  --venv DIR --lock FILE --log FILE [--wheels DIR]
    python -m ft_cli.bootstrap build --log FILE
    python -m ft_cli.bootstrap npm   --log FILE [--wheels DIR]
    python -m ft_cli.bootstrap chromium --log FILE

The lock is installed exactly as written, with no dependency resolution at all, by uv:
`uv pip install --no-deps --require-hashes --compile-bytecode -r LOCK` (every .pyc written once: where
PYTHONDONTWRITEBYTECODE is set no command would write one), then `uv pip check`. requirements.lock is the whole
closure (`./ft lock --check` says so), so nothing needs resolving; a resolver would ask the index again for every
requirement that names an extra (`coverage[toml]`) and could pick a newer, unpinned release than the lock's. uv
downloads and unpacks the wheels in parallel and links them from its cache (pip installed them one at a time:
2.5 min of the 4 min of a first set-up). uv itself comes first, from requirements-uv.lock (pinned, with its hash),
installed with the pip that `python -m venv` bundles into .ft/uv. With --wheels DIR both installs read only DIR
(`--no-index --find-links DIR`, uv also `--offline`): an air-gapped machine installs from a folder that
`./ft wheels DIR` filled (the uv wheel included).

A failing step prints one line: the step, the log file and the log's line that explains it.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: uv, pinned with its hash (installed with pip before anything else), and the venv it is installed into
UV_LOCK = ROOT / 'requirements-uv.lock'
UV_HOME = ROOT / '.ft' / 'uv'
# what pip needs to build the lock's few sdists (empy) from a wheel folder with no index
SDIST_BUILD_TOOLS = ('setuptools', 'wheel')
NPM_CACHE = 'npm-cache'   # the folder of `./ft wheels DIR` that holds the npm packages' tarballs
# Debian's Chromium for the viewer's browser test, pinned. Debian's archive keeps only the newest build of a
# release (each security update replaces it), so when the pin is gone from the archive the newest is installed
# and the step says so: bump the pin then. chromium depends on chromium-common of its own version exactly, so both
# are pinned: with chromium alone pinned, apt takes the newest chromium-common (a security update's) and refuses.
CHROMIUM = 'chromium'
CHROMIUM_PACKAGES = (CHROMIUM, 'chromium-common')
CHROMIUM_VERSION = '150.0.7871.100-1~deb12u1'


class SetupError(Exception):
    """A set-up step failed: the step, its log file, and the log's line that explains it."""

    def __init__(self, step: str, log: Path, line: str):
        super().__init__(f'{step} failed: {line} (log: {log})')


def explaining_line(text: str) -> str:
    """The line of a tool's log that says why it failed: uv's (with its causes), pip's, CMake's, colcon's or
    npm's first error."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    patterns = (r'^ERROR: (?!Exception:)', r'^CMake Error', r'error:', r'^npm ERR!|^npm error', r'\berror\b',
                r'Failed\s+<<<', r'has requirement|requires .*, which is not installed|is not supported')
    for pattern in patterns:
        for i, line in enumerate(lines):
            if re.search(pattern, line, re.I):
                # pip's "ERROR: ... These do not:" names the culprit on the next line
                if line.endswith(':') and i + 1 < len(lines):
                    return f'{line} {lines[i + 1]}'
                # uv's "error: ..." is followed by its causes, the innermost last ("cause: Hash mismatch ...")
                causes = []
                for later in lines[i + 1:]:
                    if not re.match(r'(cause|Caused by):', later):
                        break
                    causes.append(later.split(':', 1)[1].strip())
                return ': '.join([line, *causes])
    return lines[-1] if lines else '(the log is empty)'


def _run(step: str, cmd: list, log: Path, env: dict | None = None, cwd: Path | None = None) -> None:
    with open(log, 'a') as out:
        out.write(f'$ {" ".join(map(str, cmd))}\n')
        out.flush()
        rc = subprocess.call([str(c) for c in cmd], stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd)
    if rc:
        raise SetupError(step, log, explaining_line(log.read_text(errors='replace').split('$ ')[-1]))


def _pip_env() -> dict:
    env = dict(os.environ, PIP_DISABLE_PIP_VERSION_CHECK='1', _ROS_WHEELS_BOOTSTRAP_COMPLETE='1')
    env.pop('PIP_REQUIRE_VIRTUALENV', None)
    return env


def source_args(wheels: Path | None) -> list:
    """pip's package source: the configured registry, or only the folder DIR (no network)."""
    return [] if wheels is None else ['--no-index', '--find-links', str(wheels)]


def uv_version(uv_lock: Path = UV_LOCK) -> str:
    """The version of uv that UV_LOCK pins."""
    found = re.search(r'^uv==(\S+)', uv_lock.read_text(), re.M)
    if found is None:
        raise SetupError('reading the uv pin', uv_lock, f'no line uv==VERSION in {uv_lock}; expected one')
    return found.group(1)


def ensure_uv(log: Path, wheels: Path | None = None, home: Path = UV_HOME, uv_lock: Path = UV_LOCK) -> Path:
    """uv as UV_LOCK pins it, in its own venv HOME: installed with pip (--require-hashes, no resolution) when
    HOME does not hold that version yet. Returns the uv executable."""
    uv = home / 'bin' / 'uv'
    version = uv_version(uv_lock)
    if uv.exists() and list((home / 'lib').glob(f'python*/site-packages/uv-{version}.dist-info')):
        return uv
    log.parent.mkdir(parents=True, exist_ok=True)
    python = home / 'bin' / 'python'
    if not python.exists():
        _run('python -m venv (for uv)', [sys.executable, '-m', 'venv', home], log)
    _run('pip install uv', [python, '-m', 'pip', 'install', '--no-deps', '--require-hashes', '--no-input',
                            *source_args(wheels), '-r', uv_lock], log, env=_pip_env())
    return uv


def _uv_env() -> dict:
    """uv with this machine's configuration (its index, cache, certificates), as pip had it; no progress bars."""
    return dict(os.environ, UV_NO_PROGRESS='1', _ROS_WHEELS_BOOTSTRAP_COMPLETE='1')


def install_lock(python: Path, lock: Path, log: Path, wheels: Path | None = None, uv: Path | None = None) -> None:
    """Install exactly what LOCK pins into PYTHON's environment: no resolution, every hash checked (uv; UV: its
    executable, else ensure_uv's)."""
    if wheels is not None and not wheels.is_dir():
        raise SetupError('uv pip install', log, f'FT_WHEELS={wheels} is not a folder (make one with ./ft wheels DIR)')
    uv = ensure_uv(log, wheels) if uv is None else uv
    offline = [] if wheels is None else ['--offline', *source_args(wheels)]
    # --compile-bytecode: where PYTHONDONTWRITEBYTECODE is set (this machine's default) no command would ever write
    # a .pyc, and every start would compile numpy, scipy and the rest from source: `./ft bag correct`'s imports
    # 0.22 s instead of 0.11 s; compiling them here costs about 9 s of the set-up, once
    _run('uv pip install', [uv, 'pip', 'install', '--python', python, '--no-deps', '--require-hashes', *offline,
                            '--compile-bytecode', '-r', lock], log, env=_uv_env())
    _run('uv pip check', [uv, 'pip', 'check', '--python', python], log, env=_uv_env())


def setup_venv(venv: Path, lock: Path, log: Path, wheels: Path | None = None, mend: Path | None = None) -> None:
    """Make VENV (if needed), install LOCK into it, and mend the ROS wheels' CMake files."""
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text('')
    python = venv / 'bin' / 'python'
    uv = ensure_uv(log, wheels)
    if not python.exists():   # uv's venv: no bundled pip to unpack (10 s here); the lock has what the venv needs
        _run('uv venv', [uv, 'venv', '--python', sys.executable, venv], log, env=_uv_env())
    install_lock(python, lock, log, wheels, uv=uv)
    if mend is not None:
        _run('mending the ROS wheels', [python, mend], log, env=_pip_env())


def package_states(src: Path) -> dict:
    """{package: the names and modification times of its files} for each package under SRC (a folder with a
    package.xml): what says a package changed, as ./ft's stamp says src/ did (times, not contents)."""
    states = {}
    for xml in sorted(src.glob('*/package.xml')):
        folder = xml.parent
        h = hashlib.sha256()
        for path in sorted(folder.rglob('*')):
            if path.is_file() and '__pycache__' not in path.parts:
                h.update(f'{path.relative_to(src)} {path.stat().st_mtime_ns}\n'.encode())
        states[folder.name] = h.hexdigest()
    return states


def changed_packages(states: dict, built: dict, install: Path) -> list:
    """The packages to build: those whose files changed since BUILT (the states of the last build) or that
    install/ lacks. colcon's --packages-above adds what depends on them."""
    return [name for name, state in states.items()
            if built.get(name) != state or not (install / name).is_dir()]


def build(log: Path, root: Path = ROOT) -> list:
    """colcon-build the packages of src/ that changed (and those above them) into install/ (./ft has set the ROS
    environment), then byte-compile them and ./ft's own tools: with PYTHONDONTWRITEBYTECODE set, as on some
    machines, every command would otherwise compile its modules from source at each start (a quarter of a second
    here). Returns the packages built (none when only files outside the packages changed)."""
    log.write_text('')
    stamp = root / '.ft' / 'build.packages.json'
    states = package_states(root / 'src')
    try:
        built = json.loads(stamp.read_text())
    except (OSError, ValueError):
        built = {}
    todo = changed_packages(states, built, root / 'install')
    if todo:
        _run('colcon build', ['colcon', '--log-base', root / 'log', 'build', '--base-paths', 'src',
                              '--build-base', root / 'build', '--install-base', root / 'install',
                              '--event-handlers', 'console_direct-', '--packages-above', *todo], log, cwd=root)
        _run('byte-compiling', [sys.executable, '-m', 'compileall', '-q', root / 'install', root / 'tools'], log)
    stamp.parent.mkdir(parents=True, exist_ok=True)
    stamp.write_text(json.dumps(states, indent=1) + '\n')
    return todo


def npm_install(folder: Path, log: Path, wheels: Path | None = None) -> None:
    """`npm ci` from the folder's package-lock.json; offline from `./ft wheels`' npm cache when given one."""
    if shutil.which('npm') is None:
        raise SetupError('npm ci', log, f'no npm on PATH; {folder.name} needs Node.js 20 and npm')
    log.write_text('')
    offline = [] if wheels is None else ['--offline', '--cache', str(wheels / NPM_CACHE)]
    _run('npm ci', ['npm', 'ci', '--no-audit', '--no-fund', *offline], log, cwd=folder)


def install_chromium(log: Path) -> str:
    """Install Debian's Chromium with apt-get (as root, or through sudo without a password): the pinned
    version, or the archive's newest when the pin is gone. Returns what was installed."""
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text('')
    if shutil.which('apt-get') is None:
        raise SetupError('apt-get install', log, 'no apt-get: install Chromium with the system\'s package manager')
    sudo = [] if os.geteuid() == 0 else ['sudo', '-n']
    if sudo and shutil.which('sudo') is None:
        raise SetupError('apt-get install', log, 'not root and no sudo: run `apt-get install chromium` as root')
    env = dict(os.environ, DEBIAN_FRONTEND='noninteractive')
    apt = [*sudo, 'apt-get', '-y', '-q', '--no-install-recommends']
    _run('apt-get update', [*sudo, 'apt-get', '-q', 'update'], log, env=env)
    policy = subprocess.run(['apt-cache', 'madison', CHROMIUM], capture_output=True, text=True).stdout
    why = 'the archive no longer has'
    if f'| {CHROMIUM_VERSION} |' in policy:
        try:
            _run('apt-get install', [*apt, 'install', *(f'{p}={CHROMIUM_VERSION}' for p in CHROMIUM_PACKAGES)],
                 log, env=env)
            return f'{CHROMIUM} {CHROMIUM_VERSION}'
        except SetupError:   # the pinned set no longer installs together: the newest, said so (the log has why)
            why = 'apt-get could not install'
    _run('apt-get install', [*apt, 'install', CHROMIUM], log, env=env)
    return f'{CHROMIUM} ({why} the pinned {CHROMIUM_VERSION}: the newest instead; bump the pin)'


def download(lock: Path, into: Path, log: Path, npm_folders: tuple = ()) -> int:
    """Fill INTO with uv's wheel and every file the lock pins (hashes checked), the sdists' build tools, and the npm
    tarballs of each folder of NPM_FOLDERS (one npm cache holds them all)."""
    into.mkdir(parents=True, exist_ok=True)
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text('')
    python = ensure_uv(log).parent / 'python'   # uv's venv has pip (the workspace's .venv, made by uv, has none)
    for pinned in (UV_LOCK, lock):   # uv first: an offline machine installs it from INTO before the lock
        _run('pip download', [python, '-m', 'pip', 'download', '--no-deps', '--require-hashes', '--no-input',
                              '-d', into, '-r', pinned], log, env=_pip_env())
    tools = [t for t in SDIST_BUILD_TOOLS if f'\n{t}==' not in '\n' + lock.read_text()]   # the lock's own if pinned
    if tools and any(p.name.endswith(('.tar.gz', '.zip')) for p in into.iterdir()):
        _run('pip download', [python, '-m', 'pip', 'download', '--no-input', '--only-binary', ':all:',
                              '-d', into, *tools], log, env=_pip_env())
    for npm_folder in npm_folders if shutil.which('npm') else ():
        # npm ci into a scratch copy fills the cache folder with every tarball of package-lock.json
        scratch = into / '.npm-scratch'
        shutil.rmtree(scratch, ignore_errors=True)
        scratch.mkdir()
        for name in ('package.json', 'package-lock.json'):
            shutil.copy2(npm_folder / name, scratch / name)
        _run('npm ci', ['npm', 'ci', '--no-audit', '--no-fund', '--ignore-scripts', '--cache', into / NPM_CACHE],
             log, cwd=scratch)
        shutil.rmtree(scratch)
    return sum(1 for p in into.iterdir() if p.is_file())


def main(argv: list | None = None) -> int:
    p = argparse.ArgumentParser(prog='python -m ft_cli.bootstrap', description=__doc__.split('\n\n')[0])
    sub = p.add_subparsers(dest='step', required=True)
    v = sub.add_parser('venv', help='make the venv and install the lock into it')
    v.add_argument('--venv', type=Path, required=True)
    v.add_argument('--lock', type=Path, required=True)
    v.add_argument('--log', type=Path, required=True)
    v.add_argument('--wheels', type=Path, help='install from this folder only (no network)')
    v.add_argument('--mend', type=Path, help="the script that mends the ROS wheels' CMake files")
    b = sub.add_parser('build', help='colcon-build src/ into install/')
    b.add_argument('--log', type=Path, required=True)
    n = sub.add_parser('npm', help='npm ci in a folder with a package-lock.json')
    n.add_argument('folder', type=Path)
    n.add_argument('--log', type=Path, required=True)
    n.add_argument('--wheels', type=Path)
    c = sub.add_parser('chromium', help="install Debian's Chromium (pinned) for the viewer's browser test")
    c.add_argument('--log', type=Path, required=True)
    args = p.parse_args(argv)
    try:
        if args.step == 'venv':
            setup_venv(args.venv, args.lock, args.log, args.wheels, args.mend)
        elif args.step == 'build':
            build(args.log)
        elif args.step == 'chromium':
            print(f'ft: installed {install_chromium(args.log)}', file=sys.stderr)
        else:
            npm_install(args.folder, args.log, args.wheels)
    except SetupError as e:
        print(f'ft: error: {e}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
