"""./ft lock: requirements.lock, every package ./ft installs pinned to one version with its hashes.

requirements.txt says what the workspace needs; requirements.lock (made by `uv pip compile
--generate-hashes` for CPython 3.11 on x86_64 Linux) says exactly what gets installed, and ./ft
installs with `uv pip install --no-deps --require-hashes` from it (the same uv, pinned in
requirements-uv.lock), so a new release somewhere cannot change a fresh
machine. The lock's first line records the SHA-256 of the requirements.txt it was made from;
`./ft lock --check` (and a test) fail when they differ, a requirement is not pinned or a pin has
no hashes, or when the closure is incomplete: a locked package requires something the lock does
not pin, or pins at a version the requirement excludes (read from the installed packages'
metadata, extras followed). ./ft installs with --no-deps, so such a gap would otherwise show only
as an ImportError. `./ft lock` keeps the versions already pinned where requirements.txt still allows them
(uv prefers the pins of the file it writes); `./ft lock --upgrade` takes the newest of everything.
"""
from __future__ import annotations

import hashlib
import importlib.metadata
import re
import subprocess
import sys
from pathlib import Path

from ..paths import ROOT

REQUIREMENTS = ROOT / 'requirements.txt'
LOCK = ROOT / 'requirements.lock'
STAMP = '# made from requirements.txt sha256 '
PLATFORM = ('--python-version', '3.11', '--python-platform', 'x86_64-unknown-linux-gnu')


def _name(spec: str) -> str:
    """The normalised project name of a requirement line (PEP 503)."""
    return re.sub(r'[-_.]+', '-', re.split(r'[\s<>=!~;\[@]', spec.strip(), maxsplit=1)[0]).lower()


def requirement_names(text: str) -> list:
    """The names requirements.txt asks for; comments, blank lines and options (-r, --index-url) are skipped."""
    return [_name(line) for line in text.splitlines() if line.strip() and line.lstrip()[0] not in '#-']


def pins(lock_text: str) -> dict:
    """{normalised name: version} of every pin in a lock."""
    return {_name(n): v for n, v in re.findall(r'^([A-Za-z0-9][A-Za-z0-9._-]*)==(\S+)', lock_text, re.M)}


def installed_requires(name: str):
    """The Requires-Dist lines of the installed package NAME, or None when it is not installed."""
    try:
        return importlib.metadata.requires(name) or []
    except importlib.metadata.PackageNotFoundError:
        return None


def closure_problems(lock_text: str, requires=installed_requires) -> list:
    """What the lock's packages require that the lock does not pin, or pins at an excluded version.
    Extras are followed: a requirement `coverage[toml]` needs what coverage's `toml` extra needs."""
    from packaging.requirements import Requirement
    pinned = pins(lock_text)
    extras = {name: {''} for name in pinned}
    problems, unread = set(), []
    todo = list(pinned)
    while todo:
        name = todo.pop()
        lines = requires(name)
        if lines is None:
            unread.append(name)
            continue
        for line in lines:
            req = Requirement(line)
            if req.marker and not any(req.marker.evaluate({'extra': e}) for e in extras[name]):
                continue
            dep = _name(req.name)
            if dep not in pinned:
                problems.add(f'{dep} (required by {name}) is not pinned')
                continue
            if not req.specifier.contains(pinned[dep], prereleases=True):
                problems.add(f'{dep}=={pinned[dep]} does not satisfy {name}\'s {line!r}')
            wanted = {_name(e) for e in req.extras} - extras[dep]
            if wanted:
                extras[dep] |= wanted
                todo.append(dep)
    if unread:
        problems.add(f'cannot read the requirements of {len(unread)} locked packages (not installed here: '
                     f'{", ".join(sorted(unread)[:3])}...); check in the workspace venv')
    return sorted(problems)


