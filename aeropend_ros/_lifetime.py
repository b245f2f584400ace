"""Child processes that die with their parent: a process the kernel sends SIGKILL when its parent dies.

Without it a SIGKILLed ``aeropend run`` left the identification node's spawned worker running (busy with a window
for 34 s and more, issue 43), and with it multiprocessing's resource tracker, which ends only once every holder of
its pipe is gone.
"""
from __future__ import annotations

import os

__all__ = ['PR_SET_PDEATHSIG', 'die_with_parent']

#: prctl option: the signal a process gets when its parent (the thread that created it) dies (linux/prctl.h).
PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> bool:
    """Make this process get SIGKILL when its parent dies (``prctl(PR_SET_PDEATHSIG)`` through ctypes), and exit at
    once if the parent is already gone (it died before the prctl: nobody would ever send the signal).

    Parameters
    ----------
    parent_pid : int [-]
        The parent's pid as the parent saw it (``os.getpid()`` there), passed to the child.

    Returns
    -------
    bool
        False where prctl is not available (not Linux): the child then ends on its own.
    """
    import ctypes
    import signal
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if os.getppid() != parent_pid:
        os._exit(1)
    return True
