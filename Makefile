# The two commands: `make demo` and `make test`. Both create .venv and install foldcell into it.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
FOLDCELL := $(VENV)/bin/foldcell

.PHONY: demo test bench install clean

install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

demo: install
	$(FOLDCELL) demo --garment all

# lint and type-check first: a finding fails `make test` before the tests run
test: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy
	$(PY) -m pytest -q --durations=30

# `make bench` runs every benchmark; `make bench budget soak` runs those named (tests/bench/bench_*.py)
ifeq (bench,$(firstword $(MAKECMDGOALS)))
BENCHES := $(wordlist 2,$(words $(MAKECMDGOALS)),$(MAKECMDGOALS))
$(eval $(BENCHES):;@:)
endif

bench: install
	$(PY) -m tests.bench $(BENCHES)

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
