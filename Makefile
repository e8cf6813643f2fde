# Two entry points a new user needs: `make demo` and `make test`.
# Both create .venv and install the package on first use, so a fresh machine needs nothing else.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-fast lint clean browser

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m activetouch demo

# The live view's browser test needs Debian's Chromium (a system package, so not in .venv):
# installed when make runs as root with apt-get, else the test is skipped with a note.
browser:
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null || \
	{ [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  { apt-get install -y -q chromium >/dev/null 2>&1 || \
	    { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q chromium >/dev/null 2>&1; }; }; } || \
	echo "note: no chromium here; the live view's browser test is skipped (apt-get install chromium)"

test: $(STAMP) browser
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
