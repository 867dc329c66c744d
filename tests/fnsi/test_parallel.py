"""Side-by-side work with a serial BLAS (fnsi.parallel)."""

import time

import numpy as np  # noqa: F401  (loads numpy's BLAS, so that threadpoolctl sees it)
import pytest
import scipy.linalg  # noqa: F401  (loads scipy's)
from threadpoolctl import threadpool_info, threadpool_limits

from fnsi.parallel import serial_blas, thread_pool


def blas_threads() -> set[int]:
    """The thread counts of every BLAS library loaded in this process."""
    return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}


def test_the_blas_is_serial_while_tasks_run_and_restored_after():
    # two threads first, whatever OPENBLAS_NUM_THREADS the test run was started with,
    # so that a limit not lifted on exit shows
    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        for workers in (1, 2):
            with thread_pool(workers) as pool:
                assert pool.submit(blas_threads).result() == {1}
            assert blas_threads() == {2}
        with serial_blas():
            assert blas_threads() == {1}
        assert blas_threads() == {2}


def test_leaving_the_pool_cancels_the_tasks_not_started():
    # a cancelled diagnosis (its progress callback raised) must not go on in the
    # background: 100 tasks of 50 ms on 2 workers would take 2.5 s; leaving at once
    # cancels all but the few already started
    started = []

    def task(k: int) -> None:
        started.append(k)
        time.sleep(0.05)

    with pytest.raises(KeyboardInterrupt), thread_pool(2) as pool:
        futures = [pool.submit(task, k) for k in range(100)]
        raise KeyboardInterrupt
    assert sum(f.cancelled() for f in futures) >= 90
    assert len(started) <= 10
