# A simulation worker: `adworker` leases jobs from AD_SERVER_URL with the token AD_TOKEN.
# Build from the repository root: docker build -f docker/worker.Dockerfile -t activedesign-worker .

# The wheel, built from the source (the same wheel as the server image's).
FROM python:3.11-slim AS wheel
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1
WORKDIR /src
COPY pyproject.toml setup.py MANIFEST.in README.md alembic.ini ./
COPY client client
COPY service service
COPY workers workers
COPY migrations migrations
RUN pip wheel --no-deps --wheel-dir /wheels .

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# The CPU build of torch first, pinned: an unpinned torch pulls several GB of CUDA packages.
RUN pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

# The built wheel with the worker extra.
COPY --from=wheel /wheels /tmp/wheels
RUN pip install "$(ls /tmp/wheels/activedesign-*.whl)[worker]" && rm -rf /tmp/wheels

# A fixed uid, so Kubernetes can check runAsNonRoot (deploy/k8s runs it as 10001).
RUN useradd --system --uid 10001 --create-home --home-dir /home/activedesign activedesign
USER activedesign
WORKDIR /home/activedesign

# One job at a time per container: scale with `docker compose up --scale worker=N`, or
# pass --concurrency N to use N cores of a bigger container.
CMD ["adworker", "--concurrency", "1", "--log-level", "info"]
