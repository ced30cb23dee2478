"""Benchmark: fuzzing every reader of bag_tools (./ft bench fuzz [--inputs N] [--formats a,b] [--cli K]).

The inputs of tests/bag_tools/fuzz.py (valid seeds of CSV, TDMS, LVM, MDF4, UFF, a channel map, campaign.yaml, a
bag's metadata.yaml and MCAP, mutated; input i a pure function of format, --seed and i), N a format (default
10^4), fed to the real reader functions in a worker process this script kills when an input takes over --limit
seconds (a hang; the worker starts again after it). Then K inputs a format (default 20) through the real
`./ft bag import ... --dry-run` / `./ft bag info` in a subprocess: exit 0, or exit 2 with one line on stderr, no
traceback, no 'internal error', no hang. Prints per format: inputs, clean errors (a BagError of one line),
accepted, tracebacks (any other exception), stderr noise (a library's lines beside the error), hangs, the slowest
input's seconds; the first example of each defect; then the CLI pass. Exit code 1 when any defect was found.
"""
from __future__ import annotations

import argparse
import multiprocessing
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'bag_tools'), str(ROOT / 'tests')]

import fuzz  # noqa: E402 - the test suite's harness: one set of seeds and mutations for both


def worker(root: str, fmt: str, seed: int, start: int, stop: int, send) -> None:
    """Feed inputs start..stop-1 of fmt, sending (i, outcome, detail, seconds) after each."""
    readers = fuzz.Readers(Path(root))
    data = (Path(root) / 'seeds' / fmt).read_bytes()
    for i in range(start, stop):
        t = time.perf_counter()
        outcome, detail = readers.feed(fmt, fuzz.mutate(fmt, data, seed, i))
        send.send((i, outcome, detail, time.perf_counter() - t))
    readers.path(fmt).write_bytes(data)
    send.close()


def fuzz_format(root: Path, fmt: str, n: int, seed: int, limit: float) -> dict:
    ctx = multiprocessing.get_context('fork')
    res = {'inputs': n, 'clean': 0, 'accepted': 0, 'traceback': 0, 'noise': 0, 'hang': 0, 'slowest': 0.0,
           'examples': {}}
    i = 0
    while i < n:
        receive, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=worker, args=(str(root), fmt, seed, i, n, send), daemon=True)
        proc.start()
        send.close()
        while i < n:
            if not receive.poll(limit):
                proc.kill()
                res['hang'] += 1
                res['slowest'] = max(res['slowest'], limit)
                res['examples'].setdefault('hang', (i, f'over {limit:g} s'))
                i += 1
                break
            try:
                k, outcome, detail, secs = receive.recv()
            except EOFError:           # the worker died (a crash in C code): that input is a defect
                res['traceback'] += 1
                res['examples'].setdefault('crash', (i, f'worker exit code {proc.exitcode}'))
                i += 1
                break
            res[outcome] += 1
            res['slowest'] = max(res['slowest'], secs)
            if outcome in ('traceback', 'noise'):
                res['examples'].setdefault(detail.split(':')[0][:60], (k, detail))
            i = k + 1
        proc.join(1)
        if proc.is_alive():
            proc.kill()
        receive.close()
    (root / fmt / fuzz.TARGET[fmt]).write_bytes((root / 'seeds' / fmt).read_bytes())
    return res


def cli_pass(root: Path, fmt: str, k: int, seed: int) -> tuple:
    """(inputs, ok, [(i, verdict)]) of k inputs through ./ft bag."""
    data = (root / 'seeds' / fmt).read_bytes()
    bad, ok = [], 0
    for j in range(k):
        i = 1_000_000 + j                    # inputs apart from the in-process ones
        (root / fmt / fuzz.TARGET[fmt]).write_bytes(fuzz.mutate(fmt, data, seed, i))
        try:
            r = subprocess.run([str(ROOT / 'ft'), 'bag', *fuzz.cli_command(fmt, root)], capture_output=True,
                               text=True, timeout=120, cwd=ROOT)
            verdict = fuzz.cli_verdict(r.returncode, r.stderr)
        except subprocess.TimeoutExpired:
            verdict = 'hang'
        if verdict == 'ok':
            ok += 1
        else:
            bad.append((i, verdict))
    (root / fmt / fuzz.TARGET[fmt]).write_bytes(data)
    return k, ok, bad


