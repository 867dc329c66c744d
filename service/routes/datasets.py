"""Datasets: upload (npz, csv, mat, h5, uff), list, summary, download, delete."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, File, Form, Query, UploadFile
from fastapi.responses import Response
from pydantic import ValidationError

from fnsi.formats import DecodeLimitError, DecodeLimits, ReadOptions, format_of, read_measurement
from service.deps import ApiKeyDep, OwnDatasetDep, SettingsDep, StoreDep
from service.downloads import file_download
from service.pagination import (
    PageCursor,
    PageLimit,
    cursor_position,
    sequence_number,
    split_page,
)
from service.problems import ERROR_RESPONSES, ProblemError
from service.schemas.datasets import (
    Dataset,
    DatasetListItem,
    DatasetPage,
    DownloadFormat,
    UploadMeta,
)
from service.store import DatasetRecord, Store

router = APIRouter(prefix="/v1/datasets", tags=["datasets"], responses=ERROR_RESPONSES)

_CHUNK = 1024 * 1024


def _described(record: DatasetRecord) -> dict:
    """Every field the dataset views take from a stored record."""
    return {"id": record.id, "name": record.name, "created_at": record.created_at,
            "size_bytes": record.size_bytes, "source_job": record.source_job,
            "n_inputs": len(record.summary["inputs"]),
            "n_outputs": len(record.summary["outputs"]), **record.summary}


def dataset_view(record: DatasetRecord) -> Dataset:
    """Public view of a stored dataset."""
    return Dataset(**_described(record))


def dataset_item(record: DatasetRecord) -> DatasetListItem:
    """Listing view of a stored dataset: its shape and channel counts, not its channels
    (a page stays small whatever the datasets hold)."""
    return DatasetListItem(**{k: v for k, v in _described(record).items()
                              if k in DatasetListItem.model_fields})


def _parse_meta(meta: str | None) -> UploadMeta:
    if not meta:
        return UploadMeta()
    try:
        return UploadMeta.model_validate_json(meta)
    except ValidationError as err:
        problems = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'meta'}: {e['msg']}"
                             for e in err.errors(include_input=False))
        raise ProblemError(422, f"meta must be a JSON object of UploadMeta: {problems}") from None


def _spool(upload: UploadFile, store: Store, limit: int) -> tuple[str, Path]:
    """Copy the upload into the store's tmp folder while hashing it."""
    digest = hashlib.sha256()
    path = store.temp_path()
    size = 0
    try:
        with open(path, "wb") as out:
            while chunk := upload.file.read(_CHUNK):
                size += len(chunk)
                if size > limit:
                    raise ProblemError(413, f"the file exceeds the upload limit of {limit} "
                                       "bytes (FNSI_MAX_UPLOAD_BYTES); send a shorter record")
                digest.update(chunk)
                out.write(chunk)
        if size == 0:
            raise ProblemError(422, "the uploaded file is empty; send the dataset in field "
                               "`file`")
    except BaseException:
        path.unlink(missing_ok=True)
        raise
    return digest.hexdigest(), path


