"""Modelling studies: create, read the error history, add revisions, diagnose."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Response

from fnsi.nonlinear import NonlinearElement
from fnsi.study import revised_elements
from service.deps import ApiKeyDep, QueueDep, SettingsDep, StoreDep, owned
from service.pagination import NOT_OURS, PageCursor, PageLimit, cursor_position, split_page
from service.problems import ERROR_RESPONSES, ProblemError
from service.queue import JobQueue
from service.schemas.jobs import Job
from service.schemas.studies import (
    Candidate,
    DiagnosisRequest,
    HistoryRow,
    Revision,
    RevisionArtefacts,
    RevisionRequest,
    Study,
    StudyDiagnosis,
    StudyJob,
    StudyPage,
    StudyRequest,
    StudySummary,
)
from service.store import DatasetRecord, JobRecord, JobState, Store
from service.study_store import STUDY_ID, StudyRecord, StudyStore
from service.submission import check_dimensions, check_request

router = APIRouter(prefix="/v1/studies", tags=["studies"], responses=ERROR_RESPONSES)
_CONFLICT = {409: ERROR_RESPONSES[422] | {"description": "Conflict"}}

# What estimation and validation data must share (summary keys, in words).
_SAME_SET_UP = (("inputs", "input channels"), ("outputs", "output channels"),
                ("fs", "sampling rate [Hz]"), ("quantity", "measured quantity"),
                ("units", "channel units"))


def _set_up(summary: dict) -> dict:
    """A dataset summary with its channels' units, "name [unit]" in order."""
    return summary | {"units": [f"{c['name']} [{c.get('unit') or 'not given'}]"
                                for c in summary["channels"]]}


def get_studies(store: StoreDep) -> StudyStore:
    """Studies of the running app."""
    return StudyStore(store)


StudiesDep = Annotated[StudyStore, Depends(get_studies)]


def own_study(study_id: Annotated[str, Path(description="Study id.")], studies: StudiesDep,
              owner: ApiKeyDep) -> StudyRecord:
    """The caller's study, or 404 (another key's study looks exactly like an unknown id)."""
    return owned(studies.get(study_id), owner, "study", study_id)


OwnStudyDep = Annotated[StudyRecord, Depends(own_study)]


def _check_pair(store: Store, request: StudyRequest) -> None:
    """Estimation and validation data of one set-up, and connections between outputs."""
    estimation: DatasetRecord = store.get_dataset(request.dataset_id)
    validation: DatasetRecord = store.get_dataset(request.validation_dataset_id)
    a, b = _set_up(estimation.summary), _set_up(validation.summary)
    for key, words in _SAME_SET_UP:
        if a[key] != b[key]:
            raise ProblemError(422, f"validation_dataset_id: datasets {estimation.id} and "
                               f"{validation.id} have different {words} ({a[key]} vs "
                               f"{b[key]}); validate on a record of the same test set-up")
    if b["periods"] - request.discard_periods < 1:
        raise ProblemError(422, f"validation_dataset_id: dataset {validation.id} has "
                           f"{b['periods']} periods and discard_periods={request.discard_periods}"
                           "; record more periods or discard fewer")
    outputs = request.outputs or a["outputs"]
    for k, pair in enumerate(request.connections):
        unknown = [name for name in pair if name not in outputs]
        if unknown:
            raise ProblemError(422, f"connections[{k}]: {unknown} are not outputs of the "
                               f"study; valid names are {outputs}")


def _check_elements(record: StudyRecord, store: Store, request: RevisionRequest) -> None:
    """Elements added must act on outputs of the study."""
    dataset = store.get_dataset(record.request["dataset_id"])
    outputs = record.request["outputs"] or (dataset.summary["outputs"] if dataset else None)
    if outputs is None:  # estimation data deleted: the job says so
        return
    for k, element in enumerate(request.add):
        for field, name in (("dof", element.dof), ("ref", element.ref)):
            if name is not None and name not in outputs:
                raise ProblemError(422, f"add[{k}].{field}: {name!r} is not an output of the "
                                   f"study; valid names are {outputs}")


def _revision_settings(studies: StudyStore, record: StudyRecord, outputs: list[str],
                       request: RevisionRequest,
                       ) -> tuple[tuple[NonlinearElement, ...], int | str] | None:
    """Elements and order of a requested revision, as far as known now. When its base is
    still to come (revisions requested before it are pending), only the added elements:
    the revision holds at least those. None when the request cannot apply to its base (the
    job says why, keeping the history)."""
    snapshot = studies.snapshot(record.id)
    revisions = snapshot.study["revisions"] if snapshot is not None else []
    pending = any(j.state in (JobState.QUEUED, JobState.RUNNING) and j.kind != "study_diagnosis"
                  for j in studies.jobs(record.id, record.owner))
    base = request.base if request.base is not None else (None if pending else -1)
    add = [e.model_dump(mode="json") for e in request.add]
    if base is None or base >= len(revisions):
        return (tuple(NonlinearElement.from_json(e) for e in add),
                request.order or record.request["order"])
    parent = revisions[base]
    remove = [r if isinstance(r, int) else r.model_dump(mode="json") for r in request.remove]
    try:
        elements, _, _ = revised_elements(
            [NonlinearElement.from_json(e) for e in parent["elements"]], outputs, add=add,
            remove=remove, parent_number=parent["number"])
    except ValueError:
        return None
    return elements, parent["identified_order"] if request.order is None else request.order


