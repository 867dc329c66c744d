"""Hostile submissions (issue 19): requests that could only fail in a worker, or succeed
with garbage, are refused at submission with a 422 naming the fault, on their own route
and inside a batch alike; and an identification with nothing to show never succeeds.

Every refusal goes through :func:`check_refused`: the status, a detail naming the fault,
stored data byte-identical before and after, and the next request answered on the same
connection. Bodies are serialised by Python's ``json``, which writes ``NaN`` and
``Infinity`` as the JSON extensions a hostile client can send.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from fnsi.measurement import Measurement
from service.deps import get_owner
from service.settings import Settings
from service.store import Store
from tests.service.hostile.conftest import (
    IDENTIFY,
    OWNER,
    REC,
    Connection,
    Reply,
    Seeded,
    check_refused,
    seed,
    start_hostile_stack,
)
from tests.service.servers import wait_for_job
from tests.service.test_simulations import REQUEST as MODEL_SIMULATION

PRESET = {"preset": "single", "periods": 3, "samples_per_period": 2500}


@dataclass(frozen=True)
class Case:
    """A hostile job request: its kind, its body for the seeded dataset, and words the
    detail must contain."""

    kind: str  # "identification" or "simulation"
    body: Callable[[Seeded], dict[str, Any]]
    says: tuple[str, ...]


def identification(**changes: Any) -> Callable[[Seeded], dict[str, Any]]:
    return lambda s: {"dataset_id": s.dataset_id, **IDENTIFY, **changes}


def element(**spec: Any) -> Callable[[Seeded], dict[str, Any]]:
    return identification(elements=[{"dof": "NC2w_Z", "ref": "NC2b_Z", **spec}])


def model_simulation(change: Callable[[dict], object]) -> Callable[[Seeded], dict[str, Any]]:
    """The generic test simulation after ``change`` edited a copy of it in place."""
    def body(_: Seeded) -> dict[str, Any]:
        request = copy.deepcopy(MODEL_SIMULATION)
        change(request)
        return request
    return body


CASES: dict[str, Case] = {
    # "500s for spline knots containing a JSON NaN"
    "spline-knots-nan": Case("identification", element(kind="spline",
                                                       knots=[-1.0, math.nan, 1.0]),
                             ("knots", "finite number")),
    # "preset simulations with periods 1 or 2 (they fail on a discard_periods presets do
    # not expose)": the detail says how many the preset discards
    "preset-one-period": Case("simulation", lambda s: {**PRESET, "periods": 1},
                              ("preset 'single'", "periods=1", "2 transient periods",
                               "periods >= 3")),
    "preset-two-periods": Case("simulation", lambda s: {**PRESET, "periods": 2},
                               ("periods=2", "2 transient periods", "periods >= 3")),
    # "preset outputs: ["nope"] and fs_int=20001 (refused for model simulations, accepted
    # for presets)"
    "preset-unknown-output": Case("simulation", lambda s: {**PRESET, "outputs": ["nope"]},
                                  ("unknown output channel 'nope'", "'NC2w_Z'")),
    "preset-fs-int-not-a-multiple": Case("simulation", lambda s: {**PRESET, "fs_int": 20001.0},
                                         ("fs_int=20001", "integer multiple of fs=2500")),
    "model-fs-int-not-a-multiple": Case("simulation", model_simulation(
        lambda r: r.update(fs_int=4001.0)), ("fs_int=4001", "integer multiple of fs=500")),
    # "identification outputs naming a channel twice"
    "outputs-twice": Case("identification", identification(outputs=["NC2w_Z", "NC2w_Z"]),
                          ("outputs ['NC2w_Z'] are chosen more than once",)),
    "inputs-twice": Case("identification", identification(inputs=["force", "force"]),
                         ("inputs ['force'] are chosen more than once",)),
    # "polynomial exponent 1e9 or Infinity ("internal error (TypingError ...)")"
    "exponent-1e9": Case("identification", element(kind="polynomial", exponent=1e9),
                         ("exponent", "less than or equal to 10")),
    "exponent-infinity": Case("identification", element(kind="polynomial", exponent=math.inf),
                              ("exponent", "finite number")),
    # "a clearance given an exponent (silently ignored, though the schema says only a
    # kind's own parameters may be given)"
    "clearance-with-exponent": Case("identification", element(kind="clearance", gap=1.0,
                                                              exponent=3.0),
                                    ("['exponent'] are not parameters of a clearance",
                                     "'gap'")),
    # "a model simulation with a singular mass matrix"
    "singular-mass-matrix": Case("simulation", model_simulation(
        lambda r: r["model"].update(M=[[0.0, 0.0], [0.0, 1.0]])),
        ("mass matrix m must be positive definite", "singular")),
    # JSON NaN / Infinity in the other numbers of a request
    "band-nan": Case("identification", identification(band=[5.0, math.nan]),
                     ("band", "finite number")),
    "stiffness-infinity": Case("simulation", model_simulation(
        lambda r: r["model"]["K"][0].__setitem__(0, math.inf)), ("K", "finite number")),
    "force-rms-nan": Case("simulation", model_simulation(
        lambda r: r["excitation"]["inputs"][0].update(rms=math.nan)),
        ("rms", "finite number")),
}


def post_json(connection: Connection, path: str, body: Any) -> Reply:
    return connection.post(path, content=json.dumps(body).encode(),
                           headers={"content-type": "application/json"})


@pytest.mark.parametrize("route", ["own-route", "batch"])
@pytest.mark.parametrize("name", list(CASES))
def test_a_request_that_could_only_fail_is_refused_at_submission(seeded, name, route):
    case = CASES[name]

    def send(connection: Connection) -> Reply:
        body = case.body(seeded)
        if route == "batch":  # the batch's jobs pass the same checks, all or none
            return post_json(connection, "/v1/batches", {"jobs": [
                {"kind": "simulation", "request": PRESET},
                {"kind": case.kind, "request": body}]})
        return post_json(connection, f"/v1/{case.kind}s", body)

    check_refused(seeded, send, 422, case.says)


# -- the job side: never succeeded with an empty result ----------------------------------
@pytest.fixture(scope="module")
def legacy(tmp_path_factory) -> Iterator[Seeded]:
    """A stack of its own holding, besides the seeded record, the record scaled to values
    near 1e200 stored directly, as a dataset uploaded before uploads refused such values
    (its channel RMS overflow, so it stays off the shared catalogue's listings)."""
    stack = start_hostile_stack(tmp_path_factory.mktemp("legacy") / "data")
    try:
        seeded = seed(stack)
        huge = Measurement.from_arrays(1e200 * REC.u, 1e200 * REC.y, REC.fs,
                                       input_names=REC.input_names,
                                       output_names=REC.output_names, periods=REC.periods)
        owner = get_owner(Settings(api_keys=[OWNER]), OWNER)
        record = Store(stack.data_dir).put_measurement(huge, owner=owner, name="huge")
        yield Seeded(stack, record.id, seeded.job_id)
    finally:
        stack.stop()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_an_identification_of_values_near_1e200_fails_instead_of_succeeding_empty(legacy):
    """The issue's record "whose identification succeeds with 0 modes and every error
    null": the errors' squares overflow, and the job fails saying to rescale. Order 6 is
    explicit (the record's outputs are sines the automatic order finds no plateau in)."""
    with legacy.connect() as connection:
        submitted = post_json(connection, "/v1/identifications", {
            "dataset_id": legacy.dataset_id, **IDENTIFY, "order": 6})
        assert submitted.status == 202, submitted.text
        with legacy.stack.client(headers={"X-API-Key": OWNER}) as client:
            job = wait_for_job(client, submitted.json()["id"])
        assert job["state"] == "failed", job
        assert job["result"] is None
        assert "errors are NaN on every channel" in job["error"]
        assert "rescale the record" in job["error"]
        connection.assert_kept()
