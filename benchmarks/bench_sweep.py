"""Benchmark: the search beyond the catalog swept over the whole grammar, on physics we did not write (the
independent generator, tests/independent/rig.py): the detection matrix per (channel, term) pair.

    ./ft bench sweep [--pairs CH[:TERM],...] [--strengths 1,3,10] [--signs +,-] [--rigs nominal,heavier,25khz]
                     [--clean N] [--pulls N] [--clean-pulls LO-HI] [--seed S]

The pairs are the grammar's, read through its public functions (force_discovery.core.beyond.grammar: pairs,
channel_band), so a change to the grammar changes the sweep: every product term on every searched channel, those the
grammar keeps off a channel (a catalog form, a signal its free phases cannot use) too, which the report must list as
unidentifiable (the `listed` flag below); not the sinusoids, which need a line's frequency. For each rig (nominal:
the rig the generator draws for the seed, sampled at 20 kHz; heavier: the same with m2 1.6 kg and an 80 kg carriage;
25khz: the nominal at 25 kHz) one clean campaign of --pulls pulls on sets 2-4 is made with its clean signals kept
(F_move, F_stat, T, a2, v, x on the sample times: the generator's own, before any sensor). Each cell of the sweep
adds one term to one recorded channel of that campaign: coefficient x the term's value from the clean signals where
the DAQ samples the channel, behind its anti-alias filter's delay, and on the channel's ADC steps again (the term
acts before the DAQ: as_recorded). The coefficient is chosen so that the term's rms over the pulls' loaded windows
(50 ms before the lanyard goes taut to 150 ms after the break) is the strength x the channel's band (channel_band:
the smallest contribution the tolerances care about), with the sign asked for. On the force and accelerometer
channels that is a sensor-side term, as the grammar means it. On the motor current it is added to the recorded
current too, not made a force on the carriage: the generator takes no free-form body force, so the motion does not
answer it (a real drag would slow the carriage a little as well). `discover` (scheduler inline) is given the
injected campaign and the rig's datasheet, never the truth.

Each cell is one of: the right term first on the right channel (and of those: the coefficient within 30 %, the
95 % interval holding the truth), a tie (a term named that the report says the true pair cannot be told from: the
pair the grammar reads it as, beyond_search.identifiability's read_as, or a member of a named term's near-tie group
there, near_tie; or the catalog cause the grammar reads a linear force as, read_as_cause: counted apart, never as
right), a catalog cause named instead (the term not found), another term
named, nothing named, or an error; in_band counts the cells whose true term was significant but inside the band
(listed under beyond_search.within_tolerance, not named), listed those whose pair the report lists as one the
campaign cannot identify (beyond_search.identifiability, with its reason: issue 39's section 1), and the right share
is given of the cells not listed too. Then --clean campaigns with nothing injected, of 4-30 pulls (drawn per
seed; --clean-pulls), on the rigs in turn: a false alarm is any entry in beyond_catalog; the catalog causes named
on them are listed too (on this generator the catalog's own figures are another benchmark's: ./ft bench discovery
--generator independent).
The whole sweep (every pair, 3 strengths, 2 signs, 3 rigs, >= 20 clean campaigns) is thousands of discover runs:
run a subset with the options. Progress goes to stderr, the matrix to stdout.
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import independent_cases as IG  # beside this script: the independent generator's campaigns
import numpy as np

from force_discovery.core.beyond.grammar import SEARCHED, channel_band, pairs
from force_discovery.core.errors import DiscoveryError
from force_discovery.core.pipeline import discover
from force_tester_sim.core.extra_terms import CHANNEL_COLUMNS, SIN, parse_term, term_values

RATE = {'daq.sample_rate_hz': 20e3}
RIGS = {'nominal': RATE,
        'heavier': {**RATE, 'force_chain.moving_side_mass_kg': 1.6, 'drive.carriage_mass_kg': 80.0},
        '25khz': {'daq.sample_rate_hz': 25e3}}
STRENGTHS = (1.0, 3.0, 10.0)
SIGNS = {'+': 1.0, '-': -1.0}
BEFORE_S, AFTER_S = 0.05, 0.15        # the loaded window the strength is measured on (about discover's own)
COEF_SHARE = 0.3
OUTCOMES = ('right', 'coef30', 'ci95', 'tie', 'catalog', 'other', 'nothing', 'error', 'in_band', 'listed')
FLAGS = ('coef30', 'ci95', 'in_band', 'listed')   # beside the one outcome a cell has


def all_pairs() -> list:
    """Every (channel, product term) pair of the grammar, in its search order (the sinusoids left out)."""
    return [(c, t) for c, t in pairs() if SIN not in parse_term(t)]


def chosen_pairs(spec: str | None) -> list:
    """The pairs --pairs names (CH for every term of a channel, CH:TERM for one); ValueError quoting a bad one."""
    pairs = all_pairs()
    if not spec:
        return pairs
    out = []
    for item in (s.strip() for s in spec.split(',') if s.strip()):
        ch, _, term = item.partition(':')
        got = [p for p in pairs if p[0] == ch and (not term or p[1] == term)]
        if not got:
            raise ValueError(f'--pairs {item!r}; expected CH or CH:TERM of the grammar: channels {", ".join(SEARCHED)}')
        out += [p for p in got if p not in out]
    return out


def pull_signals(entry: dict, t: np.ndarray) -> dict:
    """The grammar's signals of one pull from the generator's clean signals (t from the record's start)."""
    sig = {k: np.asarray(v, float) for k, v in entry['signals'].items()}
    sig['t'] = np.asarray(t, float) - float(t[0])
    return sig


def as_recorded(base: IG.Case, channel: str, term: str, entry: dict, t: np.ndarray) -> np.ndarray:
    """The term's values in one pull's record of the channel: the term from the clean signals on the sample times,
    through the channel's anti-alias filter (the truth's daq: its kind, order and corner, discretised as the
    generator discretises it), at the instants the DAQ samples the channel (the pull's clock rate error, the
    channel's skew). A term acts before the DAQ, so the record carries it as it carries the channel's own signal, and
    the library's signals are the recorded ones. Put on the nominal sample times unfiltered, a term ran ahead of its
    channel by the filter's group delay (69 us on the nominal rig): an F_move*v of 3x the band on the moving cell was
    named T*v (T, made from the stationary cell through its dynamics, leads the recorded forces); filtered, F_move*v."""
    v = term_values(term, pull_signals(entry, t))
    daq = base.truth.get('daq', {})
    f = daq.get('filter')
    if f:
        dt = float(t[1] - t[0])
        v = IG.R.run_sos(IG.R.foh_sos(*IG.R.aa_design(f['type'], int(f['order']), f['fc_hz']), dt), v)
    delta = daq.get('clock_offset_pull', {}).get(entry.get('file'), 0.0)
    skew = daq.get('channels', {}).get(CHANNEL_COLUMNS[channel], {}).get('skew_s', 0.0)
    return np.interp(t / (1.0 + delta) + skew, t, v)


def loaded(entry: dict, t: np.ndarray) -> np.ndarray:
    return (t >= entry['t_taut_s'] - BEFORE_S) & (t <= entry['t_break_s'] + AFTER_S)


def coefficient(base: IG.Case, channel: str, term: str, strength: float, sign: float) -> float | None:
    """The coefficient whose contribution's rms over the loaded windows is strength x the channel's band (None
    when the term is zero there)."""
    sq, n = 0.0, 0
    for (_meta, ch), entry in zip(base.campaign, base.truth['pulls']):
        t = np.asarray(ch['time_s'], float)
        v = as_recorded(base, channel, term, entry, t)[loaded(entry, t)]
        sq, n = sq + float(np.sum(v * v)), n + len(v)
    rms = math.sqrt(sq / max(n, 1))
    if not rms > 0 or not math.isfinite(rms):
        return None
    return sign * strength * channel_band(channel, base.rig) / rms


def inject(base: IG.Case, channel: str, term: str, coef: float) -> list:
    """The campaign with coef x term added to the channel's record, as the DAQ records it (as_recorded) and on the
    channel's ADC steps again (the term acts before the DAQ: a recorded channel plus a smooth term would be a
    quantised channel off its grid, whose one-step flickers the quality screen rightly takes for spikes). New arrays;
    the base is not changed."""
    col = CHANNEL_COLUMNS[channel]
    lsb = base.truth.get('daq', {}).get('channels', {}).get(col, {}).get('lsb_si')
    out = []
    for (meta, ch), entry in zip(base.campaign, base.truth['pulls']):
        t = np.asarray(ch['time_s'], float)
        y = np.asarray(ch[col], float) + coef * as_recorded(base, channel, term, entry, t)
        out.append((meta, {**ch, col: np.round(y / lsb) * lsb if lsb else y}))
    return out


def named_catalog(report: dict) -> list:
    return [c['name'] for c in report.get('causes', []) if c['name'] not in ('unexplained', 'beyond_catalog')]


def beyond_terms(report: dict) -> list:
    found = report.get('beyond_catalog')
    return found if isinstance(found, list) else []


def outcome(report: dict, channel: str, term: str, coef: float) -> dict:
    """The cell's outcome: {outcome: bool} over OUTCOMES: one of right, catalog, other, nothing (error: run_cell),
    with the FLAGS: coef30 and ci95 of a right term; in_band, the true term listed as significant but inside the
    channel's band (beyond_search.within_tolerance), so not named; listed, the true pair listed as one this campaign
    cannot identify (beyond_search.identifiability, with its reason)."""
    terms = beyond_terms(report)
    mine = [b for b in terms if b['channel'] == channel]
    right = bool(mine) and mine[0]['term'] == term
    got = dict.fromkeys(OUTCOMES, False)
    if right:
        got['right'] = True
        got['coef30'] = abs(mine[0]['coefficient'] - coef) <= COEF_SHARE * abs(coef)
        got['ci95'] = min(mine[0]['ci95']) <= coef <= max(mine[0]['ci95'])
    elif tied(report, channel, term):
        got['tie'] = True
    elif named_catalog(report):
        got['catalog'] = True
    else:
        got['other' if terms else 'nothing'] = True
    search = report.get('beyond_search')
    band = search.get('within_tolerance', []) if isinstance(search, dict) else []
    got['in_band'] = any(b['channel'] == channel and b['term'] == term for b in band)
    got['listed'] = any(b['channel'] == channel and b['term'] == term for b in unidentifiable(report))
    return got


def tied(report: dict, channel: str, term: str) -> bool:
    """Whether a named term is one the report says the true pair cannot be told from: the pair the true one is read
    as (its identifiability entry's read_as: the grammar's), or a member of a named term's near-tie group (the
    entries with near_tie: the data's), the true pair among them; or a named catalog cause the true pair is read as
    (read_as_cause: a linear force is the moving cell's gain). Not right: its own column."""
    named = {f'{b["channel"]}:{b["term"]}' for b in beyond_terms(report)}
    truth = f'{channel}:{term}'
    entries = unidentifiable(report)
    mine = [e for e in entries if e['channel'] == channel and e['term'] == term]
    read = {e['read_as'] for e in mine if e.get('read_as')}
    causes = {e['read_as_cause'] for e in mine if e.get('read_as_cause')}
    groups = {m for e in entries if e.get('near_tie') and e['near_tie'][0] in named for m in e['near_tie'][1:]}
    return bool(named & read) or truth in groups or bool(read & groups) or bool(causes & set(named_catalog(report)))


def unidentifiable(report: dict) -> list:
    """beyond_search.identifiability: the pairs the campaign cannot identify, {channel, term, reason}."""
    search = report.get('beyond_search')
    return list(search.get('identifiability', [])) if isinstance(search, dict) else []


def run_cell(base: IG.Case, channel: str, term: str, strength: float, sign: float, out: Path) -> tuple:
    """(outcome dict, what was named) of one cell of the sweep."""
    coef = coefficient(base, channel, term, strength, sign)
    if coef is None:
        return {**dict.fromkeys(OUTCOMES, False), 'error': True}, 'the term is zero on the loaded windows'
    try:
        report = discover(inject(base, channel, term, coef), base.rig, out, scheduler='inline', plots=False)
    except DiscoveryError as exc:
        return {**dict.fromkeys(OUTCOMES, False), 'error': True}, str(exc)
    named = [f'{b["channel"]}:{b["term"]}' for b in beyond_terms(report)] + named_catalog(report)
    return outcome(report, channel, term, coef), f'true {coef:.4g}; named {named or "nothing"}'


def what_is_named(case: IG.Case, out: Path) -> str:
    """What discover names on a campaign as it is: its beyond-catalog terms and catalog causes."""
    try:
        report = discover(case.campaign, case.rig, out, scheduler='inline', plots=False)
    except DiscoveryError as exc:
        return f'error {exc}'
    terms = [f'{b["channel"]}:{b["term"]}' for b in beyond_terms(report)]
    return f'beyond {terms or "nothing"}, catalog {named_catalog(report) or "nothing"}'


def base_case(rig: str, seed: int, pulls: int) -> IG.Case:
    return IG.case(seed, [], pulls=pulls, overrides=RIGS[rig], keep_signals=True)


def parse_list(value: str, allowed, what: str) -> list:
    items = [v.strip() for v in value.split(',') if v.strip()]
    bad = [v for v in items if v not in allowed]
    if bad or not items:
        raise ValueError(f'--{what} {value!r}; expected some of {",".join(map(str, allowed))}, comma-separated')
    return items


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--pairs', default=None, help='CH or CH:TERM, comma-separated (default every pair of the '
                                                  f'grammar: {len(all_pairs())} on {", ".join(SEARCHED)})')
    ap.add_argument('--strengths', default='1,3,10', help='multiples of the channel\'s band (default 1,3,10)')
    ap.add_argument('--signs', default='+,-', help='the coefficient\'s signs (default +,-)')
    ap.add_argument('--rigs', default=','.join(RIGS), help=f'some of {",".join(RIGS)} (default all)')
    ap.add_argument('--clean', type=int, default=20, help='campaigns with nothing injected (default 20)')
    ap.add_argument('--pulls', type=int, default=IG.PULLS, help=f'pulls of the injected campaigns (default {IG.PULLS})')
    ap.add_argument('--clean-pulls', default='4-30', help='LO-HI: the clean campaigns\' pulls, drawn per seed '
                                                          '(default 4-30)')
    ap.add_argument('--seed', type=int, default=3900, help='the rigs\' seed (default 3900); clean: seed+500+k')
    a = ap.parse_args(argv)
    try:
        a.pairs = chosen_pairs(a.pairs)
        given = a.strengths
        a.strengths = [float(s) for s in given.split(',') if _positive(s)]
        if not a.strengths or len(a.strengths) != len(given.split(',')):
            raise ValueError(f'--strengths {given!r}; expected positive numbers, comma-separated (e.g. 1,3,10)')
        a.signs = parse_list(a.signs, list(SIGNS), 'signs')
        a.rigs = parse_list(a.rigs, list(RIGS), 'rigs')
        lo, _, hi = a.clean_pulls.partition('-')
        if not (lo.isdigit() and hi.isdigit() and 4 <= int(lo) <= int(hi)):
            raise ValueError(f'--clean-pulls {a.clean_pulls!r}; expected LO-HI with 4 <= LO <= HI')
        a.clean_pulls = (int(lo), int(hi))
        if a.clean < 0 or a.pulls < 4:
            raise ValueError(f'--clean {a.clean} / --pulls {a.pulls}; expected --clean >= 0 and --pulls >= 4')
    except ValueError as exc:
        ap.exit(2, f'bench_sweep: error: {exc}\n')
    return a


def _positive(s: str) -> bool:
    try:
        return float(s) > 0 and math.isfinite(float(s))
    except ValueError:
        return False


def clean_pulls(seed: int, lo: int, hi: int) -> int:
    return int(np.random.default_rng([seed, 39]).integers(lo, hi + 1))


def main(argv=None) -> int:
    a = parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix='bench_sweep_'))
    cells = [(r, p, s, g) for r in a.rigs for p in a.pairs for s in a.strengths for g in a.signs]
    print(f'bench_sweep: {len(cells)} cells ({len(a.pairs)} pairs x {len(a.strengths)} strengths x {len(a.signs)} '
          f'signs x {len(a.rigs)} rigs) and {a.clean} clean campaigns, independent generator, seed {a.seed}',
          file=sys.stderr, flush=True)
    counts: dict = {}
    t_all = time.perf_counter()
    bases, said_of_base = {}, []
    for k, (rig, (channel, term), strength, sign) in enumerate(cells):
        if rig not in bases:
            bases[rig] = base_case(rig, a.seed, a.pulls)
            said_of_base.append(f'{rig} (seed {bases[rig].seed}, {a.pulls} pulls): ' +
                                what_is_named(bases[rig], tmp / f'base_{rig}'))
            print(f'[base] {said_of_base[-1]}', file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        got, said = run_cell(bases[rig], channel, term, strength, SIGNS[sign], tmp / f'cell{k}')
        row = counts.setdefault((channel, term, strength), dict.fromkeys(('n', *OUTCOMES, 'right_listed'), 0))
        row['n'] += 1
        row['right_listed'] += bool(got['right'] and got['listed'])
        for key, hit in got.items():
            row[key] += bool(hit)
        what = next((o for o in OUTCOMES if got[o] and o not in FLAGS), '?') + (' (in band)' if got['in_band'] else '')
        print(f'[{k + 1}/{len(cells)}] {rig} {channel} {term} x{strength:g}{sign}: {what} ({said}; '
              f'{time.perf_counter() - t0:.0f} s)', file=sys.stderr, flush=True)
    false, catalog_clean = 0, []
    for k in range(a.clean):
        seed = a.seed + 500 + k
        rig = a.rigs[k % len(a.rigs)]
        n = clean_pulls(seed, *a.clean_pulls)
        c = IG.case(seed, [], pulls=n, overrides=RIGS[rig])
        try:
            report = discover(c.campaign, c.rig, tmp / f'clean{k}', scheduler='inline', plots=False)
        except DiscoveryError as exc:
            print(f'[clean {k + 1}/{a.clean}] seed {seed}: error {exc}', file=sys.stderr, flush=True)
            continue
        terms = [f'{b["channel"]}:{b["term"]}' for b in beyond_terms(report)]
        false += bool(terms)
        catalog_clean += named_catalog(report)
        print(f'[clean {k + 1}/{a.clean}] {rig} seed {c.seed}, {n} pulls: beyond {terms or "nothing"}, catalog '
              f'{named_catalog(report) or "nothing"}', file=sys.stderr, flush=True)
    print_matrix(counts, a.strengths)
    if said_of_base:
        print('\nthe base campaigns, nothing injected (what every cell starts from): ' + '; '.join(said_of_base))
    if a.clean:
        print(f'\nclean campaigns ({a.clean_pulls[0]}-{a.clean_pulls[1]} pulls): false alarms {false}/{a.clean}; '
              f'catalog causes named on them: {sorted(set(catalog_clean)) or "none"}')
    print(f'\n{len(cells)} cells and {a.clean} clean campaigns in {time.perf_counter() - t_all:.0f} s (inline)')
    return 0


def print_matrix(counts: dict, strengths) -> None:
    head = f'{"channel":<17} {"term":<14} {"x band":>6} {"n":>3} ' + ' '.join(f'{o:>7}' for o in OUTCOMES)
    print(head)
    print('-' * len(head))
    for (channel, term, strength), row in counts.items():
        print(f'{channel:<17} {term:<14} {strength:>6g} {row["n"]:>3} ' + ' '.join(f'{row[o]:>7}' for o in OUTCOMES))
    print()
    for s in strengths:
        rows = [r for (_c, _t, x), r in counts.items() if x == s]
        n = sum(r['n'] for r in rows)
        if n:
            print(f'at {s:g}x band, {n} cells: ' + ', '.join(f'{o} {sum(r[o] for r in rows)} '
                                                              f'({100 * sum(r[o] for r in rows) / n:.0f} %)'
                                                              for o in OUTCOMES))
            tie = sum(r['tie'] for r in rows)
            print(f'  right {sum(r["right"] for r in rows)} and a tie the report lists {tie}: '
                  f'{100 * (sum(r["right"] for r in rows) + tie) / n:.0f} % together')
            listed = sum(r['listed'] for r in rows)
            right = sum(r['right'] - r['right_listed'] for r in rows)
            print(f'  of the {n - listed} cells whose pair the report does not list as unidentifiable: '
                  f'right {right} ({100 * right / max(n - listed, 1):.0f} %)')


if __name__ == '__main__':
    sys.exit(main())
