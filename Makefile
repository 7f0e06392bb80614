PY ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test bench bench-readme clean

$(BIN)/python:
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e .
	touch $@

$(VENV)/.installed-dev: pyproject.toml | $(BIN)/python
	$(BIN)/pip install -q -e '.[dev,learn,foxglove]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	$(BIN)/tether launch launch/sonar_localize.yaml --duration 20

# Two workers (CI has 2 cores), whole files to one worker so module fixtures are built once.
# This 2-core machine, quiet: serial 326 s, 2 workers 186 s, 3 workers 159 s (one run; more
# oversubscription for the timing-sensitive launch tests, so not the default: TEST_WORKERS=3).
TEST_WORKERS ?= 2

test: $(VENV)/.installed-dev
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile tests

bench: $(VENV)/.installed-dev
	$(BIN)/pip install -q -e '.[bench]'
	for b in bench/*.py; do $(BIN)/python $$b || exit 1; done

bench-readme: $(VENV)/.installed-dev
	$(BIN)/pip install -q -e '.[bench]'
	$(BIN)/python bench/readme.py --run
	$(BIN)/python bench/readme.py --write

clean:
	rm -rf $(VENV) out
