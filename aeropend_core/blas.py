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

#: Environment variables by which a user sets the BLAS thread count: then aeropend leaves it alone.
THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS', 'BLIS_NUM_THREADS')


def single_blas_thread() -> contextlib.AbstractContextManager:
    """Context in which BLAS runs on one thread (the previous count comes back on exit).

    Returns
    -------
    contextlib.AbstractContextManager
        :class:`threadpoolctl.threadpool_limits` with one BLAS thread, or a no-op context when the user set one of
        :data:`THREAD_VARIABLES`.
    """
    if any(os.environ.get(name) for name in THREAD_VARIABLES):
        return contextlib.nullcontext()
    # numpy and scipy each bring their own OpenBLAS, and a limit reaches only the libraries loaded when it is set
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits
    return threadpool_limits(limits=1, user_api='blas')
