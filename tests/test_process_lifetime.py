"""Issue 43: the identification node's spawned worker dies with its parent. Before, a SIGKILLed run left two
processes alive for 34 s and more: the spawn worker (busy with a window) and multiprocessing's resource tracker,
which only ends once every holder of its pipe is gone. The worker now asks the kernel for SIGKILL when its parent
dies (prctl PR_SET_PDEATHSIG), so both are gone a moment after the parent.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PARENT = textwrap.dedent('''
    import multiprocessing, os, sys, time
    from concurrent.futures import ProcessPoolExecutor
    from aeropend_ros.identification_node import _worker_start
    if __name__ == '__main__':
        pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                   initializer=_worker_start, initargs=(os.getpid(),))
        pool.submit(os.getpid).result()     # a task has run, so the worker's initializer (prctl) is done
        pool.submit(time.sleep, 600)        # a window that takes long
        print('ready', flush=True)
        time.sleep(600)
''')


def descendants(pid: int) -> set[int]:
    """Every process below `pid` (through /proc/*/stat parent ids)."""
    parents = {}
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int((entry / 'stat').read_text().rsplit(')', 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state != 'Z'


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='prctl is Linux only')
def test_a_sigkilled_parent_leaves_no_worker_and_no_resource_tracker(tmp_path):
    parent = subprocess.Popen([sys.executable, '-c', PARENT], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    children: set[int] = set()
    try:
        assert parent.stdout.readline().strip() == 'ready'
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(children) < 2:      # the tracker and the worker
            children = descendants(parent.pid)
            time.sleep(0.2)
        assert len(children) >= 2, children
        os.kill(parent.pid, signal.SIGKILL)             # 'ready' came after a task ran: the worker's prctl is done
        parent.wait(10)
        deadline = time.monotonic() + 30.0              # gone at once when idle; the wait ends then
        while time.monotonic() < deadline and any(alive(pid) for pid in children):
            time.sleep(0.1)
        left = [pid for pid in children if alive(pid)]
        assert not left, [Path(f'/proc/{pid}/cmdline').read_bytes() for pid in left]
    finally:
        for pid in children | descendants(parent.pid) | {parent.pid}:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
