"""Fuzzing every reader of bag_tools (issue 40): valid seed files of each format, mutated, fed to the real reader
functions. Used by tests/bag_tools/test_fuzz.py (a few hundred inputs a format) and benchmarks/bench_fuzz.py
(10^4 a format, each in a worker process it can kill at the time limit).

Formats (FORMATS): the DAQ files a user imports (campaign CSV, NI TDMS, LabVIEW LVM, ASAM MDF4, UFF 58: read,
mapped and checked as `./ft bag import FILE` does), a channel map (loaded and applied to a record), a campaign
folder's campaign.yaml (read_campaign), and a bag's metadata.yaml and MCAP file (bag_info, what `./ft bag info`
reads: every block and pull event message). Input i of a format is a pure function of (format, seed, i): one to
three mutations of the valid seed, byte-level (bits flipped, bytes set to edge values, slices cut, repeated or
inserted, the file truncated), on text formats token- and line-level too (a number made nan, -0, 1e308 or a
word; lines dropped or repeated), and on the YAML formats structural (a value anywhere replaced by None, a list,
a huge number, a long string, a key dropped or added) before dumping.

Outcome of an input: 'accepted' (the reader returned), 'clean' (a BagError of one line: what a user should
see), 'traceback' (any other exception: a reader defect). The benchmark adds 'hang' (over the time limit).
"""
from __future__ import annotations

import os
import random
import sys
import tempfile
import zlib
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))
from daq_data import (  # noqa: E402
    IMPACTOR_CHANNEL_MAP,
    SRC_DIRS,
    synth,
    write_lvm,
    write_mf4,
    write_uff,
)

for _d in reversed(SRC_DIRS):
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))

from bag_tools.core.errors import BagError  # noqa: E402

FORMATS = ('csv', 'tdms', 'lvm', 'mf4', 'uff', 'channel_map', 'campaign', 'metadata', 'mcap')
#: The file each format's input is written to, inside that format's scratch folder.
TARGET = {'csv': 'pull.csv', 'tdms': 'pull.tdms', 'lvm': 'rec.lvm', 'mf4': 'rec.mf4', 'uff': 'rec.uff',
          'channel_map': 'map.yaml', 'campaign': 'lab/campaign.yaml', 'metadata': 'bag/metadata.yaml',
          'mcap': 'bag/bag_0.mcap'}
TEXT = {'csv', 'lvm', 'uff', 'channel_map', 'campaign', 'metadata'}
YAML = {'channel_map', 'campaign', 'metadata'}
RATE = 25_000.0
N = 200            # samples per seed record: small, so an input is read in milliseconds

EDGE_BYTES = (0x00, 0xff, 0x7f, 0x80, 0x01, 0xfe, 0x20, 0x0a, 0x0d, 0x09, 0x2c, 0x2d, 0x2e, 0x3a, 0x30, 0x39, 0x65)
TOKENS = ('', '0', '-0', '-1', '1e308', '-1e308', '1e-320', 'nan', 'NaN', 'inf', '-inf', '2147483648',
          '99999999999999999999999', 'x', 'Volts', ',', '\t', '"', "'", ':', '- ', '{', '[', '\x00', 'é', '1,5',
          '\n', '0x10', '1_000', '+', '.', 'e')
VALUES = (None, '', 0, -1, 1, 1e308, float('nan'), float('inf'), True, 'x', [], {}, [1, 2], {'a': 1}, 'a' * 500,
          2 ** 64, -2 ** 63, '50 g', 'V', '0 mV/N', '1e9 mV/V/N', 'absent', '../x', '/etc/hostname', 'rec1.lvm',
          [None], {'source': 'Accel'}, 'G', 'Newtons', '5 furlong')


