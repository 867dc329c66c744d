"""``fnsi-worker``: a Celery worker that runs fnsi jobs from the broker in FNSI_BROKER_URL."""

from __future__ import annotations

import argparse
import os

from worker.job_process import share_cpus


def main(argv: list[str] | None = None) -> None:
    """Start a Celery worker with the settings of the FNSI_* environment."""
    parser = argparse.ArgumentParser(
        prog="fnsi-worker",
        description="Run fnsi jobs (simulations, identifications) queued by fnsi-service. "
        "Needs FNSI_BROKER_URL (e.g. redis://127.0.0.1:6379/0) and the same FNSI_DATA_DIR "
        "as the API.")
    parser.add_argument("--concurrency", type=int, default=os.cpu_count() or 1,
                        help="parallel jobs (pool processes); default: number of CPUs")
    parser.add_argument("--loglevel", default="INFO", help="log level (default INFO)")
    parser.add_argument("--hostname", default=None, help="worker node name (Celery -n)")
    args = parser.parse_args(argv)

    # before numpy loads: concurrent jobs share the cores instead of oversubscribing them
    share_cpus(args.concurrency)
    from service.settings import get_settings

    settings = get_settings()
    if not settings.broker_url:
        parser.error("FNSI_BROKER_URL is not set; without a broker fnsi-service runs jobs "
                     "itself and no worker is needed")
    from worker.celery_app import app

    worker_args = ["worker", f"--loglevel={args.loglevel}", f"--concurrency={args.concurrency}",
                   "--pool=prefork", f"--queues={settings.queue_name}", "--without-gossip",
                   "--without-mingle"]
    if args.hostname:
        worker_args.append(f"--hostname={args.hostname}")
    app.worker_main(worker_args)


if __name__ == "__main__":
    main()
