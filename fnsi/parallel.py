"""Side-by-side work in threads, with the BLAS serial while it runs.

A diagnosis identifies and simulates its candidates side by side in threads: each
task is compiled code and LAPACK that release the interpreter. OpenBLAS, by default,
also starts one thread per CPU inside every call, so ``workers`` tasks asked for
``workers`` x CPUs threads on as many cores, and on matrices the size of a
diagnosis's (tens to hundreds of rows) its threads cost more than they save even alone.
On a 2-core machine (AMD EPYC, AVX2) the SmallSat single-39 diagnosis of
``benchmarks/diagnosis.py`` took 67 s with two tasks side by side and OpenBLAS's two
threads in each call, 61 s with one task at a time, 53-55 s with the BLAS serial only
while tasks ran side by side and 47-50 s with it serial throughout: the pool's threads,
not the BLAS's, are the ones to keep (:func:`serial_blas`).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, contextmanager

from threadpoolctl import threadpool_limits


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the system has one, as on Linux;
    else every CPU, as on macOS and Windows)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


@contextmanager
def serial_blas() -> Iterator[None]:
    """Every BLAS library the process has loaded (numpy's and scipy's OpenBLAS, MKL,
    ...) on one thread while the context is open (threadpoolctl); the limits are
    restored when it closes.

    Serial in every task, whatever the number of workers, so that an answer does not
    depend on it, nor on ``OPENBLAS_NUM_THREADS``, to the last bit: a BLAS splits its
    work by its thread count, and the rounding moves with it. The limit is the
    process's: a context closed in one thread lifts it for the others too, so that work
    run side by side in one process's own threads (not the service's jobs, each in a
    process of its own) may see it lifted early; only the speed and the last bits
    depend on that."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@contextmanager
def thread_pool(workers: int) -> Iterator[ThreadPoolExecutor]:
    """A thread pool of ``workers`` threads whose tasks call a serial BLAS
    (:func:`serial_blas`).

    Parameters
    ----------
    workers : int
        Tasks run side by side (at least 1).

    Yields
    ------
    ThreadPoolExecutor
        Shut down, its unstarted tasks cancelled, when the context is left (so that a
        cancelled diagnosis does not go on in the background).
    """
    with ExitStack() as stack:
        stack.enter_context(serial_blas())
        pool = ThreadPoolExecutor(max_workers=workers)
        stack.callback(pool.shutdown, wait=True, cancel_futures=True)
        yield pool