def seed_files(root: Path) -> dict:
    """Write each format's valid seed (and what it needs beside it) under root; {format: seed bytes}."""
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    from bag_tools.core.convert import campaign_to_bag
    from bag_tools.core.daq import write_campaign
    root.mkdir(parents=True, exist_ok=True)
    for f in FORMATS:
        (root / f / TARGET[f]).parent.mkdir(parents=True, exist_ok=True)
    ch = synth(n=N, seed=1, optional=False)
    volts = {'Load cell': ch['force_moving_n'] * 0.225e-3, 'Accel': ch['accel_axial_m_s2'] / 9.80665 * 1.023e-3}
    seeds = {}
    from bag_tools.core.daq import write_csv
    write_csv(root / 'csv' / TARGET['csv'], ch)
    with TdmsWriter(str(root / 'tdms' / TARGET['tdms'])) as w:
        w.write_segment([RootObject(), GroupObject('data')] + [
            ChannelObject('data', c, v, properties={'wf_increment': 1 / RATE, 'unit_string': 'N'})
            for c, v in ch.items() if c != 'time_s'])
    write_lvm(root / 'lvm' / TARGET['lvm'], volts, RATE)
    write_mf4(root / 'mf4' / TARGET['mf4'], volts, RATE)
    write_uff(root / 'uff' / TARGET['uff'], volts, RATE)
    cmap = yaml.safe_load(yaml.safe_dump(IMPACTOR_CHANNEL_MAP))
    cmap['channels']['accel_axial_m_s2']['range'] = '500 g'
    cmap['sample_rate_hz'] = RATE
    (root / 'channel_map' / TARGET['channel_map']).write_text(yaml.safe_dump(cmap, sort_keys=False))
    lab = root / 'campaign' / 'lab'
    (lab / 'channels.yaml').write_text(yaml.safe_dump(IMPACTOR_CHANNEL_MAP))
    for i in range(2):
        write_lvm(lab / f'rec{i + 1}.lvm', volts, RATE)
    (lab / 'campaign.yaml').write_text(yaml.safe_dump({
        'sample_rate_hz': RATE, 'channels': 'channels.yaml', 'absent': ['force_stationary_n'],
        'pulls': [{'file': 'rec1.lvm', 'set': 1, 'coupon_lbf': 200.0, 'velocity_fps': 3.0, 'decel_g': 0.0,
                   'start_ns': 10 ** 18, 'pull_id': 1}, {'file': 'rec2.lvm'}]}, sort_keys=False))
    camp = write_campaign(root / 'camp_src', [({'set': 1, 'coupon_lbf': 200.0, 'velocity_fps': 3.0,
                                                'decel_g': 0.0}, synth(n=N, seed=2))])
    bag = campaign_to_bag(camp, root / 'bag_src', block_size=50)
    mcaps = sorted(bag.glob('*.mcap'))
    for f in ('metadata', 'mcap'):
        dest = root / f / 'bag'
        (dest / 'metadata.yaml').write_bytes((bag / 'metadata.yaml').read_bytes())
        for m in mcaps:
            (dest / m.name).write_bytes(m.read_bytes())
    TARGET['mcap'] = f'bag/{mcaps[0].name}'
    for f in FORMATS:
        seeds[f] = (root / f / TARGET[f]).read_bytes()
    return seeds


