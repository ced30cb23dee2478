"""Unfinished outputs: marked while they are written, removed by the next writer once their writer is gone.

ROS-free, standard library only. An output is written where nothing reads it as finished (a hidden
``.NAME.partial-*`` folder renamed at the end, a bag folder without ``metadata.yaml``, a hidden
``.discover-*`` staging folder); its writer holds an exclusive lock (``flock``) on a file WRITING inside
it, which says who writes it. A writer that dies (killed, its host gone) leaves the folder behind, still
unfinished, but its lock goes with its process. ``clear_stale(path)``, called by the next writer of that
output, removes such leftovers: the hidden partial folders beside ``path`` (and ``path`` itself, when it
is an unfinished folder of ours) whose lock it can take, and returns one line per folder removed. A
folder whose writer still runs (its lock is held) is left alone; one without WRITING (another program's,
e.g. a recording that needs a reindex) is never touched.

On a cluster's shared storage the lock is the file system's: NFSv4 and most cluster file systems release
a dead client's locks after their lease time (90 s for NFSv4 by default); until then the folder is
still in use.

    with Marked(folder):          # the lock, held while folder is written
        ...                       # unmark() before the rename: WRITING is not part of the output
"""
from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import time
from pathlib import Path

#: The marker file in an unfinished output: its writer holds an exclusive flock on it.
WRITING = '.ft-writing'


class Marked:
    """Hold the lock on ``folder``/WRITING (created, with the writer's host, pid and start time in it)."""

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.fd = -1

    def __enter__(self) -> 'Marked':
        self.fd = os.open(self.folder / WRITING, os.O_CREAT | os.O_WRONLY | os.O_TRUNC, 0o644)
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(self.fd, f'pid {os.getpid()} on {os.uname().nodename} since '
                          f'{time.strftime("%Y-%m-%d %H:%M:%S")}\n'.encode())
        return self

    def unmark(self) -> None:
        """Remove WRITING (the lock stays held on its file until exit): the folder is about to be finished."""
        try:
            os.unlink(self.folder / WRITING)
        except FileNotFoundError:
            pass

    def __exit__(self, *exc) -> None:
        if self.fd >= 0:
            os.close(self.fd)   # releases the lock
            self.fd = -1


def writer_gone(folder: Path) -> str | None:
    """Who wrote ``folder`` when it is an unfinished output whose writer is gone (its lock is free), else None."""
    try:
        fd = os.open(Path(folder) / WRITING, os.O_RDWR)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return None     # its writer still runs
        return os.read(fd, 200).decode(errors='replace').strip() or 'an unknown writer'
    finally:
        os.close(fd)


def _remove_gone(folders) -> list:
    lines = []
    for folder in folders:
        who = writer_gone(folder)
        if who is not None:
            shutil.rmtree(folder, ignore_errors=True)
            lines.append(f'removed {str(folder)!r}, left unfinished by a writer that is gone ({who})')
    return lines


def clear_stale(path: Path) -> list:
    """Remove the unfinished outputs of dead writers for output ``path``: ``path`` itself when it is one (a bag
    folder), and the ``.NAME.partial-*`` folders beside it (write_campaign's). Returns one line each."""
    path = Path(path)
    found = [path] if path.is_dir() else []
    if path.parent.is_dir():   # names first: a Path for each entry of a big folder costs ~1.5 us
        found += [path.parent / n for n in sorted(os.listdir(path.parent)) if n.startswith(f'.{path.name}.partial-')]
    return _remove_gone(found)


def clear_stale_in(folder: Path, prefix: str) -> list:
    """Remove the unfinished folders named ``prefix``* inside ``folder`` whose writers are gone (discover's
    ``.discover-*`` staging folders). Returns one line each."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return _remove_gone([folder / n for n in sorted(os.listdir(folder)) if n.startswith(prefix)])


@contextlib.contextmanager
def staging(folder: Path, prefix: str, warnings: list | None = None):
    """A fresh hidden folder ``prefix``* inside ``folder`` (made if needed), marked while in use and removed at
    the end; what a writer that died left there is removed first. Yields its Marked: call unmark() before moving
    the finished files out."""
    import tempfile  # here: the writers that stage nothing (a bag's) do not load it
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tell(clear_stale_in(folder, prefix), warnings)
    stage = Path(tempfile.mkdtemp(prefix=prefix, dir=folder))
    try:
        with Marked(stage) as mark:
            yield mark
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def tell(lines: list, warnings: list | None = None) -> None:
    """The lines to ``warnings`` (a command's list, printed as its warnings), else logged as warnings (on stderr
    when nothing else is configured)."""
    if warnings is not None:
        warnings.extend(lines)
    elif lines:
        import logging  # here: most commands pass a list, and logging costs a command's start-up ~10 ms
        for line in lines:
            logging.getLogger('force_tester.partial').warning(line)
