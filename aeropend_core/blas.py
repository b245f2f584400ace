"""One BLAS thread for aeropend's numerics, unless the user chose a thread count.

aeropend's matrices are small (a Jacobian of about ten thousand rows and tens of columns, Gram matrices of tens
of columns): one thread does each product in microseconds to milliseconds. OpenBLAS's own threads cost far more
than they save there, and on a machine whose cores are busy (the ROS graph beside the diagnosis, a second test
worker) a product can wait for a descheduled thread. Measured on the project's 2-core machine: at a load average of
about 7, ``(11 x 10959) @ (10959 x 16)`` took 0.54 s with OpenBLAS's two threads and 2 ms with one (at a load of 5
the same product took 0.5 ms and 0.3 ms: the cost comes with the load); ``aeropend diagnose`` of a 60 s record took
13-15.3 s of CPU with one thread against 21.5-24.4 s with two, at loads of 5-6 (``bench/bench_blas_threads.py``,
``bench/results/2026-11-27-s10-suite/``).
"""
from __future__ import annotations

import contextlib
import os
import sys

#: Environment variables by which a user sets the BLAS thread count: then aeropend leaves it alone.
THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'BLIS_NUM_THREADS')
#: The variable OpenBLAS (numpy's and scipy's wheels) reads when it is loaded.
_LOAD_VARIABLE = 'OPENBLAS_NUM_THREADS'


def single_blas_thread() -> contextlib.AbstractContextManager:
    """Context in which BLAS runs on one thread (the previous count comes back on exit for the libraries loaded
    before it).

    Imports nothing heavy itself, so a command line refused inside it stays fast: OpenBLAS reads
    ``OPENBLAS_NUM_THREADS`` when it is loaded, so the variable is set to 1 for the context's duration (numpy's and
    scipy's OpenBLAS loaded inside it start with one thread, and keep it); the libraries already loaded get
    :class:`threadpoolctl.threadpool_limits` (numpy and scipy each bring their own OpenBLAS, and a limit reaches
    only the libraries loaded when it is set). Child processes started inside it inherit the variable.

    Returns
    -------
    contextlib.AbstractContextManager
        That context, or a no-op context when the user set one of :data:`THREAD_VARIABLES`.
    """
    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return contextlib.nullcontext()
    return _one_blas_thread()


@contextlib.contextmanager
def _one_blas_thread():
    previous = os.environ.get(_LOAD_VARIABLE)
    os.environ[_LOAD_VARIABLE] = '1'
    try:
        if 'numpy' in sys.modules or 'scipy' in sys.modules:
            from threadpoolctl import threadpool_limits
            with threadpool_limits(limits=1, user_api='blas'):
                yield
        else:
            yield
    finally:
        if previous is None:
            os.environ.pop(_LOAD_VARIABLE, None)
        else:
            os.environ[_LOAD_VARIABLE] = previous
