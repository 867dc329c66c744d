"""Controls of the hostile catalogue's machinery: a refusal the service already gives
passes every check, and an accepted upload is seen by the fingerprint."""

from __future__ import annotations

from tests.service.hostile.conftest import REC, check_refused, fingerprint, npz_bytes, settle


def test_a_known_refusal_passes_every_check(seeded):
    check_refused(seeded, lambda c: c.post("/v1/identifications", content=b'{"dataset_id": ',
                                           headers={"content-type": "application/json"}),
                  422, ("json",))


def test_the_fingerprint_sees_an_accepted_upload_and_its_deletion(seeded):
    settle(seeded.stack)
    before = fingerprint(seeded.stack)
    with seeded.connect() as connection:
        reply = connection.post("/v1/datasets",
                                files={"file": ("other.npz", npz_bytes(y=2 * REC.y))})
        assert reply.status == 201, reply.text
        assert fingerprint(seeded.stack) != before
        deleted = connection.request("DELETE", f"/v1/datasets/{reply.json()['id']}")
        assert deleted.status in (200, 204), deleted.text
        connection.assert_kept()
    assert fingerprint(seeded.stack) == before
