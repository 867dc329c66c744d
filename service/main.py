"""``fnsi-service``: serve the HTTP API with uvicorn."""

from __future__ import annotations

import argparse


def main(argv: list[str] | None = None) -> None:
    """Parse --host/--port and serve the API (settings from the FNSI_* environment)."""
    parser = argparse.ArgumentParser(
        prog="fnsi-service",
        description="FNSI REST service. Jobs run on an embedded runner unless FNSI_BROKER_URL "
        "names a Celery broker served by fnsi-worker processes.")
    parser.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    parser.add_argument("--log-level", default="info", help="uvicorn log level (default info)")
    args = parser.parse_args(argv)

    from service.settings import get_settings
    from worker.job_process import share_cpus

    # embedded job processes inherit it: concurrent jobs share the cores
    share_cpus(get_settings().embedded_workers)

    import uvicorn

    from service.app import create_app

    app = create_app()
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    print(f"fnsi-service: interactive API docs at http://{shown}:{args.port}/docs "
          f"(jobs run {'on Celery workers' if get_settings().broker_url else 'embedded'})",
          flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level=args.log_level)


if __name__ == "__main__":
    main()
