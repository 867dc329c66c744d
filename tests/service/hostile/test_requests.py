"""Hostile requests (issue 19, HTTP layer): cursors, methods, nesting and other tenants'
objects. Each case is refused with a 4xx problem naming the fault, leaves everything stored
byte-identical and costs the client nothing: the next request on the same keep-alive
connection is answered (see ``check_refused``)."""

from __future__ import annotations

import base64
import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import pytest
import uvicorn

from service.app import create_app
from service.limits import MAX_JSON_DEPTH
from service.settings import Settings
from tests.service.hostile.conftest import (
    IDENTIFY,
    INTRUDER,
    PROBLEM,
    Connection,
    Reply,
    Seeded,
    check_refused,
)
from tests.service.servers import free_port

Send = Callable[[Connection, Seeded], Reply]


@dataclass(frozen=True)
class Case:
    """A hostile request, the status it must get and words its detail must contain."""

    send: Send
    status: int
    says: tuple[str, ...]
    key: str | None = None  # None: the owner of the seeded objects


def cursor(text: str) -> str:
    """A cursor as this API encodes them (URL-safe base64, unpadded), of any content."""
    return base64.urlsafe_b64encode(text.encode()).decode().rstrip("=")


def get(path: str) -> Send:
    """GET ``path``; ``{d}`` and ``{j}`` stand for the seeded dataset and job."""
    return lambda c, s: c.get(path.format(d=s.dataset_id, j=s.job_id))


def method(verb: str, path: str) -> Send:
    return lambda c, s: c.request(verb, path.format(d=s.dataset_id, j=s.job_id))


def json_body(path: str, text: str) -> Send:
    """POST raw JSON text (``{d}``: the seeded dataset id)."""
    return lambda c, s: c.post(path, content=text.replace("{d}", s.dataset_id).encode(),
                               headers={"content-type": "application/json"})


def nested(depth: int, opening: str = "[", closing: str = "]", inner: str = "1") -> str:
    """A JSON value nested ``depth`` levels deep."""
    return opening * depth + inner + closing * depth


def identification_with_elements(elements: str) -> str:
    """An identification of the seeded dataset whose ``elements`` are ``elements``."""
    body = json.dumps({"dataset_id": "{d}", **IDENTIFY, "elements": "ELEMENTS"})
    return body.replace('"ELEMENTS"', elements)


CASES: dict[str, Case] = {
    # -- cursors that are no position of a list (a 30-digit integer overflowed SQLite: 500)
    "jobs-cursor-of-a-30-digit-integer": Case(get(f"/v1/jobs?cursor={cursor('job:' + '9' * 30)}"),
                                              422, ("cursor",)),
    "datasets-cursor-of-a-30-digit-integer": Case(
        get(f"/v1/datasets?cursor={cursor('dataset:' + '9' * 30)}"), 422, ("cursor",)),
    "jobs-cursor-one-past-the-largest-sqlite-integer": Case(
        get(f"/v1/jobs?cursor={cursor(f'job:{2**63}')}"), 422, ("cursor",)),
    "datasets-cursor-of-a-5000-digit-integer": Case(
        get(f"/v1/datasets?cursor={cursor('dataset:' + '9' * 5000)}"), 422, ("cursor",)),
    "jobs-cursor-of-a-negative-number": Case(get(f"/v1/jobs?cursor={cursor('job:-5')}"), 422,
                                             ("cursor",)),
    "jobs-cursor-of-zero": Case(get(f"/v1/jobs?cursor={cursor('job:0')}"), 422, ("cursor",)),
    "jobs-cursor-of-arabic-indic-digits": Case(get(f"/v1/jobs?cursor={cursor('job:٣٤')}"), 422,
                                               ("cursor",)),
    "jobs-cursor-of-base64-garbage": Case(get("/v1/jobs?cursor=%21%21%21%21"), 422,
                                          ("cursor",)),
    "jobs-cursor-of-the-datasets-list": Case(get(f"/v1/jobs?cursor={cursor('dataset:1')}"),
                                             422, ("cursor",)),
    "studies-cursor-without-a-study-id": Case(
        get(f"/v1/studies?cursor={cursor('study:2026-01-01|')}"), 422, ("cursor",)),
    # -- methods a path does not have (405, with Allow: see the test below)
    "patch-of-a-dataset": Case(method("PATCH", "/v1/datasets/{d}"), 405,
                               ("PATCH is not allowed", "DELETE or GET")),
    "put-on-the-job-list": Case(method("PUT", "/v1/jobs"), 405, ("PUT", "GET")),
    "post-to-a-job": Case(method("POST", "/v1/jobs/{j}"), 405, ("POST", "DELETE or GET")),
    # -- JSON nested deeply (100,000 levels got "There was an error parsing the body")
    "identification-nested-100000-arrays-deep": Case(
        json_body("/v1/identifications", nested(100_000)), 422,
        ("nested too deeply", "100000 levels", f"at most {MAX_JSON_DEPTH}")),
    "batch-nested-100000-objects-deep": Case(
        json_body("/v1/batches", nested(100_000, '{"a":', "}")), 422,
        ("nested too deeply", f"at most {MAX_JSON_DEPTH}")),
    "elements-one-level-beyond-the-limit": Case(
        json_body("/v1/identifications",
                  identification_with_elements(nested(MAX_JSON_DEPTH)),
                  ), 422, ("nested too deeply", f"{MAX_JSON_DEPTH + 1} levels")),
    "nesting-that-never-closes": Case(json_body("/v1/simulations", "[" * 5000), 422,
                                      ("nested too deeply", "5000 levels")),
    # -- another tenant's objects, by the routes this work added or changed
    "intruder-deletes-the-owners-finished-job": Case(method("DELETE", "/v1/jobs/{j}"), 404,
                                                     ("does not exist",), INTRUDER),
    "intruder-downloads-the-owners-dataset-as-csv": Case(
        get("/v1/datasets/{d}/download?format=csv"), 404, ("does not exist",), INTRUDER),
    "intruder-downloads-an-artefact-of-the-owners-job": Case(
        get("/v1/jobs/{j}/artefacts/result.json"), 404, ("does not exist",), INTRUDER),
}


