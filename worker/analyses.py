"""Distortion analysis jobs: :func:`fnsi.distortion.analyse_distortion` on a stored
dataset, its summary as the result, analysis.json and distortion.png as artefacts."""

from __future__ import annotations

import json
from typing import Any

from fnsi.distortion import analyse_distortion
from fnsi.plots import plot_distortion
from worker.runner import JobContext


def analyse_job(context: JobContext) -> dict[str, Any]:
    """Analyse the job's dataset (see AnalysisRequest)."""
    store, job, progress = context.store, context.job, context.progress
    request = job.request
    measurement = store.load_measurement(request["dataset_id"])
    if request["outputs"]:
        measurement = measurement.select(outputs=request["outputs"])
    progress(0.2, "best linear approximation and distortion levels")
    analysis = analyse_distortion(measurement, discard_periods=request["discard_periods"])
    progress(0.7, "distortion figure")
    document = analysis.to_json()
    store.write_artefact(job.id, "analysis.json", json.dumps(document, indent=2).encode())
    store.write_artefact(job.id, "distortion.png",
                         plot_distortion(analysis))
    return document
