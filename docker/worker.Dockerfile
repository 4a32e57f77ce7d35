# A simulation worker: `adworker` leases jobs from AD_SERVER_URL with the token AD_TOKEN.
# Build from the repository root: docker build -f docker/worker.Dockerfile -t activedesign-worker .
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# The CPU build of torch first, pinned: an unpinned torch pulls several GB of CUDA packages.
RUN pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

WORKDIR /opt/activedesign
COPY pyproject.toml README.md ./
COPY client client
COPY service service
COPY workers workers
RUN pip install ".[worker]"

RUN useradd --system --create-home --home-dir /home/activedesign activedesign
USER activedesign
WORKDIR /home/activedesign

# One job at a time per container: scale with `docker compose up --scale worker=N`, or
# pass --concurrency N to use N cores of a bigger container.
CMD ["adworker", "--concurrency", "1", "--log-level", "info"]