def main() -> int:
    ap = argparse.ArgumentParser(prog='./ft bench fuzz', description=__doc__.split('\n\n')[0])
    ap.add_argument('--inputs', type=int, default=10_000, help='inputs a format, in-process (default 10000)')
    ap.add_argument('--cli', type=int, default=20, help='inputs a format through ./ft bag (default 20)')
    ap.add_argument('--formats', default=','.join(fuzz.FORMATS), help=f'default: {",".join(fuzz.FORMATS)}')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--limit', type=float, default=10.0, help='seconds an input may take (default 10)')
    args = ap.parse_args()
    formats = [f.strip() for f in args.formats.split(',') if f.strip()]
    bad = [f for f in formats if f not in fuzz.FORMATS]
    if bad or args.inputs < 1 or args.cli < 0 or args.limit <= 0:
        print(f'./ft bench fuzz: error: format {bad[0]!r} is unknown; expected some of {", ".join(fuzz.FORMATS)}'
              if bad else './ft bench fuzz: error: expected --inputs >= 1, --cli >= 0, --limit > 0',
              file=sys.stderr)
        return 2
    import asammdf  # noqa: F401 - imported once, before the workers fork (2 s each otherwise)
    import lvm_read  # noqa: F401
    import nptdms  # noqa: F401
    import pyuff  # noqa: F401

    import bag_tools.core.info  # noqa: F401
    with tempfile.TemporaryDirectory(prefix='ft_fuzz_') as tmp:
        root = Path(tmp)
        seeds = fuzz.seed_files(root)
        fuzz.keep_seed_lvm(root)
        (root / 'seeds').mkdir()
        for f, data in seeds.items():
            (root / 'seeds' / f).write_bytes(data)
        print(f'fuzz: {args.inputs} inputs a format in-process (limit {args.limit:g} s each), seed {args.seed}; '
              f'{args.cli} a format through ./ft bag')
        head = f'{"format":<12}{"inputs":>8}{"clean":>8}{"accepted":>10}{"tracebacks":>12}{"noise":>7}{"hangs":>7}' \
               f'{"slowest s":>11}{"wall s":>8}'
        print(head)
        print('-' * len(head))
        results, total_bad = {}, 0
        for fmt in formats:
            t0 = time.perf_counter()
            r = fuzz_format(root, fmt, args.inputs, args.seed, args.limit)
            results[fmt] = r
            total_bad += r['traceback'] + r['noise'] + r['hang']
            print(f'{fmt:<12}{r["inputs"]:>8}{r["clean"]:>8}{r["accepted"]:>10}{r["traceback"]:>12}{r["noise"]:>7}'
                  f'{r["hang"]:>7}{r["slowest"]:>11.3f}{time.perf_counter() - t0:>8.0f}', flush=True)
        for fmt, r in results.items():
            for _key, (i, detail) in r['examples'].items():
                print(f'  {fmt} input {i}: {detail}')
        if args.cli:
            print('\nthrough ./ft bag (exit 0, or 2 with one line; no traceback, no hang):')
            for fmt in formats:
                k, ok, bad = cli_pass(root, fmt, args.cli, args.seed)
                total_bad += len(bad)
                print(f'  {fmt:<12} {ok}/{k} ok' + (f'; first: input {bad[0][0]}: {bad[0][1]}' if bad else ''),
                      flush=True)
    print(f'\ndefects: {total_bad}')
    return 1 if total_bad else 0


if __name__ == '__main__':
    sys.exit(main())
