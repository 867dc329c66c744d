"""Simulation jobs: a simulated test becomes a new dataset; its truth the artefact
``truth.json``, kept apart from the measurement."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from service.schemas.simulations import StructuralModelSpec
from worker.runner import JobContext, Progress


def _excitation(spec: dict[str, Any], fs: float):
    """The Excitation of a generic simulation request: one signal per input."""
    from fnsi.excitation import Excitation, multisine, periodic_noise

    signals = []
    for j, force in enumerate(spec["inputs"]):
        common = {"realisations": spec["realisations"], "seed": spec["seed"] + j}
        if spec["signal"] == "multisine":
            signals.append(multisine(spec["samples_per_period"], fs, tuple(spec["band"]),
                                     force["rms"], lines=spec["lines"],
                                     detection=spec["detection"], **common))
        else:
            signals.append(periodic_noise(spec["samples_per_period"], fs, tuple(spec["band"]),
                                          force["rms"], **common))
    names = [f["name"] or "F_" + "+".join(f["direction"]) for f in spec["inputs"]]
    return Excitation(np.stack(signals, axis=2), fs, tuple(f["direction"] for f in
                                                           spec["inputs"]), tuple(names))


def _simulate_model(request: dict[str, Any], progress: Progress):
    from fnsi.acquisition import acquire

    model = StructuralModelSpec.model_validate(request["model"]).structural_model()
    return acquire(model, _excitation(request["excitation"], request["fs"]),
                   fs=request["fs"], fs_int=request["fs_int"], periods=request["periods"],
                   outputs=request["outputs"], quantity=request["quantity"],
                   noise_percent=request["noise_percent"],
                   noise_reference=request["noise_reference"],
                   noise_band=tuple(request["noise_band"]),
                   discard_periods=request["discard_periods"], seed=request["seed"],
                   progress=progress)


def _simulate_preset(request: dict[str, Any], progress: Progress):
    from fnsi.smallsat import simulate_preset

    return simulate_preset(request["preset"], periods=request["periods"],
                           samples_per_period=request["samples_per_period"],
                           rms=request["rms"], seed=request["seed"],
                           noise_percent=request["noise_percent"],
                           outputs=request["outputs"], quantity=request["quantity"],
                           fs=request["fs"], fs_int=request["fs_int"], progress=progress)


def simulate_job(context: JobContext) -> dict[str, Any]:
    """Run a simulation request; result ``{"dataset_id": ...}``."""
    store, job = context.store, context.job
    request = job.request
    simulate = _simulate_model if "model" in request else _simulate_preset
    measurement, truth = simulate(request, context.progress)
    store.write_artefact(job.id, "truth.json", json.dumps(truth.to_json(), indent=1).encode())
    label = request.get("preset") or "model"
    record = store.put_measurement(measurement, owner=job.owner, source_job=job.id,
                                   name=request["name"] or f"{label} simulation {job.id}")
    return {"dataset_id": record.id}
