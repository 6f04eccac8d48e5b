# ippc developer commands. Needs only python3 (>= 3.11) and make.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install test test-fast demo bench lint clean experiments

install: $(STAMP)

# Re-install when the project metadata changes; otherwise a no-op.
$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || \
		{ echo "ippc needs Python >= 3.11 (found $$($(PYTHON) --version))"; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	@$(BIN)/python -m pip install -qq --upgrade pip
	@$(BIN)/python -m pip install -qq -e '.[test]'
	@# The tests check generated PDDL with the `pddl` parser, which pins lark<1.2 (ippc's
	@# grammar needs 1.2; pddl runs on it): installed without its dependencies.
	@$(BIN)/python -m pip install -qq --no-deps 'pddl==0.5.1'
	@touch $(STAMP)

# The whole suite, corpus runs included (as CI runs it): first everything that
# can share the machine, on one pytest-xdist worker per core; then the tests
# marked `alone` (load, worker processes, timing), one at a time.
test: install
	$(BIN)/python -m pytest -q -n auto -m 'not alone'
	$(BIN)/python -m pytest -q -m 'alone'

# The loop while working: everything but the slow corpus runs and the tests
# that must run alone, in parallel.
test-fast: install
	$(BIN)/python -m pytest -q -n auto -m 'not slow and not alone'

# The main job: rddl-server on the bundled print-fetching domain, and
# rddl-client playing a session against it with noop, with random and with
# exact (the optimal policy, by value iteration over the instance's 480 states).
demo: install
	@set -e; out=$$(mktemp); \
	$(BIN)/rddl-server domains/print_jobs --port 0 --rounds 3 -q > $$out & pid=$$!; \
	trap 'kill $$pid 2>/dev/null; rm -f $$out' EXIT; \
	for i in $$(seq 300); do grep -q '^listening on' $$out && break; sleep 0.1; done; \
	port=$$(sed -n 's/^listening on .*://p' $$out); \
	test -n "$$port" || { echo "rddl-server did not start"; exit 1; }; \
	echo "rddl-server listening on 127.0.0.1:$$port"; \
	for planner in noop random exact; do \
		$(BIN)/rddl-client --port $$port --instance print_jobs_inst_1 --planner $$planner --seed 1 -q; \
	done

# The print-fetching robot study (docs/print-fetch.md): the paper's four experiments
# through rddl-dispatch's simulated office, report in reports/print_fetch/. PROST joins
# the approaches when PROST_BIN names its search program.
experiments: install
	$(BIN)/python -m ippc.experiments.print_fetch run --workers 2 --out reports/print_fetch

bench: install
	$(BIN)/python bench/parse.py
	$(BIN)/python bench/sim.py
	$(BIN)/python bench/server.py
	$(BIN)/python bench/kb.py
	$(BIN)/python bench/dispatch.py
	$(BIN)/python bench/gym.py

# The import packages: every top-level folder with an __init__.py but tests/.
PACKAGES := $(sort $(patsubst %/__init__.py,%,$(filter-out tests/__init__.py,$(wildcard */__init__.py))))
MYPY_TREE := $(VENV)/mypy-tree

# ruff over the whole tree; mypy over every package and bench/. mypy sees the
# folders as the ippc.* packages they are installed as (through a tree of links,
# $(MYPY_TREE)/ippc/NAME -> NAME/, so its paths start there): checked as bare
# folders, every import between two packages would be an unchecked Any.
lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	@rm -rf "$(MYPY_TREE)" && mkdir -p "$(MYPY_TREE)/ippc"
	@for p in $(PACKAGES); do ln -s "$(CURDIR)/$$p" "$(MYPY_TREE)/ippc/$$p"; done
	MYPYPATH="$(MYPY_TREE)" $(BIN)/mypy --cache-dir "$(VENV)/mypy-cache" $(addprefix -p ippc.,$(PACKAGES))
	MYPYPATH="$(MYPY_TREE)" $(BIN)/mypy --cache-dir "$(VENV)/mypy-cache" bench

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
