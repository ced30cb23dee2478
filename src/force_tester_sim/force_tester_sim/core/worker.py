"""The sim node's worker process (it simulates the next pull while the node publishes this one)
must not outlive the node: a node killed with SIGKILL cannot shut its pool down, and its
spawned worker would wait on a closed pipe for good, holding a few hundred MB.
"""
from __future__ import annotations

import os
import threading
import time

PARENT_POLL_S = 1.0   # how often the worker looks for its parent


def exit_with_parent(parent_pid: int, poll_s: float = PARENT_POLL_S) -> None:
    """A process-pool initializer: a daemon thread ends this process once ``parent_pid`` is no longer
    its parent (the parent died and the process was re-parented)."""
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)
    threading.Thread(target=watch, name='exit-with-parent', daemon=True).start()