def _check_size(studies: StudyStore, record: StudyRecord, store: Store, request: RevisionRequest,
                memory_limit_mb: float) -> None:
    """Refuse now (422), as an identification is, a revision FNSI cannot compute on the
    study's data: working memory above FNSI_MEMORY_LIMIT_MB, too many basis functions
    for the data."""
    dataset = store.get_dataset(record.request["dataset_id"])
    if dataset is None:  # estimation data deleted: the job says so
        return
    revision = _revision_settings(studies, record, record.request["outputs"]
                                  or dataset.summary["outputs"], request)
    if revision is None:
        return
    elements, order = revision
    try:
        check_dimensions(dataset.summary, {**record.request, "order": order,
                                           "elements": [e.to_json() for e in elements]},
                         memory_limit_mb)
    except ValueError as err:
        raise ProblemError(422, f"add: the revision (elements {[e.name for e in elements]}, "
                           f"order {order}) cannot be identified on the study's data: "
                           f"{err}") from None


def _check_alive(studies: StudyStore, record: StudyRecord) -> None:
    """409 when the study has no revision and none is coming (its creation failed)."""
    jobs = studies.jobs(record.id, record.owner)
    if all(j.state in (JobState.FAILED, JobState.CANCELLED) for j in jobs
           if j.kind != "study_diagnosis"):
        raise ProblemError(409, f"study {record.id} has no revision and none is coming: its "
                           "creation job failed or was cancelled; see that job's error and "
                           "create the study again")


def _submit(store: Store, queue: JobQueue, record: StudyRecord, kind: str,
            request: dict[str, Any]) -> JobRecord:
    job = store.create_job(record.owner, kind, {"study_id": record.id, **request})
    queue.submit(job.id)
    return job


def _artefacts(store: Store, job_id: str) -> dict[str, str]:
    return {name: f"/v1/jobs/{job_id}/artefacts/{name}" for name, _ in
            store.list_artefacts(job_id)}


def _revision(store: Store, data: dict[str, Any], job_id: str) -> Revision:
    links = _artefacts(store, job_id)
    number = data["number"]
    figures = RevisionArtefacts(
        comparison=links.get(f"revision-{number}-comparison.png"),
        residual_spectra=links.get(f"revision-{number}-residual-spectra.png"),
        residual_map=links.get(f"revision-{number}-residual-map.png"),
        all=f"/v1/jobs/{job_id}/artefacts")
    return Revision(**data, job_id=job_id, artefacts=figures)


def _diagnosis(job: JobRecord) -> StudyDiagnosis:
    result = job.result or {}
    return StudyDiagnosis(job_id=job.id, state=job.state, revision=result.get("revision"),
                          found=result.get("found"), summary=result.get("summary"),
                          candidates=[Candidate(**c) for c in result.get("candidates", [])],
                          artefacts=f"/v1/jobs/{job.id}/artefacts")


def _view(store: Store, studies: StudyStore, record: StudyRecord) -> Study:
    snapshot = studies.snapshot(record.id)
    jobs = studies.jobs(record.id, record.owner)
    revisions, history, chart = [], [], None
    if snapshot is not None:
        revisions = [_revision(store, data, job_id) for data, job_id in
                     zip(snapshot.study["revisions"], snapshot.producers, strict=True)]
        history = [HistoryRow(**row) for row in snapshot.study["history"]]
        chart = _artefacts(store, snapshot.producers[-1]).get("history.png")
    return Study(
        id=record.id, name=record.name, created_at=record.created_at,
        definition=record.request, revisions=revisions,
        history=history, history_chart=chart,
        diagnoses=[_diagnosis(j) for j in jobs if j.kind == "study_diagnosis"],
        jobs=[StudyJob(id=j.id, kind=j.kind, state=j.state, message=j.message, error=j.error,
                       url=f"/v1/jobs/{j.id}") for j in jobs],
        report=None if snapshot is None else f"/v1/studies/{record.id}/report.html")


