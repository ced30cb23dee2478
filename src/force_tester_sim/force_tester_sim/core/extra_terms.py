"""Terms beyond the departures catalog: the grammar `./ft discover` searches, and the rig YAML's
``extra_terms:`` section that adds such terms to the sim's channels. The one home of the grammar.

A term is added to one channel (CHANNELS) and is either a product of SIGNALS with integer powers up to MAX_POWER,
written in the SIGNALS order, joined by ``*``, with ``^k`` for k > 1 (``F_move^2``, ``v^2``, ``t``, ``F_move*v``),
or a sinusoid ``sin`` at ``frequency_hz``, optionally times signals (``v*sin``). The signals: F_move, the moving
cell's force (the clean one); F_stat; T, the lanyard tension; a2; v and x, the carriage velocity and position; t,
the time from the record's start, s. The coefficient is in the channel's SI unit per the term's. A sinusoid's phase
is each pull's own (seeded in the sim, as the hum's; fitted per pull when discover re-simulates a measured pull);
its coefficient is the amplitude.

    extra_terms:
      - {channel: motor_current, term: v^2, coefficient: 0.05}
      - {channel: force_moving, term: v*sin, coefficient: 6.2, frequency_hz: 1258.2}
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np

from .errors import SimError

CHANNELS = ('force_moving', 'force_stationary', 'accel_axial', 'motor_current')
CHANNEL_UNITS = {'force_moving': 'N', 'force_stationary': 'N', 'accel_axial': 'm/s^2', 'motor_current': 'A'}
CHANNEL_COLUMNS = {'force_moving': 'force_moving_n', 'force_stationary': 'force_stationary_n',
                   'accel_axial': 'accel_axial_m_s2', 'motor_current': 'motor_current_a'}
SIGNALS = ('F_move', 'F_stat', 'T', 'a2', 'v', 'x', 't')
SIGNAL_UNITS = {'F_move': 'N', 'F_stat': 'N', 'T': 'N', 'a2': 'm/s^2', 'v': 'm/s', 'x': 'm', 't': 's'}
MAX_POWER = 3
SIN = 'sin'
KEYS = ('channel', 'term', 'coefficient', 'frequency_hz')

_FACTOR = re.compile(r'^([A-Za-z_0-9]+?)(?:\^(\d+))?$')


def term_name(powers: Mapping[str, int]) -> str:
    """'F_move^2', 'F_move*v', 'v*sin': the signals in SIGNALS order, then sin."""
    parts = [s if powers[s] == 1 else f'{s}^{powers[s]}' for s in SIGNALS if powers.get(s, 0) > 0]
    if powers.get(SIN):
        parts.append(SIN)
    return '*'.join(parts)


def parse_term(term: str) -> Dict[str, int]:
    """{signal: power} (and 'sin': 1) of a term of the grammar; SimError quoting it otherwise."""
    out: Dict[str, int] = {}
    for f in str(term).split('*'):
        m = _FACTOR.match(f.strip())
        name, k = (m.group(1), int(m.group(2) or 1)) if m else (None, 0)
        if name not in (*SIGNALS, SIN) or not 1 <= k <= MAX_POWER or (name == SIN and k != 1) or name in out:
            raise SimError(f'term {term!r} is not in the grammar; expected products of {", ".join(SIGNALS)} '
                           f'with powers 1-{MAX_POWER} (e.g. F_move^2, F_move*v), optionally times sin')
        out[name] = k
    if term_name(out) != term:
        raise SimError(f"term {term!r} is not written in the grammar's order; expected {term_name(out)!r}")
    return out


def term_unit(term: str) -> str:
    """The term's SI unit ('1' for a bare sin)."""
    p = parse_term(term)
    return '*'.join(SIGNAL_UNITS[s] if k == 1 else f'{SIGNAL_UNITS[s]}^{k}' for s, k in p.items() if s != SIN) or '1'


