"""Every `./ft ...` command line in README.md and docs/ names a real command, and every option it
uses is one that command's --help lists (so an example cannot rot when an option is renamed)."""
from __future__ import annotations

import re
import subprocess
from functools import lru_cache

import pytest

from ft_cli.commands import NAMES
from ft_cli.paths import INSTALL, ROOT

DOCS = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md')),
        *sorted((ROOT / 'src').glob('*/README.md')), *sorted((ROOT / 'src').glob('*/*.md'))]
# `./ft` then words up to the end of a code span, a line, a pipe, a redirection or a comment
LINE = re.compile(r'(?:^|[\s`(])(?:[A-Z_]+=\S+ )*\./ft((?: [^`|>#;\n)]*)?)')
SUBCOMMANDS = {'bag', 'bench'}   # commands whose first argument names a tool of its own


def command_lines() -> list:
    found = {}
    for doc in dict.fromkeys(DOCS):
        for n, text in enumerate(doc.read_text().splitlines(), 1):
            for m in LINE.finditer(text):
                words = []
                for word in m.group(1).split():   # up to the first placeholder (CMD, <cmd>, PKG)
                    word = word.rstrip(':,.')
                    if '<' in word or '...' in word or (word.isupper() and len(word) > 1):
                        break
                    words.append(word)
                if words and words[0] in NAMES or not words:
                    found.setdefault(' '.join(words), f'{doc.relative_to(ROOT)}:{n}')
    return sorted(found.items())


@lru_cache(maxsize=None)
def help_text(*words: str) -> str:
    res = subprocess.run([str(ROOT / 'ft'), *words, '--help'], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, f'./ft {" ".join(words)} --help: rc {res.returncode}: {res.stderr[-500:]}'
    # a help text, not the command's work (bench_sim ran its whole benchmark on --help: 20 s)
    assert res.stdout.startswith('usage: '), f'./ft {" ".join(words)} --help: {res.stdout[:300]!r}'
    return res.stdout


def test_the_docs_have_command_lines():
    assert len(command_lines()) > 30


@pytest.mark.parametrize('line, where', command_lines(), ids=[w for _, w in command_lines()])
def test_a_documented_command_line_parses(line, where):
    words = line.split()
    if not words:
        help_text()
        return
    command, rest = words[0], words[1:]
    if command == 'run':    # ./ft run PACKAGE EXECUTABLE: the node must exist after the build
        if len(rest) < 2:
            help_text('run')
            return
        package, executable = rest[:2]
        assert (INSTALL / package / 'lib' / package / executable).is_file(), f'{where}: no {package}/{executable}'
        return
    head = (command, rest[0]) if command in SUBCOMMANDS and rest and not rest[0].startswith('-') else (command,)
    text = help_text(*head)
    for option in (w.split('=')[0] for w in rest if w.startswith('--')):
        if command == 'test':
            continue    # pytest's own options
        assert re.search(rf'{re.escape(option)}\b', text), \
            f'{where}: {option} is not an option of ./ft {" ".join(head)}'
