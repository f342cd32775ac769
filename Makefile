# The whole set-up on a fresh machine: `make demo`, then `make test`.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench docs mutation clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# torch first, from the local CPU wheel, so nothing resolves a CUDA build.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[test,docs]'
	touch $(STAMP)

demo: $(STAMP)
	rm -rf runs/demo
	$(BIN)/servogym tune --chip MC2100 --plant vertical-axis --budget 400 --tuner tpe \
		--workers 2 --out runs/demo

test: $(STAMP)
	$(BIN)/ruff check servogym tests experiments
	$(BIN)/python -m pytest -q -n 2 -m "not slow"

lint: $(STAMP)
	$(BIN)/ruff check servogym tests experiments
	$(BIN)/ruff format --check servogym tests experiments

bench: $(STAMP)
	$(BIN)/python experiments/bench_servo_loop.py
	$(BIN)/python experiments/bench_tuner_overhead.py
	$(BIN)/python experiments/bench_multiaxis.py

# The guides and the API reference from the docstrings (mkdocs + mkdocstrings) into site/;
# strict, so a broken link or reference fails.
docs: $(STAMP)
	$(BIN)/mkdocs build --strict --quiet
	@echo "wrote site/index.html"

# Mutation testing of the spec-bearing modules (docs/testing.md). Slow (hours for every
# mutant), resumable, not part of `make test`. Pass options through MUTATION, e.g.
#   make mutation MUTATION="pmd-filter sim-metrics --max-mutants 60"
MUTATION ?= --max-mutants 60
$(VENV)/.mutation-installed: $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[test,mutation]'
	touch $@

mutation: $(VENV)/.mutation-installed
	$(BIN)/python experiments/mutation.py $(MUTATION)

clean:
	rm -rf $(VENV) runs site .pytest_cache
