"""The one unit lookup (issue 40 item 4): the spellings labs write, and none made ambiguous."""
from __future__ import annotations

import pytest

from force_tester_common.core.units import G_M_S2, SYMBOLS, UNITS, WORDS, known_units, unit, unit_name


@pytest.mark.parametrize('spelling, canonical', [
    ('Newtons', 'N'), ('newton', 'N'), ('NEWTON', 'N'), (' N ', 'N'), ('[N]', 'N'), ('kilonewtons', 'kN'),
    ('KN', 'kN'), ('pounds-force', 'lbf'), ('LBF', 'lbf'),
    ('m/s²', 'm/s^2'), ('m/s^2', 'm/s^2'), ('m/s2', 'm/s^2'), ('m s^-2', 'm/s^2'), ('m·s⁻²', 'm/s^2'),
    ('metres per second squared', 'm/s^2'), ('G', 'g'), ('g', 'g'), ("g's", 'g'),
    ('Volts', 'V'), ('volt', 'V'), ('v', 'V'), ('millivolts', 'mV'), ('mv', 'mV'), ('µV', 'uV'), ('μV', 'uV'),
    ('mV/V', 'mV/V'), ('millivolts per volt', 'mV/V'), ('Meters', 'm'), ('millimetres', 'mm'), ('inches', 'in'),
    ('feet', 'ft'), ('Amps', 'A'), ('milliamperes', 'mA'), ('fps', 'ft/s'), ('feet per second', 'ft/s'),
    ('Seconds', 's'), ('msec', 'ms'),
])
def test_spellings_labs_write_are_read(spelling, canonical):
    assert unit_name(spelling) == canonical
    assert unit(spelling) == UNITS[canonical]


@pytest.mark.parametrize('spelling', ['M', 'MV', 'MN', 'MA', 'Ms', 'furlong', 'gram', 'Newton-meters', '', ' ',
                                      'm/s^3', None, 3, ['N']])
def test_what_is_not_a_unit_here_stays_unknown(spelling):
    """M is mega (not metre or milli), there is no gram; nothing that is not a string is a unit."""
    assert unit_name(spelling) is None and unit(spelling) is None


def test_g_is_standard_gravity_in_every_case():
    assert unit('g') == unit('G') == ('acceleration', G_M_S2)


def test_no_spelling_is_ambiguous():
    """Every spelling names one canonical unit; the any-case names never shadow a symbol of another unit (a
    symbol's lower case read as a word would lose its prefix: 'MN' is not 'mN')."""
    assert all(w == w.lower() for w in WORDS), 'WORDS are matched in lower case'
    for table in (SYMBOLS, WORDS):
        assert set(table.values()) <= set(UNITS)
    for sym, canon in SYMBOLS.items():
        assert WORDS.get(sym.lower(), canon) == canon, sym
    for canon in UNITS:   # a canonical name is itself, never another unit through a table
        assert unit_name(canon) == canon


def test_every_unit_of_the_table_has_a_spelled_out_name():
    assert set(UNITS) == set(WORDS.values())


def test_the_known_list_names_every_unit():
    text = known_units()
    assert all(u in text for u in UNITS) and 'Newtons' in text
