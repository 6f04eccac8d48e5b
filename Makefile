# ippc developer commands. Needs only python3 (>= 3.11) and make.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install test test-fast demo bench lint clean

install: $(STAMP)

# Re-install when the project metadata changes; otherwise a no-op.
$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
		{ echo "ippc needs Python >= 3.11 (found $$($(PYTHON) --version))"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The whole suite, corpus runs included (as CI runs it).
test: install
	$(BIN)/python -m pytest -q

# Everything but the slow corpus runs.
test-fast: install
	$(BIN)/python -m pytest -q -m 'not slow'

# For now: check the bundled domains and show one formatted back.
demo: install
	$(BIN)/rddl check domains/
	$(BIN)/rddl fmt domains/print_fetch/domain.rddl | head -40

bench: install
	$(BIN)/python bench/parse.py

lint: install
	$(BIN)/ruff check .
	$(BIN)/mypy rddl protocol

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
