# One-command dev loop. `make run` installs and runs the simulated mission; `make test`
# installs the dev tools (and the Debian packages some tests use, when run as root) and runs
# lint (ruff, mypy) and the whole suite (the manual's strict build and checks included);
# `make test-fast` leaves out the slow tests; `make docs` serves the manual. All use a
# virtual environment in .venv.
PYTHON ?= python3
VENV ?= .venv
BIN = $(VENV)/bin

$(BIN)/shepherd: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	$(BIN)/shepherd compile
	touch $@

.PHONY: install run test test-fast lint bench docs clean
install: $(BIN)/shepherd

run: install
	$(BIN)/shepherd run

lint: install
	$(BIN)/ruff check schemas services tests
	$(BIN)/mypy schemas services tests

test: install
	bash scripts/install-test-deps
	$(MAKE) lint
	$(BIN)/pytest -q

# everything but the tests marked slow (end-to-end runs, the wheel install), on both cores:
# under a minute
test-fast: install
	bash scripts/install-test-deps
	$(MAKE) lint
	$(BIN)/pytest -q -m "not slow" -n 2

bench: install
	$(BIN)/shepherd bench

# the manual (MkDocs + Material) at http://127.0.0.1:8000, rebuilt as pages change
docs: install
	$(BIN)/mkdocs serve

clean:
	rm -rf $(VENV) build *.egg-info runs
