"""The sim node's worker process (it simulates the next pull while the node publishes this one).

It must not outlive the node: a node killed with SIGKILL cannot shut its pool down, and its
spawned worker would wait on a closed pipe for good, holding a few hundred MB. And it leaves
shutdown to the node: started from a terminal, it is in the terminal's process group, so Ctrl-C
(SIGINT) reaches it too, mid-pull or while it is still importing its modules (before: a
`SpawnProcess-1 ... KeyboardInterrupt` traceback). It starts with SIGINT ignored, and ends when the
node shuts its pool down (or dies).
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import shlex
import sys
import tempfile
import threading
import time
from pathlib import Path

PARENT_POLL_S = 1.0   # how often the worker looks for its parent


@contextlib.contextmanager
def sigint_ignoring_spawn():
    """A 'spawn' multiprocessing context whose processes start with SIGINT ignored, from their first
    instruction on: they are started through a shell that ignores it (`trap '' INT`) and execs
    Python, and an ignored SIGINT stays ignored across exec and in Python ("SIGINT is translated
    into a KeyboardInterrupt exception if the parent process has not changed it", the signal
    module's documentation). The process itself keeps its own Ctrl-C. (Blocking SIGINT in the
    starting thread does not reach a spawned child: it starts with an empty signal mask.)

    multiprocessing keeps one executable for every 'spawn' process of this process: use this in a
    process that starts no other (the sim node)."""
    ctx = multiprocessing.get_context('spawn')
    with tempfile.TemporaryDirectory(prefix='ft-sim-worker-') as tmp:
        exe = Path(tmp) / 'python'
        exe.write_text("#!/bin/sh\n# the sim's worker process: Ctrl-C is for the node, which shuts it down\n"
                       f"trap '' INT\nexec {shlex.quote(sys.executable)} \"$@\"\n")
        exe.chmod(0o700)
        ctx.set_executable(str(exe))
        try:
            yield ctx
        finally:
            ctx.set_executable(sys.executable)


def exit_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """A process-pool initializer: a daemon thread ends this process once ``parent_pid`` is no longer
    its parent (the parent died and the process was re-parented)."""
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)
    threading.Thread(target=watch, name='exit-with-parent', daemon=True).start()
