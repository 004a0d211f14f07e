# The fleetbus image (compose.yaml's `setup`, `worker` and `api` services).
FROM python:3.12-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /app
COPY . .
# the server, the API and MongoDB, at the versions CI tested (requirements.lock)
RUN pip install -c requirements.lock ".[server,api,mongodb]" \
    && useradd --system --create-home --uid 10001 fleetbus \
    && mkdir -p /data/accounts \
    && chown -R fleetbus /data

USER fleetbus
# service credentials and local state (a named volume in compose.yaml)
ENV FLEETBUS_DATA_DIR=/data
CMD ["fleetbus", "worker"]
