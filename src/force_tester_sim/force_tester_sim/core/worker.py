"""The sim node's worker process (it simulates the next pull while the node publishes this one).

It must not outlive the node: a node killed with SIGKILL cannot shut its pool down, and its
spawned worker would wait on a closed pipe for good, holding a few hundred MB. And it leaves
shutdown to the node: started from a terminal, it is in the terminal's process group, so Ctrl-C
(SIGINT) reaches it too, mid-pull or while it is still importing its modules (before: a
`SpawnProcess-1 ... KeyboardInterrupt` traceback). It never receives that SIGINT, and ends when
the node shuts its pool down (or dies).
"""
from __future__ import annotations

import os
import signal
import threading
import time
from multiprocessing import resource_tracker

PARENT_POLL_S = 1.0   # how often the worker looks for its parent


def keep_sigint_from_workers() -> None:
    """Block SIGINT in the calling thread (a thread of the node, not its main thread, which handles
    Ctrl-C), so that every process it spawns starts with SIGINT blocked, from its first instruction
    on, and so do the threads it starts (the pool's manager thread, which starts the replacement
    workers). multiprocessing's resource tracker unblocks SIGINT in the thread that starts it, so it
    is started first."""
    resource_tracker.ensure_running()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})


def exit_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """A process-pool initializer: ignore SIGINT (the node shuts the pool down; a SIGINT that came
    while it was blocked is dropped), and end this process once ``parent_pid`` is no longer its
    parent (the parent died and the process was re-parented), from a daemon thread."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch():
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)
    threading.Thread(target=watch, name='exit-with-parent', daemon=True).start()
