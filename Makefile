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

# Both run on two workers (pytest-xdist): every test has its own router on a free port and its
# own temporary folder; the numba kernels are compiled once before the workers start (edited
# kernels would otherwise compile in both at once; cached, this takes a second). Tests marked
# xdist_group("realtime") (real-time missions, dead-man deadlines, the flat-out load run) run
# one after another on one worker, never beside each other.
test: install
	bash scripts/install-test-deps
	$(MAKE) lint
	$(BIN)/shepherd compile
	$(BIN)/pytest -q -n 2 --dist loadgroup

# everything but the tests marked slow (end-to-end runs, the wheel install): a few minutes
test-fast: install
	bash scripts/install-test-deps
	$(MAKE) lint
	$(BIN)/shepherd compile
	$(BIN)/pytest -q -m "not slow" -n 2 --dist loadgroup

bench: install
	$(BIN)/shepherd bench

# the manual (MkDocs + Material) at http://127.0.0.1:8000, rebuilt as pages change
docs: install
	$(BIN)/mkdocs serve

clean:
	rm -rf $(VENV) build *.egg-info runs
