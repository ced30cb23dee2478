"""Unfinished outputs (force_tester_common.core.partial): a writer killed midway leaves its folder, marked; the next
writer of that output removes it and says so; a folder whose writer still runs, or one not marked (another
program's), is left alone. Real processes, real locks: the writer is a child process, SIGKILLed."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from force_tester_common.core.partial import WRITING, Marked, clear_stale, clear_stale_in, staging, writer_gone

HOLD = textwrap.dedent('''
    import sys, time
    from pathlib import Path
    from force_tester_common.core.partial import Marked
    folder = Path(sys.argv[1])
    folder.mkdir()
    (folder / 'half.csv').write_text('t,f\\n0.0,1')
    with Marked(folder):
        print('ready', flush=True)
        time.sleep(600)
''')


def writer(folder: Path) -> subprocess.Popen:
    """A process that writes into ``folder`` (marked) and then waits: it is the writer until it is killed."""
    proc = subprocess.Popen([sys.executable, '-c', HOLD, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == 'ready'
    return proc


def kill(proc: subprocess.Popen) -> None:
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()


def test_a_killed_writers_partial_folder_is_removed_by_the_next_writer(tmp_path):
    dead = tmp_path / '.out.partial-abc123'
    proc = writer(dead)
    kill(proc)
    assert (dead / WRITING).is_file() and (dead / 'half.csv').is_file()   # left behind, marked
    lines = clear_stale(tmp_path / 'out')
    assert not dead.exists()
    assert len(lines) == 1 and lines[0].startswith(f"removed '{dead}', left unfinished by a writer that is gone "
                                                   f'(pid {proc.pid} on '), lines


def test_a_running_writers_folder_and_an_unmarked_folder_are_left_alone(tmp_path):
    live = tmp_path / '.out.partial-live'
    proc = writer(live)
    try:
        foreign = tmp_path / 'out'        # e.g. a recording without metadata.yaml: it needs a reindex, not removal
        foreign.mkdir()
        (foreign / 'bag_0.mcap').write_bytes(b'\x89MCAP0\r\n')
        assert writer_gone(live) is None and clear_stale(tmp_path / 'out') == []
        assert live.is_dir() and (foreign / 'bag_0.mcap').is_file()
    finally:
        kill(proc)
    assert writer_gone(live) is not None      # once its writer is gone it is stale


def test_a_marked_output_folder_itself_is_removed_once_its_writer_is_gone(tmp_path):
    """A bag folder is written in place (no metadata.yaml until closed): marked, it is removed as a whole."""
    bag = tmp_path / 'bag'
    kill(writer(bag))
    lines = clear_stale(bag)
    assert not bag.exists() and len(lines) == 1 and repr(str(bag)) in lines[0]


def test_staging_clears_dead_staging_folders_and_leaves_nothing(tmp_path):
    out = tmp_path / 'report'
    out.mkdir()
    kill(writer(out / '.discover-dead'))
    seen = []
    with staging(out, '.discover-', seen) as mark:
        assert mark.folder.parent == out and (mark.folder / WRITING).is_file()
        assert not (out / '.discover-dead').exists()
        (mark.folder / 'report.json').write_text('{}')
        mark.unmark()
        assert [p.name for p in mark.folder.iterdir()] == ['report.json']   # the marker is no output
        (mark.folder / 'report.json').replace(out / 'report.json')
    assert sorted(p.name for p in out.iterdir()) == ['report.json']
    assert len(seen) == 1 and '.discover-dead' in seen[0] and clear_stale_in(out, '.discover-') == []


def test_a_folder_is_marked_once(tmp_path):
    with Marked(tmp_path):
        with pytest.raises(OSError):
            Marked(tmp_path).__enter__()     # a second writer of the same folder cannot take it
