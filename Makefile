# Two commands do everything on a fresh machine: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp

.PHONY: run test test-fast test-vcan lint bench clean

$(STAMP): pyproject.toml scripts/system-deps.sh
	bash scripts/system-deps.sh
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $@

## run the main job: simulated units on an in-process virtual CAN bus
run: $(STAMP)
	$(VENV)/bin/atris launch sim_fleet

## every test: lint and types (inside pytest), host tests
test: $(STAMP)
	$(PY) -m pytest -q
	bash scripts/vcan-tests.sh

## real SocketCAN tests (tests/vcan): natively with vcan0/vcan1, else in a VM; see docs/vcan.md
test-vcan: $(STAMP)
	bash scripts/vcan-tests.sh

test-fast: $(STAMP)
	$(PY) -m pytest -q -x -m 'not slow and not vcan and not hardware'

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/mypy

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
