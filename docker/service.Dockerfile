# The activedesign server: `adserver` on 0.0.0.0:8000, migrating its database at start.
# Build from the repository root: docker build -f docker/service.Dockerfile -t activedesign-service .

# The wheel, built from the source: it carries the Alembic migrations (as
# adservice/migrations) and the dashboard's files, so the image needs no source tree.
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

# The built wheel with the service extra (not editable: nothing of the source is here).
COPY --from=wheel /wheels /tmp/wheels
RUN pip install "$(ls /tmp/wheels/activedesign-*.whl)[service]" && rm -rf /tmp/wheels

# A fixed uid, so Kubernetes can check runAsNonRoot (deploy/k8s runs it as 10001).
RUN useradd --system --uid 10001 --create-home --home-dir /home/activedesign activedesign \
    && mkdir -p /data/artifacts \
    && chown -R activedesign /data
USER activedesign
WORKDIR /data

ENV AD_HOST=0.0.0.0 \
    AD_PORT=8000 \
    AD_ARTIFACT_DIR=/data/artifacts
EXPOSE 8000
VOLUME ["/data/artifacts"]
HEALTHCHECK --interval=10s --timeout=5s --start-period=30s --retries=6 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]
# Off loopback the server requires bearer tokens (AD_AUTH); create them with
# `adserver token create --role worker` (same AD_DATABASE_URL).
CMD ["adserver", "--host", "0.0.0.0", "--port", "8000", "--log-level", "info"]
