# aectorch developer entry points. `make train` and `make test` set everything up
# on first use (scripts/setup.sh is idempotent and fast once .venv is current).

SHELL := /bin/bash
VENV_PY := .venv/bin/python
ARGS ?=
PYTEST_ARGS ?=

.PHONY: setup train test bench clean

setup:
	bash scripts/setup.sh

train: setup
	PYOPENGL_PLATFORM=osmesa $(VENV_PY) train.py $(ARGS)

test: setup
	PYOPENGL_PLATFORM=osmesa OMP_WAIT_POLICY=PASSIVE $(VENV_PY) -m pytest -q $(PYTEST_ARGS)

bench: setup
	$(VENV_PY) benchmarks/omp.py

clean:
	rm -rf .venv .pytest_cache .hypothesis build dist *.egg-info
	find . -path ./.git -prune -o -type d -name __pycache__ -prune -exec rm -rf {} +