@router.post("", response_model=Study, status_code=202, summary="Create a study")
def create_study(request: StudyRequest, store: StoreDep, queue: QueueDep, owner: ApiKeyDep,
                 settings: SettingsDep, studies: StudiesDep, response: Response) -> Study:
    """Create a study and queue its revision 0: the starting model identified on the
    estimation data and judged on the validation data. Poll the study (or the job in
    `jobs`) until revision 0 appears in `revisions`."""
    check_request(store, owner, "identification", request, settings.memory_limit_mb)
    _check_pair(store, request)
    body = request.model_dump(mode="json")
    record = studies.create(owner, request.name, body)
    _submit(store, queue, record, "study", body)
    response.headers["Location"] = f"/v1/studies/{record.id}"
    return _view(store, studies, record)


def _summary(studies: StudyStore, record: StudyRecord) -> StudySummary:
    snapshot = studies.snapshot(record.id)
    latest = snapshot.study["history"][-1] if snapshot and snapshot.study["history"] else {}
    return StudySummary(id=record.id, name=record.name, created_at=record.created_at,
                        revisions=len(snapshot.study["revisions"]) if snapshot else 0,
                        nrmse_percent=latest.get("nrmse_percent"),
                        noise_floor_percent=latest.get("noise_floor_percent"),
                        url=f"/v1/studies/{record.id}")


def _study_position(position: str) -> tuple[str, str]:
    created_at, _, study_id = position.rpartition("|")
    if not created_at or not STUDY_ID.match(study_id):
        raise ValueError(NOT_OURS)
    return created_at, study_id


@router.get("", response_model=StudyPage, summary="List studies")
def list_studies(studies: StudiesDep, owner: ApiKeyDep, limit: PageLimit = 50,
                 cursor: PageCursor = None) -> StudyPage:
    """The caller's studies, newest first, each with its latest validation error."""
    before = cursor_position(cursor, "study", _study_position)
    records = studies.owned_by(owner, before=before, limit=limit + 1)
    page, next_cursor = split_page(records, limit, "study",
                                   lambda r: f"{r.created_at}|{r.id}")
    return StudyPage(items=[_summary(studies, r) for r in page], next_cursor=next_cursor)


@router.get("/{study_id}", response_model=Study, summary="Get a study")
def get_study(record: OwnStudyDep, store: StoreDep, studies: StudiesDep) -> Study:
    """The study's revisions with their validation errors (the error history, with a
    chart), its diagnoses with their ranked candidates, and its jobs."""
    return _view(store, studies, record)


@router.post("/{study_id}/revisions", response_model=Job, status_code=202,
             summary="Add a revision", responses=_CONFLICT)
def create_revision(request: RevisionRequest, record: OwnStudyDep, store: StoreDep,
                    queue: QueueDep, studies: StudiesDep, settings: SettingsDep) -> Job:
    """Queue a new revision: add or remove nonlinear elements, change the order. Its
    result names the revision number and the error history; its artefacts are the
    revision's figures. Revisions of a study run one at a time, in the order requested."""
    _check_alive(studies, record)
    _check_elements(record, store, request)
    _check_size(studies, record, store, request, settings.memory_limit_mb)
    return Job.of(_submit(store, queue, record, "study_revision",
                          request.model_dump(mode="json")))


@router.post("/{study_id}/diagnoses", response_model=Job, status_code=202,
             summary="Diagnose a revision", responses=_CONFLICT)
def create_diagnosis(request: DiagnosisRequest, record: OwnStudyDep, store: StoreDep,
                     queue: QueueDep, studies: StudiesDep) -> Job:
    """Queue a diagnosis: which physical effect the revision lacks, and where. Its result
    lists `candidates`, best first, each with `effect`, `element` (ready to POST as a
    revision's `add`, beside its `partner`'s element when it is claimed with one),
    `validation_nrmse_percent`, `error_reduction_factor` and `explanation`; its artefacts
    show stiffness curves at the top locations."""
    _check_alive(studies, record)
    return Job.of(_submit(store, queue, record, "study_diagnosis",
                          request.model_dump(mode="json")))


@router.get("/{study_id}/report.html", summary="The study's one-page report",
            response_class=Response, responses=_CONFLICT | {200: {
                "description": "A self-contained HTML page (figures embedded): the error "
                               "history, every revision and every diagnosis.",
                "content": {"text/html": {"schema": {"type": "string"}}}}})
def get_study_report(record: OwnStudyDep, studies: StudiesDep) -> Response:
    """The study on one printable page, as it stands now: error history with its chart,
    each revision's modes, coefficients, errors and figures, each diagnosis's ranked
    candidates, notes and figures. Images are embedded, so the page opens offline."""
    page = studies.report(record.id, record.owner)
    if page is None:
        raise ProblemError(409, f"study {record.id} has no revision yet: poll the study until "
                           "revision 0 appears in revisions, then ask again")
    return Response(page, media_type="text/html")
