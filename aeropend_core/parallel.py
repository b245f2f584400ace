"""Independent work side by side on the machine's cores: the candidates of one round of the catalog search, the
motor observer's simulations, the weak form's equations (a leaf: signals, wsindy and diagnosis all call it).

Each candidate's output-error fit spends most of its time in the compiled simulation kernel
(:func:`aeropend_core.diagnosis.output_error._simulate_kernel`, compiled ``nogil``), so threads of one process
run the fits of a round at the same time without copying the record into other processes or importing the
stack again. The fits share nothing they write, BLAS runs one thread (:mod:`aeropend_core.blas`) and each fit
does exactly the arithmetic it does alone, so the results are identical whatever the number of workers (a test
compares 1 and 2 workers exactly); the results come back in the order of the inputs.

``AEROPEND_WORKERS`` sets the number of workers (1: one after the other, as before); by default one per core this
process may run on. Where a thread cannot be started, and for records longer than :data:`PARALLEL_MAX_SAMPLES`
(memory), the fits run one after the other.
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from typing import TypeVar

from aeropend_core.errors import AeropendError

#: Environment variable that sets the number of workers (a whole number >= 1).
WORKERS_VARIABLE = 'AEROPEND_WORKERS'

#: Name prefix of the worker threads (a map inside a worker runs serially).
_THREAD_PREFIX = 'aeropend-fit'

Item = TypeVar('Item')
Result = TypeVar('Result')


def default_workers() -> int:
    """Workers for independent fits [-]: ``AEROPEND_WORKERS`` when set, else the cores this process may run on.

    Raises
    ------
    AeropendError
        ``AEROPEND_WORKERS`` is not a whole number >= 1.
    """
    text = os.environ.get(WORKERS_VARIABLE, '').strip()
    if text:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value < 1:
            raise AeropendError(f'{WORKERS_VARIABLE}={text!r} is not a number of workers; set a whole number >= 1 '
                                f'(1: one fit after the other) or unset it (one worker per core)')
        return value
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):        # not on Linux
        return max(1, os.cpu_count() or 1)


#: Longest record [samples] whose fits run side by side (~306 s at 490 Hz). Each fit of a long record holds its own
#: simulations and Jacobian: a 600 s record diagnosed with two workers peaked at 632 MB of resident memory against
#: 436 MB with one (bench/results/2026-12-06-s18-speed), so longer records fit one candidate after the other.
PARALLEL_MAX_SAMPLES = 150_000


def workers_for(samples: int) -> int | None:
    """Workers for the fits of a record of `samples` samples [-]: None (the default, one per core) up to
    :data:`PARALLEL_MAX_SAMPLES`, 1 above it (the peak memory stays that of one fit)."""
    return None if samples <= PARALLEL_MAX_SAMPLES else 1


def map_in_order(function: Callable[[Item], Result], items: Iterable[Item], workers: int | None = None) -> list[Result]:
    """``[function(item) for item in items]``, computed on up to `workers` threads (None: :func:`default_workers`).

    Parameters
    ----------
    function : callable [-]
        Applied to each item; must not write anything another call reads.
    items : iterable [-]
        The inputs.
    workers : int or None [-]
        Number of threads; 1 computes in this thread, one item after the other.

    Returns
    -------
    list
        The results in the order of `items`. An exception raised by a call is raised here (the first in the order
        of `items`), as the serial loop would.
    """
    items = list(items)
    count = min(default_workers() if workers is None else int(workers), len(items))
    if threading.current_thread().name.startswith(_THREAD_PREFIX):
        count = 1                           # already a worker: the cores are taken by the outer map
    if count <= 1:
        return [function(item) for item in items]
    from concurrent.futures import ThreadPoolExecutor
    try:
        pool = ThreadPoolExecutor(max_workers=count, thread_name_prefix=_THREAD_PREFIX)
        futures = [pool.submit(function, item) for item in items]
    except RuntimeError:                     # cannot start a thread (resource limits, interpreter shutting down)
        return [function(item) for item in items]
    try:
        return [future.result() for future in futures]
    finally:                                 # on an error or Ctrl-C: start no further fit
        pool.shutdown(wait=True, cancel_futures=True)


#: Fewest samples a compiled kernel's call must cover before its segments are split over threads (below, starting
#: the threads costs more than the split saves).
SPLIT_MIN_SAMPLES = 8_000
_kernel_pool = None


def _forget_kernel_pool() -> None:
    global _kernel_pool
    _kernel_pool = None      # a forked child has none of the pool's threads: it starts its own


if hasattr(os, 'register_at_fork'):
    os.register_at_fork(after_in_child=_forget_kernel_pool)


def in_segment_chunks(call: Callable, seg_start, seg_stop) -> None:
    """``call(first, last)`` for contiguous chunks ``[first, last)`` of the segments, one chunk per worker thread,
    as balanced in samples as whole segments allow; one call over all of them with one worker, inside a worker of
    :func:`map_in_order` (the cores are taken) or for a short simulation.

    For a compiled kernel (``nogil``) that simulates each segment from its own initial state and writes only that
    segment's samples: the numbers are those of one call whatever the chunks. A long record's fits run one after
    the other (:data:`PARALLEL_MAX_SAMPLES`), so without this its kernels used one core of the machine's.
    """
    global _kernel_pool
    count = len(seg_start)
    lengths = [int(b) - int(a) for a, b in zip(seg_start, seg_stop)]
    workers = min(default_workers(), count)
    if workers <= 1 or sum(lengths) < SPLIT_MIN_SAMPLES or threading.current_thread().name.startswith(_THREAD_PREFIX):
        call(0, count)
        return
    edges, done, total = [0], 0, sum(lengths)
    for index, length in enumerate(lengths[:-1]):
        done += length
        if done * workers >= total * len(edges) and len(edges) < workers:
            edges.append(index + 1)
    edges.append(count)
    from concurrent.futures import ThreadPoolExecutor
    try:
        if _kernel_pool is None:
            _kernel_pool = ThreadPoolExecutor(max_workers=default_workers(), thread_name_prefix='aeropend-kernel')
        futures = [_kernel_pool.submit(call, a, b) for a, b in zip(edges[:-1], edges[1:])]
    except RuntimeError:                     # cannot start a thread: one call, the same numbers
        call(0, count)
        return
    for error in [future.exception() for future in futures]:      # every chunk finished before anything is raised
        if error is not None:
            raise error


def locked(say: Callable[[str], None]) -> Callable[[str], None]:
    """`say` made safe to call from several workers (one message at a time)."""
    lock = threading.Lock()

    def say_locked(message: str) -> None:
        with lock:
            say(message)
    return say_locked
