"""Hostile requests to the job machinery that are refused at submission (the catalogue's
``check_refused``). The process-level cases of job execution (an API killed under its
job processes, a broker down, a foreign worker, the requeue order) are in
tests/service/test_restart.py, tests/service/test_faults.py and tests/worker/.
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest

from tests.service.hostile.conftest import (
    IDENTIFY,
    OWNER,
    Seeded,
    check_refused,
    seed,
    start_hostile_stack,
)
from tests.service.servers import wait_for_job

# Working memory of FNSI [MiB] between the study's revision 0 (no element: about 0.13
# MiB on the record) and a revision adding three hinge basis functions (about 0.37 MiB).
MEMORY_LIMIT_MB = "0.25"
HINGES = {"kind": "piecewise_linear", "dof": "NC2w_Z", "ref": "NC2b_Z",
          "breakpoints": [0.1, 0.2, 0.3]}


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> Iterator[tuple[Seeded, str]]:
    """A hostile stack with a small FNSI_MEMORY_LIMIT_MB, seeded, with a study of the
    record whose revision 0 is computed."""
    stack = start_hostile_stack(tmp_path_factory.mktemp("execution") / "data",
                                FNSI_MEMORY_LIMIT_MB=MEMORY_LIMIT_MB)
    try:
        seeded = seed(stack)
        with httpx.Client(base_url=stack.url, timeout=60, headers={"X-API-Key": OWNER}) as c:
            study = c.post("/v1/studies", json={
                "name": "small", "dataset_id": seeded.dataset_id,
                "validation_dataset_id": seeded.dataset_id, **IDENTIFY, "order": 4}).json()
            (job,) = study["jobs"]
            final = wait_for_job(c, job["id"])
            assert final["state"] == "succeeded", final["error"]
        yield seeded, study["id"]
    finally:
        stack.stop()


def test_a_study_revision_above_the_memory_limit_is_refused_at_submission(small):
    seeded, study_id = small
    reply = check_refused(seeded, lambda c: c.post(f"/v1/studies/{study_id}/revisions",
                                                   json={"add": [HINGES]}),
                          422, ("add:", "MiB, above the limit", "basis functions"))
    assert "piecewise_linear" in reply.json()["detail"], reply.text


def test_a_revision_whose_base_is_pending_is_refused_on_what_it_adds(small):
    """Revision 2 is requested while revision 1 is pending (queued or running): its base
    is not known yet, but it holds at least the elements it adds, and those alone are
    above the limit. (Had revision 1 finished meanwhile, the check is exact instead.)"""
    seeded, study_id = small
    with seeded.connect() as connection:
        first = connection.post(f"/v1/studies/{study_id}/revisions", json={"order": 4})
        assert first.status == 202, first.text
        second = connection.post(f"/v1/studies/{study_id}/revisions", json={"add": [HINGES]})
        assert second.status == 422, second.text
        assert "MiB, above the limit" in second.json()["detail"]
        connection.assert_kept()
    with httpx.Client(base_url=seeded.stack.url, headers={"X-API-Key": OWNER}) as client:
        assert wait_for_job(client, first.json()["id"])["state"] == "succeeded"
