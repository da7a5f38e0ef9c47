# Every target creates the virtual environment and installs what it needs on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench fuzz clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	# byte-compile the package as pip does for a regular install: an editable install leaves
	# it to the first import, which writes nothing where PYTHONDONTWRITEBYTECODE is set, and
	# then every command compiles its 50-odd modules again (0.14 s of the demo's CPU: issue 16)
	$(BIN)/python -m compileall -q src
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/nonprehensile demo

test: $(STAMP)
	# two processes (pytest-xdist): the machines have 2 cores, and the suite stays under 5
	# minutes (one process: 236-313 s; two: 154-221 s)
	# (--dist loadgroup: the tests of the demo's session run share one worker, conftest.py)
	$(BIN)/python -m pytest -n 2 --dist loadgroup

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks examples docs
	$(BIN)/mypy

bench: $(STAMP)
	# the clustering benchmark reads real motion datasets shipped in these packages' data
	# files; it never imports them, so their heavy dependencies (numba, pandas) are skipped
	$(BIN)/python -m pip install --quiet --no-deps sktime==1.2.0 aeon==1.6.0 tslearn==0.10.0
	# river's streaming clusterers are anchors of the clustering benchmark (skipped if absent)
	$(BIN)/python -m pip install --quiet river==0.26.1 || echo "river not installed: its anchors are skipped"
	$(BIN)/python -m benchmarks

fuzz: $(STAMP)
	# >= 10,000 generated and mutated inputs through the CLI on 2 processes, and 3,200 HTTP
	# requests to the service over SQLite and PostgreSQL with 12 SIGKILLs (docs/robustness.md)
	$(BIN)/python tests/fuzz_harness.py --budget 10000 --jobs 2 --http-budget 3200 --report fuzz-report.json

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info .pytest_cache .mypy_cache .ruff_cache report fuzz-report.json
