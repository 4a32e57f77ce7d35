# All set-up lives here: a fresh machine needs only `make demo` or `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TORCH := torch==2.13.0
export PYTHONUNBUFFERED := 1

.PHONY: install demo test test-fast lint format typecheck bench screenshot clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip setuptools wheel
	# The CPU build of torch first, pinned: an unpinned torch pulls several GB of CUDA packages.
	$(BIN)/pip install -q $(TORCH)
	$(BIN)/pip install -q -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/python examples/demo.py

test: install
	# Debian's chromium and postgresql, once, before any test process starts.
	$(BIN)/python tests/system_packages.py
	# Three test processes on two cores: they keep both busy (99% of the CPU outside a
	# run's last two minutes, 90% over the whole run, on this project's 2-core machine).
	# Bytecode caches on (some machines set PYTHONDONTWRITEBYTECODE): else each of the
	# three processes compiles and assert-rewrites every test module again, 12 CPU-s each.
	# Then the tests that measure latency (marked `alone`), with nothing beside them.
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -n 3 --dist loadgroup -q --durations=30 \
		-m "not alone"; status=$$?; \
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -m alone || status=1; \
	exit $$status

test-fast: install
	$(BIN)/python -m pytest -q -m "not slow and not browser and not postgres"

lint: install
	$(BIN)/ruff check client service workers tests bench
	$(BIN)/ruff format --check client service workers tests bench

format: install
	$(BIN)/ruff format client service workers tests bench
	$(BIN)/ruff check --fix client service workers tests bench

typecheck: install
	$(BIN)/mypy client/adclient service/adservice workers/adworker

screenshot: install
	$(BIN)/python docs/screenshot.py

clean:
	rm -rf $(VENV) var .pytest_cache .mypy_cache .ruff_cache
