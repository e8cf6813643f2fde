# Two entry points a new user needs: `make demo` and `make test`.
# Both create .venv and install the package on first use, so a fresh machine needs nothing else.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast lint clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m activetouch demo

test: $(STAMP)
	$(BIN)/ruff check activetouch tests benchmarks
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q

# While developing: everything but the tests marked slow (CI runs them all).
test-fast: $(STAMP)
	$(BIN)/ruff check activetouch tests benchmarks
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -q -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check activetouch tests benchmarks
	$(BIN)/ruff format --check activetouch tests benchmarks
	$(BIN)/lint-imports

clean:
	rm -rf $(VENV) build *.egg-info
