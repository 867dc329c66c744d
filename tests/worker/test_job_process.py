"""The CPU share a launcher gives its job processes (worker.job_process.share_cpus)."""

from __future__ import annotations

import os

import pytest

from worker import main as worker_main
from worker.job_process import JOB_CPUS, job_cpus, share_cpus


@pytest.fixture
def clean_environment(monkeypatch):
    for name in ("OPENBLAS_NUM_THREADS", JOB_CPUS, "FNSI_BROKER_URL"):
        monkeypatch.setenv(name, "")     # recorded, so that what the tests set is undone
        monkeypatch.delenv(name)
    monkeypatch.setattr(os, "cpu_count", lambda: 8)


def test_the_cpus_are_divided_among_the_concurrent_jobs(clean_environment):
    assert job_cpus() is None            # no launcher: the library's defaults apply
    assert share_cpus(3) == 2
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2" and job_cpus() == 2


def test_more_jobs_than_cpus_still_get_one_each_and_a_given_value_is_kept(
        clean_environment, monkeypatch):
    assert share_cpus(20) == 1 and job_cpus() == 1
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    monkeypatch.setenv(JOB_CPUS, "3")
    share_cpus(1)
    assert os.environ["OPENBLAS_NUM_THREADS"] == "4" and job_cpus() == 3


def test_fnsi_worker_gives_each_pool_process_its_share(clean_environment):
    # a worker of 4 processes on 8 CPUs: a diagnosis validates its candidates on 2 threads
    with pytest.raises(SystemExit):      # no broker configured: it stops after sharing
        worker_main.main(["--concurrency", "4"])
    assert job_cpus() == 2
