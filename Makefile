# One command to set up and run the HIL demo, one to set up and run every test (see README).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup demo test bench lint typecheck imports docs clean safety-coverage mutation

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
	$(MAKE) --no-print-directory imports
	$(MAKE) --no-print-directory safety-coverage
	$(MAKE) --no-print-directory docs
	$(BIN)/pytest -m "not slow and not hil" -n 2 --dist loadfile $(SAFETY_SPEC_IGNORE)
	$(BIN)/pytest -m "hil and not slow"

# The safety authority's spec tests run once, under branch coverage (safety-coverage above).
SAFETY_SPEC_IGNORE = $(addprefix --ignore=,$(shell $(BIN)/python tools/safety_coverage.py --list-tests 2>/dev/null))

# The import rules of DESIGN section 2 (pyproject.toml [tool.importlinter]). The tool is installed
# here if the venv predates it in the `test` extra.
imports: setup
	@$(BIN)/python -c 'import importlinter' 2>/dev/null || $(BIN)/python -m pip install --quiet 'import-linter>=2.1'
	$(BIN)/lint-imports

# mypy checks the package as Python imports it (pyproject.toml [tool.mypy]: strict on ecu and protocol).
typecheck: setup
	$(BIN)/mypy

# The documentation site (mkdocs.yml): the guides of docs/, and the protocol table, the file schemas,
# the calibration's limits and the API generated from the code (tools/docs_site), into build/docs;
# any warning fails it. Offline: no web fonts, no plugin that fetches. The tools are installed here if
# the venv predates them in the `test` extra. Material's notice about MkDocs 2 is not a warning of ours;
# no --quiet, which hides from --strict the warnings it counts.
docs: setup
	@$(BIN)/python -c 'import mkdocs, material, mkdocstrings_handlers.python' 2>/dev/null \
		|| $(BIN)/python -m pip install --quiet 'mkdocs>=1.6,<2' 'mkdocs-material>=9.5,<10' 'mkdocstrings[python]>=0.29'
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict

bench: setup
	$(BIN)/python benchmarks/run.py
	$(BIN)/bywire bench runtime

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

clean:
	rm -rf $(VENV) reports build *.egg-info

# Testing the tests of the safety authority (files and spec tests: tools/safety_scope.py). The tools
# are installed here if the venv predates their extra (pyproject: coverage in `test`, `mutation`).
# Branch coverage of the safety files by their spec tests only, missing branches listed;
# reports/safety_coverage.{md,json}. SAFETY_COVERAGE_ARGS=--fail-under=100 once every branch is
# tested or excused with a reason.
SAFETY_COVERAGE_ARGS ?=
safety-coverage: setup
	@$(BIN)/python -c 'import coverage, sys; sys.exit(coverage.version_info < (7, 10))' 2>/dev/null \
		|| $(BIN)/python -m pip install --quiet 'coverage>=7.10'
	$(BIN)/python tools/safety_coverage.py $(SAFETY_COVERAGE_ARGS)

# Mutation testing (mutmut) of MUTATE (default: ecu/safety.py and ecu/tx_guard.py) against
# MUTATION_TESTS (default: the spec tests), on both cores; reports/mutation/report.md. A survivor
# that is equivalent is explained in docs/mutation_equivalents.toml. MUTATION_ARGS=--rev=HEAD
# mutates the last commit instead of the working tree; --report-only re-reports the last run.
MUTATE ?=
MUTATION_TESTS ?=
MUTATION_ARGS ?=
mutation: setup
	@$(BIN)/python -c 'import mutmut' 2>/dev/null || $(BIN)/python -m pip install --quiet 'mutmut>=3.8.1,<4'
	$(BIN)/python tools/mutation.py $(addprefix --mutate=,$(MUTATE)) \
		$(addprefix --tests=,$(MUTATION_TESTS)) $(MUTATION_ARGS)
