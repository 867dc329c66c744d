"""The FastAPI application: routers, error handling, limits and the job machinery."""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from fastapi_offline import FastAPIOffline

from service import problems
from service.limits import BodyLimitMiddleware
from service.problems import FieldError, Problem
from service.queue import Supervisor, make_queue
from service.routes import (
    analyses,
    artefacts,
    batches,
    datasets,
    health,
    identifications,
    jobs,
    simulations,
    studies,
)
from service.settings import Settings, get_settings
from service.store import Store

# Multipart framing and the meta field around the file [bytes].
_MULTIPART_SLACK = 1024 * 1024

TAGS = [
    {"name": "health", "description": "Is the service up."},
    {"name": "datasets", "description": "Measured or simulated input-output records."},
    {"name": "simulations", "description": "Simulated tests of the SmallSat structure."},
    {"name": "identifications", "description": "FNSI identification of nonlinear models."},
    {"name": "analyses", "description": "Nonlinear distortion levels before any model: "
     "is the structure nonlinear, how much, and of which law."},
    {"name": "batches", "description": "Many jobs in one request."},
    {"name": "jobs", "description": "Status, progress, results and cancellation of jobs."},
    {"name": "artefacts", "description": "Plots, JSON results and models of a job."},
    {"name": "studies", "description": "Modelling studies: revisions judged on validation "
     "data, their error history, and diagnoses of what a model lacks."},
]


def operation_id(route: APIRoute) -> str:
    """Stable operationId: the handler's name (create_dataset, get_job, ...)."""
    return route.name


def _mark_binary(component: dict[str, Any]) -> None:
    """Add ``format: binary`` to file fields: OpenAPI 3.1 ``contentMediaType`` alone makes
    client generators (openapi-python-client) treat an upload as a plain string."""
    for field in component.get("properties", {}).values():
        if field.get("type") == "string" and "contentMediaType" in field:
            field["format"] = "binary"


def _openapi(app: FastAPI) -> dict[str, Any]:
    if app.openapi_schema is None:
        # One schema per model: a request shape served back (a job's request, a study's
        # definition, an identified element to post as `add`) keeps its name and fields in
        # generated clients, instead of an untyped "-Output" twin.
        schema = get_openapi(title=app.title, version=app.version, description=app.description,
                             routes=app.routes, tags=app.openapi_tags,
                             separate_input_output_schemas=False)
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in (Problem, FieldError):
            components[model.__name__] = model.model_json_schema(
                ref_template="#/components/schemas/{model}")
        for component in components.values():
            _mark_binary(component)
        for operation in (op for path in schema["paths"].values() for op in path.values()):
            if operation.get("security"):
                operation["security"].append({})  # the key is needed only with FNSI_API_KEYS
        app.openapi_schema = schema
    return app.openapi_schema


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API for ``settings`` (default: from the FNSI_* environment)."""
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = Store.from_settings(settings)
        queue = make_queue(settings, store)
        supervisor = Supervisor(settings, store, queue)
        app.state.settings, app.state.store, app.state.queue = settings, store, queue
        supervisor.check()  # jobs a previous process left running
        queue.start()
        supervisor.start()
        try:
            yield
        finally:
            supervisor.stop()
            queue.stop()

    # /docs and /redoc with Swagger UI and ReDoc served from a package, no CDN or web
    # fonts: lab networks often have no internet.
    app = FastAPIOffline(
        title="fnsi-service",
        description="Frequency-domain nonlinear subspace identification (FNSI) of nonlinear "
        "structures: upload measurements, simulate tests, identify models, fetch plots. "
        "Errors are application/problem+json (RFC 9457).",
        version=health._version(),
        openapi_tags=TAGS,
        generate_unique_id_function=operation_id,
        lifespan=lifespan,
    )
    app.add_middleware(BodyLimitMiddleware, default=settings.max_request_bytes,
                       uploads=settings.max_upload_bytes + _MULTIPART_SLACK,
                       upload_routes=frozenset({("POST", "/v1/datasets")}))
    problems.install(app)
    app.include_router(health.router)
    app.include_router(datasets.router, form_limits={"max_files": 1, "max_fields": 1,
                                    "max_part_size": settings.max_meta_bytes})
    for module in (simulations, identifications, analyses, batches, jobs, artefacts, studies):
        app.include_router(module.router)
    app.openapi = lambda: _openapi(app)
    return app
