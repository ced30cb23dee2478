"""The per-user cache of arrays and JSON data (force_tester_common.core.cache), and the peak uncertainty's normals
kept in it."""
from __future__ import annotations

import os

import numpy as np
import pytest

from force_correction.core import peak_uncertainty as pu
from force_tester_common.core.cache import CACHE_ENV, CACHE_SUBDIR, cache_dir, cached_array, cached_json


def test_the_folder_is_ft_cache_dir_else_xdg_else_home():
    assert cache_dir({CACHE_ENV: '/x/c', 'XDG_CACHE_HOME': '/y'}) == cache_dir({CACHE_ENV: '/x/c'})
    assert str(cache_dir({CACHE_ENV: '/x/c'})) == '/x/c'
    assert str(cache_dir({'XDG_CACHE_HOME': '/y'})) == f'/y/{CACHE_SUBDIR}'
    assert cache_dir({}) == cache_dir({'HOME': os.environ.get('HOME', '')}) != cache_dir({'XDG_CACHE_HOME': '/y'})
    assert cache_dir({}).parts[-2:] == ('.cache', CACHE_SUBDIR)


def test_an_entry_is_made_once_then_read_and_a_damaged_one_is_made_again(tmp_path):
    env = {CACHE_ENV: str(tmp_path / 'c')}
    calls = []

    def make():
        calls.append(1)
        return np.arange(6.0)

    first = cached_array('e', (2, 3), make, env)
    again = cached_array('e', (2, 3), make, env)
    assert len(calls) == 1 and np.array_equal(first, again) and again.shape == (2, 3)
    assert sorted(p.name for p in (tmp_path / 'c').iterdir()) == ['e.npy']   # no temporary left
    (tmp_path / 'c' / 'e.npy').write_bytes(b'\x93NUMPY damaged')
    assert np.array_equal(cached_array('e', (2, 3), make, env), first) and len(calls) == 2
    assert np.array_equal(cached_array('e', (6,), make, env), np.arange(6.0)) and len(calls) == 3  # another shape
    assert np.array_equal(cached_array('e', (6,), make, env), np.arange(6.0)) and len(calls) == 3


def test_a_folder_that_cannot_be_written_is_not_used(tmp_path):
    blocked = tmp_path / 'file'
    blocked.write_text('a file where the folder would be')
    env = {CACHE_ENV: str(blocked / 'c')}
    assert np.array_equal(cached_array('e', (3,), lambda: [1.0, 2.0, 3.0], env), [1.0, 2.0, 3.0])
    assert blocked.read_text() == 'a file where the folder would be'


def test_json_data_are_made_once_and_what_the_check_refuses_is_made_again(tmp_path):
    env = {CACHE_ENV: str(tmp_path / 'c')}
    calls = []

    def make():
        calls.append(1)
        return {'a': [1, 'x', None]}

    def valid(data):
        return isinstance(data, dict) and 'a' in data
    want = {'a': [1, 'x', None]}
    assert cached_json('j', make, valid, env) == cached_json('j', make, valid, env) == want and len(calls) == 1
    entry = tmp_path / 'c' / 'j.json'
    for bad in ('{"a": [1', '{"b": 2}', '\x00\xff'):   # cut short, refused by the check, not JSON
        entry.write_text(bad)
        assert cached_json('j', make, valid, env) == want
    assert len(calls) == 4 and sorted(p.name for p in entry.parent.iterdir()) == ['j.json']
    blocked = tmp_path / 'file'
    blocked.write_text('here')
    assert cached_json('j', make, valid, {CACHE_ENV: str(blocked / 'c')}) == want and blocked.read_text() == 'here'


@pytest.mark.parametrize('width', [41, 7])
def test_the_monte_carlos_normals_are_numpys_draws_whether_cached_or_not(tmp_path, monkeypatch, width):
    draws = pu.MC_DRAWS
    rng = np.random.default_rng(pu.MC_SEED)
    want = rng.standard_normal((4, draws)), rng.standard_normal((draws, width))   # the two draws, in that order
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    for _ in range(2):   # made, then read from the cache
        pu.mc_normals.cache_clear()
        pu.noise_extremes.cache_clear()
        z, noise = pu.mc_normals(draws, width)
        assert np.array_equal(z, want[0]) and np.array_equal(noise, want[1])
        assert not z.flags.writeable and not noise.flags.writeable
        assert len(list(tmp_path.glob(f'mc_normals-*-{draws}x{width}.npy'))) == 1
    pu.mc_normals.cache_clear()
    pu.noise_extremes.cache_clear()
