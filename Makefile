# The README's two commands. Each first runs scripts/setup.sh, which installs
# whatever is missing (Debian packages, venv, pinned wheels, native code) and
# skips what is already done.
VENV ?= .venv
PY := $(VENV)/bin/python

.PHONY: setup run test

setup:
	@./scripts/setup.sh

run: setup
	@$(VENV)/bin/cito-demo

test: setup
	@$(PY) -m pytest -q test