def lock_problems(requirements: Path = REQUIREMENTS, lock: Path = LOCK, requires=installed_requires) -> list:
    """Why the lock does not match the requirements (empty when it does), most telling first."""
    if not lock.is_file():
        return [f'{lock.name} is missing']
    req_text, lock_text = requirements.read_text(), lock.read_text()
    problems = []
    missing = [n for n in requirement_names(req_text) if n not in pins(lock_text)]
    if missing:
        problems.append(f'not pinned in {lock.name}: {", ".join(missing)}')
    digest = hashlib.sha256(requirements.read_bytes()).hexdigest()
    if not lock_text.startswith(STAMP + digest):
        problems.append(f'{lock.name} was not made from this {requirements.name} (its SHA-256 {digest[:12]}... '
                        'is not the one the lock records)')
    if re.search(r'^\S+==\S+$', lock_text, re.M):   # a pin line ends in ' \' when hashes follow
        problems.append(f'{lock.name} has a pin without hashes')
    closure = closure_problems(lock_text, requires)
    if closure:
        problems.append(f'{lock.name} is not a complete closure: {"; ".join(closure)}')
    return problems


def _uv() -> str:
    """The uv that installs the lock (requirements-uv.lock, in .ft/uv), so that one uv compiles and installs."""
    from ..bootstrap import SetupError, ensure_uv
    try:
        return str(ensure_uv(ROOT / '.ft' / 'uv.log'))
    except SetupError as exc:
        print(f'ft lock: error: {exc}', file=sys.stderr)
        return ''


def add_arguments(p):
    p.description = ('Write requirements.lock: every package requirements.txt pulls in, at one version with its '
                     'hashes, for CPython 3.11 on x86_64 Linux (uv pip compile; uv, as requirements-uv.lock pins '
                     'it, is installed into .ft/uv on first use). Versions already pinned are kept where '
                     'requirements.txt allows them.')
    p.add_argument('--check', action='store_true',
                   help='only check: exit 1 with one line if the lock does not match requirements.txt')
    p.add_argument('--upgrade', action='store_true', help='take the newest allowed version of every package')


def run(args) -> int:
    if args.check:
        problems = lock_problems()
        if problems:
            print(f'ft lock: error: {"; ".join(problems)}; run ./ft lock', file=sys.stderr)
            return 1
        print(f'ft lock: {LOCK.name} matches {REQUIREMENTS.name}')
        return 0
    keep = LOCK.is_file() and not args.upgrade
    print(f'ft lock: resolving {REQUIREMENTS.name} for CPython 3.11 on x86_64 Linux (uv pip compile'
          f'{", keeping the current pins" if keep else ", newest versions"})', file=sys.stderr)
    uv = _uv()
    if not uv:
        return 1
    out = LOCK.with_suffix('.lock.tmp')
    # uv prefers the versions pinned in the file it writes over; seeded without hashes, it takes those
    # afresh from PyPI instead of copying them from the old lock
    pins = re.findall(r'^\S+==\S+', LOCK.read_text(), re.M) if keep else []
    out.write_text(''.join(f'{pin}\n' for pin in pins))
    res = subprocess.run([uv, 'pip', 'compile', '--quiet', '--generate-hashes', '--no-header', *PLATFORM,
                          str(REQUIREMENTS), '-o', str(out)], cwd=ROOT)
    if res.returncode:
        out.unlink(missing_ok=True)
        print('ft lock: error: uv could not resolve requirements.txt (see above)', file=sys.stderr)
        return 1
    digest = hashlib.sha256(REQUIREMENTS.read_bytes()).hexdigest()
    body = out.read_text()
    out.unlink()
    Path(LOCK).write_text(f'{STAMP}{digest}\n# by ./ft lock (uv pip compile --generate-hashes); '
                          'do not edit: change requirements.txt and run ./ft lock\n' + body)
    print(f'ft lock: wrote {LOCK.name} ({body.count("==")} pinned packages)', file=sys.stderr)
    return 0
