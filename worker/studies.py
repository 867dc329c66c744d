"""Study jobs: create a study (revision 0), add a revision, diagnose a revision.

Each job loads the study from the store, calls :mod:`fnsi.study` / :mod:`fnsi.diagnosis`,
and writes figures and JSON as artefacts. Creation and revisions change the study: they
run in the order requested (a job waits for the revisions requested before it), under
the study's lock, and save a new snapshot only when complete. A re-run attempt of a
revision whose snapshot was already saved only redraws its artefacts.

Artefacts of a revision job: ``history.png``, ``revision-<n>-comparison.png``,
``revision-<n>-residual-spectra.png``, ``revision-<n>-residual-map.png`` (when the model
could be simulated) and ``revision-<n>.json`` (errors per channel and DFT line). Of a
diagnosis job: ``stiffness.png`` (curves at the top locations), ``candidates.png``,
``screening.png``, ``history.png`` and ``diagnosis.json``.
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Any

from fnsi.diagnosis import DiagnosisSettings
from fnsi.report import strict_json
from fnsi.study import Study
from fnsi.study_plots import diagnosis_figures, plot_history, study_figures
from service.study_store import StudyStore
from worker.identifications import settings_of
from worker.job_process import job_cpus
from worker.runner import JobContext


def _revision_result(context: JobContext, study: Study, number: int) -> dict[str, Any]:
    """Store the artefacts of revision ``number``; the job result (no spectra)."""
    revision = study.revisions[number]
    for name, content in study_figures(study, number).items():
        context.store.write_artefact(context.job.id, name, content)
    detail = strict_json(revision.to_json(spectra=revision.errors is not None))
    context.store.write_artefact(context.job.id, f"revision-{number}.json",
                                 json.dumps(detail).encode())
    return {"study_id": context.job.request["study_id"], "revision": number,
            "revision_summary": strict_json(revision.to_json()),
            "history": strict_json(study.history()), "warnings": study.warnings}


def _change(context: JobContext, change) -> dict[str, Any]:
    """Apply ``change(study or None, progress) -> Study`` under the study's lock, in
    request order, and save the result (or only redraw, on a re-run that saved)."""
    studies = StudyStore(context.store)
    job = context.job
    study_id = job.request["study_id"]
    # Waiting reports progress: the lease stays alive and a cancel request stops the wait.
    studies.wait_for_earlier_revisions(job, lambda message: context.progress(0.0, message))
    with studies.locked(study_id, lambda: context.progress(0.0, "waiting for the study")):
        loaded = studies.load(study_id)
        study, producers = loaded if loaded is not None else (None, [])
        if job.id in producers:   # an earlier attempt saved this revision, then died
            return _revision_result(context, study, producers.index(job.id))
        study = change(study, lambda f, m: context.progress(0.85 * f, m))
        context.progress(0.9, "saving the study")
        studies.save(study_id, study, [*producers, job.id])
    context.progress(0.95, "drawing figures")
    return _revision_result(context, study, len(study.revisions) - 1)


def create_study_job(context: JobContext) -> dict[str, Any]:
    """Identify and validate revision 0 of a new study (request: StudyRequest + study_id)."""
    request = context.job.request
    store = context.store

    def create(_: None, progress) -> Study:
        return Study.create(store.load_measurement(request["dataset_id"]),
                            store.load_measurement(request["validation_dataset_id"]),
                            settings_of(request, context.settings.memory_limit_mb),
                            connections=[tuple(p) for p in request["connections"]],
                            name=request["name"], note=request["note"], progress=progress)

    return _change(context, create)


def revise_study_job(context: JobContext) -> dict[str, Any]:
    """Add a revision (request: RevisionRequest + study_id)."""
    request = context.job.request

    def revise(study: Study | None, progress) -> Study:
        if study is None:
            raise ValueError("the study has no starting model: its creation job failed; "
                             "see that job's error and create the study again")
        base = -1 if request["base"] is None else request["base"]
        if base >= len(study.revisions):
            raise ValueError(f"base revision {base} does not exist; the study has revisions "
                             f"0..{len(study.revisions) - 1}")
        study.add_revision(add=request["add"], remove=request["remove"],
                           order=request["order"], note=request["note"], base=base,
                           progress=progress)
        return study

    return _change(context, revise)


def diagnose_study_job(context: JobContext) -> dict[str, Any]:
    """Rank candidate missing effects of a revision (request: DiagnosisRequest +
    study_id). Read-only: waits for the revisions requested before it, not for the lock."""
    studies, job = StudyStore(context.store), context.job
    request = job.request
    studies.wait_for_earlier_revisions(job, lambda message: context.progress(0.0, message))
    loaded = studies.load(request["study_id"])
    if loaded is None:
        raise ValueError("the study has no revision to diagnose: its creation job failed; "
                         "see that job's error and create the study again")
    study, _ = loaded
    number = len(study.revisions) - 1 if request["revision"] is None else request["revision"]
    if number >= len(study.revisions):
        raise ValueError(f"revision {number} does not exist; the study has revisions "
                         f"0..{len(study.revisions) - 1}")
    effort = DiagnosisSettings(**{k: v for k, v in request.items()
                                  if k not in ("study_id", "revision")})
    if (cpus := job_cpus()) is not None:   # the launcher's share, not the whole machine
        effort = replace(effort, workers=min(effort.workers, cpus))
    diagnosis = study.diagnose(number, effort, lambda f, m: context.progress(0.95 * f, m))
    context.progress(0.95, "drawing figures")
    figures = {"history.png": plot_history(study), **diagnosis_figures(diagnosis)}
    doc = strict_json(diagnosis.to_json())
    figures["diagnosis.json"] = json.dumps(doc).encode()
    for name, content in figures.items():
        context.store.write_artefact(job.id, name, content)
    return {"study_id": request["study_id"],
            **{k: doc[k] for k in ("revision", "nrmse_before_percent", "noise_floor_percent",
                                   "found", "summary", "candidates", "notes", "timings",
                                   "unexplained", "claim_rule")}}