@pytest.mark.parametrize("name", list(CASES))
def test_hostile_request_is_a_4xx_problem_on_a_kept_connection(seeded, name):
    case = CASES[name]
    kwargs = {} if case.key is None else {"key": case.key}
    check_refused(seeded, lambda c: case.send(c, seeded), case.status, case.says, **kwargs)


@pytest.mark.parametrize(("verb", "path", "allowed"), [
    ("PATCH", "/v1/datasets/{d}", "DELETE, GET"),
    ("PUT", "/v1/datasets", "GET, POST"),
    ("POST", "/v1/jobs/{j}", "DELETE, GET"),
    ("DELETE", "/v1/jobs/{j}/artefacts", "GET"),
    ("POST", "/health", "GET"),
])
def test_405_names_every_method_of_the_path_in_allow(seeded, verb, path, allowed):
    reply = check_refused(seeded, lambda c: method(verb, path)(c, seeded), 405, (verb,))
    assert reply.headers["allow"] == allowed


def test_an_empty_cursor_is_the_first_page(seeded):
    with seeded.connect() as connection:
        for route in ("/v1/jobs", "/v1/datasets", "/v1/studies"):
            first = connection.get(route)
            empty = connection.get(f"{route}?cursor=")
            assert empty.status == 200, empty.text
            assert empty.json() == first.json()
        connection.assert_kept()


@pytest.mark.parametrize(("body", "words"), [
    # exactly the limit: the body reaches validation, which names the field at fault
    (identification_with_elements(nested(MAX_JSON_DEPTH - 1)), "elements"),
    # brackets inside a string are text, not nesting
    (identification_with_elements(json.dumps(["[" * 10_000])), "elements"),
], ids=["at-the-limit", "brackets-in-a-string"])
def test_json_within_the_nesting_limit_reaches_validation(seeded, body, words):
    reply = check_refused(seeded, lambda c: json_body("/v1/identifications", body)(c, seeded),
                          422, (words,))
    assert "nested too deeply" not in reply.json()["detail"]


@pytest.fixture
def failing_server(tmp_path) -> Iterator[str]:
    """The API on uvicorn in this process, with one extra route (added here, not in the
    product) that raises an unexpected error; its URL."""
    app = create_app(Settings(data_dir=tmp_path / "data", broker_url=None))

    @app.get("/boom")
    def boom() -> None:
        raise ZeroDivisionError("a bug")

    server = uvicorn.Server(uvicorn.Config(app, port=free_port(), log_level="critical"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert time.monotonic() < deadline and thread.is_alive(), "uvicorn did not start"
        time.sleep(0.05)
    yield f"http://127.0.0.1:{server.config.port}"
    server.should_exit = True
    thread.join(timeout=30)


def test_an_unexpected_error_is_a_complete_500_on_a_kept_connection(failing_server, caplog):
    with Connection(failing_server, key=None) as connection:
        for _ in range(3):
            reply = connection.get("/boom")
            assert reply.status == 500
            assert reply.headers["content-type"] == PROBLEM
            assert "server log" in reply.json()["detail"]
            connection.assert_kept()
    logged = [r for r in caplog.records if r.name == "fnsi.service" and r.exc_info]
    assert logged and logged[0].exc_info[0] is ZeroDivisionError