@router.post("", status_code=201, response_model=Dataset, summary="Upload a dataset")
def create_dataset(
    store: StoreDep, owner: ApiKeyDep, settings: SettingsDep,
    file: Annotated[UploadFile, File(description="The dataset: .npz (canonical), .csv, .mat "
                                     "(v5 or v7.3), .h5 or .uff (58/58b records).")],
    meta: Annotated[str | None, Form(description="Optional JSON object (UploadMeta): name, "
                                     "format, fs [Hz], inputs, outputs, periods, quantity, "
                                     "units, group. "
                                     "CSV needs inputs, and fs unless it has a time column.",
                                     examples=['{"fs": 2500, "inputs": ["force"]}'])] = None,
) -> Dataset:
    """Upload a measurement; it is validated and summarised now (channels, RMS, SNR).

    Identical content with identical meta is stored once: re-uploading it only creates a
    new dataset id, without parsing the file again.
    """
    options = _parse_meta(meta)
    try:
        fmt = format_of(file.filename or "", options.format)
    except ValueError as err:
        raise ProblemError(422, f"{err} (the upload's meta.format)") from None
    name = options.name or file.filename or f"upload.{fmt}"
    raw_digest, path = _spool(file, store, settings.max_upload_bytes)
    try:
        reading = options.model_dump_json(exclude={"name"})
        upload_key = hashlib.sha256(f"{raw_digest}|{fmt}|{reading}".encode()).hexdigest()
        record = store.dataset_for_upload(upload_key, owner, name)
        if record is None:
            read = ReadOptions(fs=options.fs, periods=options.periods, quantity=options.quantity,
                               inputs=tuple(options.inputs) if options.inputs else None,
                               outputs=tuple(options.outputs) if options.outputs else None,
                               units=options.units, group=options.group)
            limits = DecodeLimits(settings.max_decoded_bytes, settings.max_channels)
            try:
                measurement, periods_source = read_measurement(path, fmt, read, limits)
            except DecodeLimitError as err:
                raise ProblemError(413, f"{err} (FNSI_{err.limit_name.upper()} = "
                                   f"{err.limit})") from None
            except ValueError as err:
                raise ProblemError(422, f"not a valid {fmt} dataset: {err}") from None
            record = store.put_measurement(measurement, owner=owner, name=name,
                                           periods_source=periods_source, upload_key=upload_key)
    finally:
        path.unlink(missing_ok=True)
    return dataset_view(record)


@router.get("", response_model=DatasetPage, summary="List datasets")
def list_datasets(store: StoreDep, owner: ApiKeyDep, limit: PageLimit = 50,
                  cursor: PageCursor = None) -> DatasetPage:
    """The caller's datasets (uploaded and simulated), newest first, one page at a time;
    each with its channel counts (GET one dataset for its channels)."""
    before = cursor_position(cursor, "dataset", sequence_number)
    records = store.list_datasets(owner, before_seq=before, limit=limit + 1)
    page, next_cursor = split_page(records, limit, "dataset", lambda r: str(r.seq))
    return DatasetPage(items=[dataset_item(r) for r in page], next_cursor=next_cursor)


@router.get("/{dataset_id}", response_model=Dataset, summary="Get a dataset's summary")
def get_dataset(dataset: OwnDatasetDep) -> Dataset:
    """Channels, sampling rate, periods, RMS and SNR of a dataset."""
    return dataset_view(dataset)


@router.get("/{dataset_id}/download", summary="Download a dataset", response_class=Response,
            responses={200: {"description": "The dataset file.", "content": {
                "application/octet-stream": {"schema": {"type": "string", "format": "binary"}},
                "text/csv": {"schema": {"type": "string", "format": "binary"}}}}})
def download_dataset(
    dataset: OwnDatasetDep, store: StoreDep,
    format: Annotated[DownloadFormat, Query(
        description="npz (canonical) or csv (one realisation, inputs then outputs)")
    ] = DownloadFormat.NPZ,
) -> Response:
    """The dataset as the canonical NPZ or as CSV (rendered on the first CSV download,
    then kept)."""
    stem = dataset.name.rsplit(".", 1)[0] or dataset.id
    if format == DownloadFormat.CSV:
        try:
            file = store.open_csv(dataset)
        except ValueError as err:
            raise ProblemError(422, str(err)) from None
        media_type = "text/csv"
    else:
        file, media_type = store.open_blob(dataset), "application/octet-stream"
    if file is None:
        raise ProblemError(404, f"dataset {dataset.id} does not exist: it was deleted as this "
                           "download began")
    return file_download(file, media_type, f"{stem}.{format.value}")


@router.delete("/{dataset_id}", status_code=204, summary="Delete a dataset",
               response_class=Response)
def delete_dataset(dataset: OwnDatasetDep, store: StoreDep) -> None:
    """Delete a dataset (jobs that already used it keep their results)."""
    store.delete_dataset(dataset.id)

