# One image for the API and the workers (docker-compose.yml picks the command).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    MPLBACKEND=Agg \
    NUMBA_CACHE_DIR=/tmp/numba-cache \
    FNSI_DATA_DIR=/data

WORKDIR /app
COPY pyproject.toml README.md ./
COPY fnsi ./fnsi
COPY worker ./worker
COPY service ./service
RUN pip install --no-cache-dir . \
 && useradd --create-home --uid 1000 fnsi \
 && mkdir -p /data \
 && chown fnsi /data

USER fnsi
VOLUME ["/data"]
EXPOSE 8000
CMD ["fnsi-service", "--host", "0.0.0.0", "--port", "8000"]
