# Two commands on a fresh machine with Python >= 3.11: `make run` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: run worker test test-numerics lint bench bench-paper bench-determinism clean

## run: create the virtual environment, install, serve http://127.0.0.1:8000 (embedded jobs)
run: $(VENV)/.installed
	$(BIN)/fnsi-service $(ARGS)

## worker: start one Celery worker (needs FNSI_BROKER_URL=redis://...)
worker: $(VENV)/.installed
	$(BIN)/fnsi-worker $(ARGS)

## test: install the dev extra, lint, and run the whole suite (starts a Redis if none answers)
test: $(VENV)/.installed-dev
	$(BIN)/ruff check .
	$(BIN)/python -m pytest $(PYTEST_ARGS)

## test-numerics: the numerical tests alone, to run under another BLAS kernel, e.g.
## OPENBLAS_CORETYPE=SkylakeX OPENBLAS_NUM_THREADS=2 make test-numerics on an AVX-512 CPU,
## Sandybridge on others (CI does, see .ci/run)
test-numerics: $(VENV)/.installed-dev
	$(BIN)/python -m pytest tests/fnsi tests/benchmarks $(PYTEST_ARGS)

lint: $(VENV)/.installed-dev
	$(BIN)/ruff check .

## bench: timing benchmarks of the FNSI stages, the Newmark integrator and the refinement
bench: $(VENV)/.installed-dev
	$(BIN)/python benchmarks/fnsi_scaling.py
	$(BIN)/python benchmarks/newmark.py
	$(BIN)/python benchmarks/refinement.py

## bench-determinism: spread of the headline numbers over BLAS kernels and threads
## against their spread over noise realisations (benchmarks/results/determinism.md)
bench-determinism: $(VENV)/.installed-dev
	$(BIN)/python benchmarks/determinism.py

## bench-paper: reproduce the paper's Section IV and write benchmarks/results/paper.md
bench-paper: $(VENV)/.installed-dev
	$(BIN)/python benchmarks/paper.py

$(VENV)/.python-ok:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
	  { echo "fnsi-service needs Python >= 3.11; set PYTHON=python3.11"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	touch $@

# constraints.txt pins every version, so both commands install what the tests passed with
$(VENV)/.installed: $(VENV)/.python-ok pyproject.toml constraints.txt
	$(BIN)/python -m pip install --quiet -c constraints.txt -e .
	touch $@

$(VENV)/.installed-dev: $(VENV)/.python-ok pyproject.toml constraints.txt
	$(BIN)/python -m pip install --quiet -c constraints.txt -e '.[dev]'
	touch $@ $(VENV)/.installed

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