def term_values(term: str, sig: Mapping[str, np.ndarray]) -> np.ndarray:
    """A term's product part from the signals (a sinusoid's factor only: sin itself needs its phase)."""
    out = np.ones_like(np.asarray(sig['t'], float))
    for s, k in parse_term(term).items():
        if s != SIN:
            out = out * np.asarray(sig[s], float) ** k
    return out


@dataclass(frozen=True)
class ExtraTerm:
    channel: str
    term: str
    coefficient: float
    frequency_hz: Optional[float] = None

    @property
    def is_sin(self) -> bool:
        return SIN in parse_term(self.term)

    def values(self, sig: Mapping[str, np.ndarray], phase: float = 0.0) -> np.ndarray:
        """What the term adds to its channel (phase: a sinusoid's, rad)."""
        out = self.coefficient * term_values(self.term, sig)
        if self.is_sin:
            out = out * np.sin(2.0 * math.pi * self.frequency_hz * np.asarray(sig['t'], float) + phase)
        return out


def extra_terms_from_data(data: Any) -> Tuple[ExtraTerm, ...]:
    """The rig YAML's extra_terms: section (a list of {channel, term, coefficient[, frequency_hz]})."""
    if data is None:
        return ()
    if not isinstance(data, list):
        raise SimError(f'extra_terms is {data!r}; expected a list of {{channel, term, coefficient}} mappings')
    out = []
    for i, e in enumerate(data):
        where = f'extra_terms[{i}]'
        if not isinstance(e, Mapping) or sorted(set(e) - set(KEYS)) or not {'channel', 'term', 'coefficient'} <= set(e):
            raise SimError(f'{where} is {e!r}; expected a mapping with channel, term, coefficient (and frequency_hz '
                           'for a sin term) only')
        if e['channel'] not in CHANNELS:
            raise SimError(f'{where}.channel is {e["channel"]!r}; expected one of {", ".join(CHANNELS)}')
        p = parse_term(e['term'])
        c = e['coefficient']
        if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(c):
            raise SimError(f'{where}.coefficient is {c!r}; expected a finite number')
        f = e.get('frequency_hz')
        if (SIN in p) != (f is not None):
            raise SimError(f'{where}.frequency_hz is {f!r}; expected a frequency exactly when the term has sin')
        if f is not None and (isinstance(f, bool) or not isinstance(f, (int, float)) or not 0 < f < math.inf):
            raise SimError(f'{where}.frequency_hz is {f!r}; expected a positive finite number')
        out.append(ExtraTerm(str(e['channel']), str(e['term']), float(c), None if f is None else float(f)))
    return tuple(out)


def signals(t, F_move, F_stat, T, a2, v, x) -> Dict[str, np.ndarray]:
    """The SIGNALS of one pull as a term's values take them (t: the sample times; the record starts at t = 0)."""
    t = np.asarray(t, float)
    return {'F_move': F_move, 'F_stat': F_stat, 'T': T, 'a2': a2, 'v': v, 'x': x, 't': t - t[0]}


def sin_phase(seed: int) -> float:
    """A pull's phase of the sinusoid terms (seeded: the same pull gives the same phase)."""
    return float(np.random.default_rng([int(seed), 0x27]).uniform(0.0, 2.0 * math.pi))


def extra_channels(terms, sig: Mapping[str, np.ndarray], seed: int = 0,
                   phases: Optional[Mapping[ExtraTerm, float]] = None) -> Dict[str, np.ndarray]:
    """{channel: what the terms add to it} for one pull's signals. A sinusoid's phase: the pull's seeded one
    (sin_phase(seed)), or with ``phases`` given, the term's phase there (rad); a sin term not in it is left out."""
    out: Dict[str, np.ndarray] = {}
    for e in terms:
        if e.is_sin and phases is not None and e not in phases:
            continue
        v = e.values(sig, (sin_phase(seed) if phases is None else phases[e]) if e.is_sin else 0.0)
        out[e.channel] = out[e.channel] + v if e.channel in out else v
    return out