# --------------------------------------------------------------------------- mutation
def _bytes_mutation(rng: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    if not b:
        return bytes(rng.choice(EDGE_BYTES) for _ in range(rng.randint(1, 8)))
    op = rng.randrange(7)
    i = rng.randrange(len(b))
    if op == 0:                                    # bits flipped
        for _ in range(rng.randint(1, 4)):
            k = rng.randrange(len(b))
            b[k] ^= 1 << rng.randrange(8)
    elif op == 1:                                  # bytes set to edge values
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.choice(EDGE_BYTES)
    elif op == 2:                                  # a slice cut
        del b[i:i + rng.randint(1, 64)]
    elif op == 3:                                  # a slice repeated
        j = rng.randint(i, min(len(b), i + 256))
        b[i:i] = b[i:j] * rng.randint(1, 3)
    elif op == 4:                                  # random bytes inserted
        b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
    elif op == 5:                                  # truncated
        del b[i:]
    else:                                          # a 4- or 8-byte field set to an edge integer
        width = rng.choice((4, 8))
        v = rng.choice((0, 1, 2 ** (8 * width - 1) - 1, 2 ** (8 * width) - 1, 2 ** 31, 2 ** 20))
        b[i:i + width] = v.to_bytes(width, 'little')
    return bytes(b)


def _text_mutation(rng: random.Random, data: bytes) -> bytes:
    text = data.decode('utf-8', 'replace')
    lines = text.split('\n')
    op = rng.randrange(4)
    k = rng.randrange(len(lines))
    if op == 0:                                    # a token (a field between separators) replaced
        parts = [p for p in _split_keep(lines[k])]
        idx = [j for j, p in enumerate(parts) if p not in ('\t', ',', ' ', ':')]
        if idx:
            parts[rng.choice(idx)] = rng.choice(TOKENS)
        lines[k] = ''.join(parts)
    elif op == 1:
        del lines[k]
    elif op == 2:
        lines.insert(k, lines[rng.randrange(len(lines))] if rng.random() < 0.7 else rng.choice(TOKENS))
    else:
        j = rng.randrange(len(lines))
        lines[k], lines[j] = lines[j], lines[k]
    return '\n'.join(lines).encode('utf-8', 'surrogatepass')


def _split_keep(line: str) -> list:
    out, cur = [], ''
    for c in line:
        if c in '\t, :':
            if cur:
                out.append(cur)
            out.append(c)
            cur = ''
        else:
            cur += c
    if cur:
        out.append(cur)
    return out


def _yaml_mutation(rng: random.Random, data: bytes) -> bytes:
    try:
        doc = yaml.safe_load(data.decode('utf-8'))
    except Exception:   # noqa: BLE001 - an earlier mutation broke it: mutate bytes instead
        return _bytes_mutation(rng, data)
    holder = {'root': doc}
    nodes = [(holder, 'root')]
    stack = [doc]
    while stack:
        x = stack.pop()
        items = list(x.items()) if isinstance(x, dict) else list(enumerate(x)) if isinstance(x, list) else []
        for key, v in items:
            nodes.append((x, key))
            stack.append(v)
    parent, key = rng.choice(nodes)
    op = rng.randrange(3)
    if op == 0 or parent is holder:
        parent[key] = rng.choice(VALUES)
    elif op == 1:
        if isinstance(parent, dict):
            del parent[key]
        else:
            parent.pop(key)
    else:
        if isinstance(parent, dict):
            parent[rng.choice(('x', 'channels', 'pulls', 'files', 'absent', 'unit', 'range', 'sign'))] = \
                rng.choice(VALUES)
        else:
            parent.append(rng.choice(VALUES))
    try:
        return yaml.safe_dump(holder['root'], sort_keys=False, allow_unicode=True).encode('utf-8')
    except Exception:   # noqa: BLE001
        return _bytes_mutation(rng, data)


def mutate(fmt: str, seed_bytes: bytes, seed: int, i: int) -> bytes:
    """Input i of a format: 1-3 mutations of its seed (a pure function of its arguments)."""
    rng = random.Random(zlib.crc32(f'{fmt}/{seed}/{i}'.encode()))
    data = seed_bytes
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        r = rng.random()
        if fmt in YAML and r < 0.5:
            data = _yaml_mutation(rng, data)
        elif fmt in TEXT and r < 0.75:
            data = _text_mutation(rng, data)
        else:
            data = _bytes_mutation(rng, data)
    return data


# --------------------------------------------------------------------------- the readers
class Readers:
    """The real reader functions on the files of one scratch root (seed_files wrote it)."""

    def __init__(self, root: Path) -> None:
        from bag_tools.core.channel_map import load_channel_map
        from bag_tools.core.daqfiles import read_records
        self.root = Path(root)
        self.cmap = load_channel_map(IMPACTOR_CHANNEL_MAP)
        self.record = read_records(self.root / 'lvm' / TARGET['lvm'])[0]

    def path(self, fmt: str) -> Path:
        return self.root / fmt / TARGET[fmt]

    def run(self, fmt: str) -> None:
        """Read the file of ``fmt`` as its command does; raises what the reader raises."""
        from bag_tools.core.channel_map import apply_map, load_channel_map
        from bag_tools.core.daq import check_channels, read_campaign
        from bag_tools.core.daqfiles import read_records
        from bag_tools.core.info import bag_info
        p = self.path(fmt)
        if fmt in ('csv', 'tdms', 'lvm', 'mf4', 'uff'):
            cmap = self.cmap if fmt in ('lvm', 'mf4', 'uff') else None
            for rec in read_records(p):
                raw, absent, _used = apply_map(rec, cmap, str(p))
                check_channels(raw, str(p), None, [], absent)
        elif fmt == 'channel_map':
            raw, absent, _used = apply_map(self.record, load_channel_map(p), 'rec.lvm')
            check_channels(raw, 'rec.lvm', None, [], absent)
        elif fmt == 'campaign':
            read_campaign(p.parent)
        else:
            bag_info(p.parent)

    def feed(self, fmt: str, data: bytes) -> tuple:
        """(outcome, detail) of one input: 'accepted', ('clean', message), ('traceback', type: message) or
        ('noise', the first line written to stderr: a library's log line or warning, which a CLI would print beside
        its one line; the file descriptor itself is watched, so a forked child's output counts)."""
        self.path(fmt).write_bytes(data)
        outcome = 'accepted', ''
        sys.stderr.flush()
        saved = os.dup(2)
        with tempfile.TemporaryFile() as err:
            os.dup2(err.fileno(), 2)
            try:
                self.run(fmt)
            except BagError as exc:
                msg = str(exc)
                outcome = ('traceback', f'BagError not one line: {msg!r}') if '\n' in msg or not msg.strip() \
                    else ('clean', msg)
            except Exception as exc:  # noqa: BLE001 - what the fuzzing looks for
                outcome = 'traceback', f'{type(exc).__name__}: {" ".join(str(exc).split())[:300]}'
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                os.close(saved)
            err.seek(0)
            noise = err.read(2000).decode('utf-8', 'replace').strip()
        if noise and outcome[0] != 'traceback':
            return 'noise', noise.splitlines()[0][:300]
        return outcome


def cli_command(fmt: str, root: Path) -> list:
    """The ./ft bag arguments that read the input of ``fmt`` (written where Readers.path puts it)."""
    p = Path(root) / fmt / TARGET[fmt]
    if fmt in ('csv', 'tdms'):
        return ['import', str(p), '--dry-run'] + (['--rate', str(RATE)] if fmt == 'tdms' else [])
    if fmt in ('lvm', 'mf4', 'uff'):
        return ['import', str(p), '--channels', str(Path(root) / 'campaign' / 'lab' / 'channels.yaml'), '--dry-run']
    if fmt == 'channel_map':
        return ['import', str(Path(root) / 'lvm' / 'seed.lvm'), '--channels', str(p), '--dry-run']
    if fmt == 'campaign':
        return ['import', str(p.parent), '--dry-run']
    return ['info', str(p.parent)]


def cli_verdict(returncode: int | None, stderr: str) -> str:
    """'ok' when ./ft bag ended as a CLI must (0, or 2 with one line and no traceback); else what went wrong."""
    if returncode is None:
        return 'hang'
    if 'Traceback' in stderr or 'internal error' in stderr:
        return 'traceback'
    if returncode == 0:
        return 'ok'
    if returncode == 2 and stderr.count('\n') == 1 and stderr.startswith('./ft bag'):
        return 'ok'
    return f'exit {returncode}: {stderr.strip()[:200]!r}'


def keep_seed_lvm(root: Path) -> None:
    """A pristine LVM beside the fuzzed one, for the channel map's CLI pass."""
    (Path(root) / 'lvm' / 'seed.lvm').write_bytes((Path(root) / 'lvm' / TARGET['lvm']).read_bytes())


__all__ = ['FORMATS', 'Readers', 'cli_command', 'cli_verdict', 'keep_seed_lvm', 'mutate', 'seed_files']
