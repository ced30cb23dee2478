"""The docs hold together. Every `./ft ...` command line in README.md and docs/ names a real command, and every
option it uses is one that command's --help lists (so an example cannot rot when an option is renamed). The map
(docs/README.md) lists every page and every link between the pages resolves, anchors included; pages have
headings and stay under about 15 KB; the README comes in its order and shows the demo's table as the demo prints
it; the CLI reference is what tools/cli_reference.py writes; docs/tests-files*.md name every test file; the
references of the rig YAML and the channel map, and the catalog page, name every key, cause and band the code
defines."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from functools import lru_cache

import cli_reference
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
        if doc.name.startswith('reference-cli'):
            continue    # the --help texts themselves (usage lines): test_the_cli_reference_is_current
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
                         timeout=120, env=dict(os.environ, COLUMNS=cli_reference.COLUMNS))
    assert res.returncode == 0, f'./ft {" ".join(words)} --help: rc {res.returncode}: {res.stderr[-500:]}'
    # a help text, not the command's work (bench_sim ran its whole benchmark on --help: 20 s)
    assert res.stdout.startswith('usage: '), f'./ft {" ".join(words)} --help: {res.stdout[:300]!r}'
    return res.stdout


def test_the_docs_have_command_lines():
    assert len(command_lines()) > 30


# one worker runs them all (one xdist group), so each command's `./ft ... --help` runs once per run (help_text's cache
# is a process's), not once on each worker: 46 commands for 162 lines
@pytest.mark.xdist_group('documented_command_lines')
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


# ----------------------------------------------------------------------------- the map and the pages
PAGES = sorted(p for p in (ROOT / 'docs').glob('*.md') if p.name != 'README.md')
MAP = ROOT / 'docs' / 'README.md'
MAX_PAGE_BYTES = 16_000      # "about 15 KB"
# pages over it, each with why it stays for now; the test fails once one is under it, so the entry goes too
OVERSIZE = {'reliability.md': 'other engineers edit it now; split along its sections (## ...) after'}
LINK = re.compile(r'\[[^\]]*\]\(([^)\s]+)\)')


def anchors(path) -> set:
    """GitHub's anchors of a page's headings (the same slug rule as the CLI reference's)."""
    text = re.sub(r'```.*?```', '', path.read_text(), flags=re.S)
    return {cli_reference.anchor(m.group(1).strip()) for m in re.finditer(r'^#+ (.+)$', text, re.M)}


def test_the_map_lists_every_page():
    linked = {m.group(1).split('#')[0] for m in LINK.finditer(MAP.read_text())}
    missing = [p.name for p in PAGES if p.name not in linked]
    assert not missing, f'docs/README.md does not list {missing}'


@pytest.mark.parametrize('doc', DOCS, ids=[str(d.relative_to(ROOT)) for d in DOCS])
def test_every_link_resolves(doc):
    """A relative link names a file that exists, and its #anchor a heading of that page."""
    bad = []
    for m in LINK.finditer(re.sub(r'```.*?```', '', doc.read_text(), flags=re.S)):
        target = m.group(1)
        if re.match(r'[a-z]+:', target):
            continue                      # https:, mailto:
        path, _, frag = target.partition('#')
        dest = (doc.parent / path).resolve() if path else doc
        if not dest.exists():
            bad.append(f'{target}: no such file')
        elif frag and dest.suffix == '.md' and frag not in anchors(dest):
            bad.append(f'{target}: no heading #{frag}')
    assert not bad, f'{doc.relative_to(ROOT)}: ' + '; '.join(bad)


def test_every_page_has_headings():
    """A title first; a page of more than a screen has sections."""
    bad = [p.name for p in [MAP, *PAGES] if not p.read_text().startswith('# ')
           or len(p.read_bytes()) > 3000 and not re.search(r'^## ', p.read_text(), re.M)]
    assert not bad, f'no title, or no ## sections on a long page: {bad}'


def test_no_page_is_over_about_15_kb():
    sizes = {p.name: len(p.read_bytes()) for p in [MAP, *PAGES]}
    over = {n: s for n, s in sizes.items() if s > MAX_PAGE_BYTES and n not in OVERSIZE}
    assert not over, f'split these pages along their topics: {over}'
    fixed = [n for n in OVERSIZE if sizes.get(n, 0) <= MAX_PAGE_BYTES]
    assert not fixed, f'{fixed} are no longer over {MAX_PAGE_BYTES} bytes: take them out of OVERSIZE'


def test_tests_files_md_describes_every_test_file():
    """docs/tests-files.md's two pages name every tests/**/test_*.py (by its name, `test_x`)."""
    table = ''.join(p.read_text() for p in sorted((ROOT / 'docs').glob('tests-files*.md')))
    named = set(re.findall(r'`(?:[\w/]+/)?(test_\w+)`', table))
    files = sorted((ROOT / 'tests').rglob('test_*.py'))
    assert len(files) > 50
    missing = [str(f.relative_to(ROOT)) for f in files if f.stem not in named]
    assert not missing, f'docs/tests-files*.md do not describe {missing}'


# ----------------------------------------------------------------------------- the README
README = ROOT / 'README.md'


def test_the_readme_comes_in_its_order():
    """What the workspace is (with one picture), the two commands (the first within 20 lines), what the demo
    prints, your own data, the map of the docs."""
    lines = README.read_text().splitlines()
    first = next(n for n, line in enumerate(lines, 1) if line.startswith('./ft '))
    assert first <= 20, f'the first command is on line {first}'
    assert any(line.startswith('![') for line in lines[:first]), 'no picture before the commands'
    sections = [line[3:] for line in lines if line.startswith('## ')]
    order = ['Two commands', 'What the demo prints', "Your own rig's data", 'The docs']
    assert [s for s in sections if s in order] == order, sections
    assert 'docs/README.md' in '\n'.join(lines[lines.index('## The docs'):])


def readme_demo_table() -> list:
    text = README.read_text()
    block = text[text.index('## What the demo prints'):]
    block = block[block.index('```') + 4:]
    return block[:block.index('```')].splitlines()


def test_the_readme_demo_table_is_laid_out_as_the_demo_prints_it():
    """The README's table, read back into scores and printed by the demo's own format_table, comes out as it
    stands: the same columns in the same order and widths (the README leaves out the last, U ext, which drifts)."""
    from force_tester_common.core.units import LBF_N
    from ft_cli.commands.demo import format_table
    shown = readme_demo_table()
    rows = [line.split() for line in shown if re.match(r'\s+\d+\s+\d+\s', line)]
    assert [int(r[0]) for r in rows] == [1, 2, 3, 4, 5]
    scores = []
    for r in rows:
        s, pulls, stat, raw, mas, ma, ext, d_raw, d_mas, d_ma, d_ext, u = (float(x) for x in r)
        for _ in range(int(pulls)):
            scores.append({'test_set': int(s), 'stationary_peak_n': stat * LBF_N, 'raw_peak_n': raw * LBF_N,
                           'corrected_peak_n': mas * LBF_N, 'filtered_peak_n': ma * LBF_N,
                           'raw_diff_pct': d_raw, 'corrected_diff_pct': d_mas, 'filtered_diff_pct': d_ma,
                           'corrected_peak_u_n': u * LBF_N, 'dropped_blocks': 0,
                           'extension': {'corrected_peak_n': ext * LBF_N, 'corrected_diff_pct': d_ext,
                                         'corrected_peak_u_n': float('nan')}})
    printed = format_table(scores).splitlines()
    u_ext = len(printed[0]) - len(printed[0].rstrip('U ext').rstrip())
    cut = [line[:-u_ext] if n < 8 else line for n, line in enumerate(printed)]
    cut[2] = '-' * len(cut[0])
    assert shown[:len(cut)] == cut


# ----------------------------------------------------------------------------- the CLI reference
@pytest.mark.slow
def test_the_cli_reference_is_current():
    """docs/reference-cli*.md are what `python3 tools/cli_reference.py` writes from today's --help texts, each a
    help text (it starts with its usage line), not the command's work. The texts are taken in one interpreter
    (`--here`: the benchmarks' imports once, not one `./ft` per command); `./ft WORDS --help` itself is run for
    every command line the docs show (test_a_documented_command_line_parses)."""
    res = subprocess.run([sys.executable, str(ROOT / 'tools' / 'cli_reference.py'), '--here', '--json'],
                         cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env=dict(os.environ, COLUMNS=cli_reference.COLUMNS))
    assert res.returncode == 0, res.stderr[-2000:]
    pages = json.loads(res.stdout)
    assert {'reference-cli.md', 'reference-cli-bag.md', 'reference-cli-bench.md'} <= set(pages)
    assert len(pages['reference-cli.md'].split('```')) > 2 * len(NAMES)
    block = re.compile(r'^## (\./ft[^\n]*)\n\n```\n(.*?)```', re.M | re.S)
    sections = [m for page in pages.values() for m in block.finditer(page)]
    assert len(sections) > 40
    for m in sections:
        assert m.group(2).startswith('usage: '), (m.group(1), m.group(2)[:300])
    stale = cli_reference.stale(pages)
    assert not stale, f'not current: {stale}; run python3 tools/cli_reference.py'


# ----------------------------------------------------------------------------- references that name every key
def keys_of(data) -> set:
    """Every mapping key in a parsed YAML, at any depth (list items included)."""
    if isinstance(data, dict):
        return {k for k in data} | {k for v in data.values() for k in keys_of(v)}
    if isinstance(data, list):
        return {k for v in data for k in keys_of(v)}
    return set()


def named_in(page: str) -> set:
    """What a page names in code spans."""
    text = (ROOT / 'docs' / page).read_text()
    blocks = re.findall(r'```.*?```', text, flags=re.S)
    spans = re.findall(r'`([^`]+)`', re.sub(r'```.*?```', '', text, flags=re.S))
    return {w for span in [*blocks, *spans] for w in re.split(r'[\s,:{}\[\]`]+', span) if w}


def test_the_rig_yaml_reference_names_every_key():
    import yaml

    from force_tester_sim.core import extra_terms
    from force_tester_sim.core.departures import CATALOG, OPTIONAL_PARAMS
    from force_tester_sim.core.params import NOMINAL_YAML, TRUTH_YAML
    keys = keys_of(yaml.safe_load(NOMINAL_YAML.read_text())) | keys_of(yaml.safe_load(TRUTH_YAML.read_text()))
    keys |= set(CATALOG) | {p for spec in CATALOG.values() for p in spec[1]}
    keys |= {p for spec in OPTIONAL_PARAMS.values() for p in spec}
    keys |= set(extra_terms.KEYS) | set(extra_terms.CHANNELS) | set(extra_terms.SIGNALS)
    missing = sorted(keys - named_in('reference-rig-yaml.md') - {'name'})   # `name:` is the list form's key
    assert not missing, f'docs/reference-rig-yaml.md does not name {missing}'


def test_the_catalog_page_names_every_cause_and_band():
    import dataclasses

    from force_tester_sim.core.departures import CATALOG
    from force_tester_sim.core.params import load_rig
    want = set(CATALOG) | {p for spec in CATALOG.values() for p in spec[1]}
    want |= {f.name for f in dataclasses.fields(load_rig().tolerances)}
    missing = sorted(want - named_in('discovery-catalog.md'))
    assert not missing, f'docs/discovery-catalog.md does not name {missing}'


def test_the_channel_map_reference_names_every_key_and_channel():
    import yaml

    from bag_tools.core.channel_map import MAP_KEYS
    from force_tester_common.core.channels import CHANNELS
    example = yaml.safe_load((ROOT / 'config' / 'channel_maps' / 'drop_impactor.yaml').read_text())
    want = set(MAP_KEYS) | set(CHANNELS) | set(example) | keys_of(example['channels'])
    missing = sorted(want - named_in('reference-channel-map.md'))
    assert not missing, f'docs/reference-channel-map.md does not name {missing}'


def test_the_report_json_reference_names_every_key():
    from force_discovery.core.report import CANDIDATE_KEYS, NOT_AVAILABLE, REPORT_KEYS
    want = set(REPORT_KEYS) | set(CANDIDATE_KEYS) | {NOT_AVAILABLE}
    missing = sorted(want - named_in('reference-report-json.md'))
    assert not missing, f'docs/reference-report-json.md does not name {missing}'


def test_the_rig_yaml_reference_states_the_nominal_values():
    """Each `| `key` | value |` row of a section's table in docs/reference-rig-yaml.md holds nominal.yaml's value."""
    import yaml

    from force_tester_sim.core.params import NOMINAL_YAML
    nominal = yaml.safe_load(NOMINAL_YAML.read_text())
    text = (ROOT / 'docs' / 'reference-rig-yaml.md').read_text()
    checked, wrong = 0, []
    for section in ('daq', 'drive', 'force_chain', 'sensors', 'tolerances'):
        part = text[text.index(f'## `{section}:`'):]
        part = part[:part.index('\n## ', 1)]
        for keys, values in re.findall(r'^\| ((?:`\w+`(?:, )?)+) \| ([^|]+) \|', part, re.M):
            for key, value in zip(re.findall(r'`(\w+)`', keys), re.split(r',\s*(?![^\[]*\])', values.strip())):
                checked += 1
                if yaml.safe_load(value) != nominal[section][key]:
                    wrong.append(f'{section}.{key}: {value} (nominal.yaml: {nominal[section][key]})')
    assert not wrong, wrong
    assert checked == sum(len(nominal[s]) for s in ('daq', 'drive', 'force_chain', 'sensors', 'tolerances'))
