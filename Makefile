# One command to set up and run the HIL demo, one to set up and run every test (see README).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup demo test bench lint typecheck clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

demo: setup
	$(BIN)/bywire hil demo --report reports/demo --record reports/demo/run.mcap

# The suite in two parts: everything that runs in one process, on both cores (files kept whole on a
# worker: module-scoped fixtures run once); then the multi-process HIL runs one at a time, alone on
# the machine, as their real-time processes need. `-m slow` (long campaigns) runs neither.
test: setup
	$(BIN)/ruff check .
	$(MAKE) --no-print-directory typecheck
	$(BIN)/pytest -m "not slow and not hil" -n 2 --dist loadfile
	$(BIN)/pytest -m "hil and not slow"

# mypy cannot follow setuptools' package-dir mapping (folders protocol/, ecu/, ... are bywire.*),
# so it checks a tree of symlinks laid out the way Python imports the package.
typecheck: setup
	rm -rf build/typecheck && mkdir -p build/typecheck/bywire
	for d in protocol ecu host hil vehicle_models; do ln -s ../../../$$d build/typecheck/bywire/$$d; done
	for f in bywire/*.py; do ln -s ../../../$$f build/typecheck/bywire/; done
	cd build/typecheck && ../../$(BIN)/mypy -p bywire --ignore-missing-imports --follow-imports=silent

bench: setup
	$(BIN)/python benchmarks/run.py
	$(BIN)/bywire bench runtime

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) reports build *.egg-info
