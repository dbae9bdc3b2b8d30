# hostd — set up, test, demo. Every target builds .venv itself on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: all venv test lint pytest test-octoprint demo bench docs clean

all: test

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# The suite on both cores (pytest-xdist, a test file a worker), then the tests that compare
# rates measured in their own run, alone.
pytest: $(STAMP)
	$(BIN)/pytest -q -n 2 --dist loadfile -m "not serial" --durations=15
	$(BIN)/pytest -q -m serial

test: lint test-octoprint pytest

demo: $(STAMP)
	$(BIN)/python -m hostd.demo

docs: $(STAMP)
	$(BIN)/python -m hostd.config.docs yaml > config/hostd.yaml
	$(BIN)/python -m hostd.config.docs readme README.md

bench: $(STAMP)
	for b in bench/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) $(OCTO) build *.egg-info .pytest_cache .ruff_cache .mypy_cache

# The link against another project's Marlin emulator (OctoPrint's virtual printer), in a venv
# of its own so OctoPrint's dependencies never meet ours. os._exit: the virtual printer leaves
# non-daemon threads behind that would hold the interpreter for minutes after the tests.
OCTO := .venv-octoprint
$(OCTO)/.installed: pyproject.toml
	$(PYTHON) -m venv $(OCTO)
	$(OCTO)/bin/pip install --quiet "octoprint==1.11.8" "pyserial-asyncio>=0.6,<0.7" \
		"pytest>=8,<10" "pytest-asyncio>=0.24,<2" "pytest-timeout>=2.3,<3" \
		"hypothesis>=6.100,<7" "numpy>=2,<3" "pyyaml>=6,<7" "prometheus-client>=0.20,<1"
	touch $(OCTO)/.installed

test-octoprint: $(OCTO)/.installed
	PYTHONPATH=. $(OCTO)/bin/python -c 'import os, sys, pytest; \
		rc = pytest.main(["-q", "-p", "no:cacheprovider", "tests/link/test_link_octoprint.py"]); \
		sys.stdout.flush(); os._exit(int(rc))'
