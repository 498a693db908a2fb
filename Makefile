# Every target sets itself up: a .venv with the project installed editable.
# Two stamps: `make produce` installs what producing (and exporting,
# evaluating) needs; `make test` adds the test extras (torch, polars, duckdb,
# moto, datasets, ...) on top of the same .venv.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-produce
STAMP_TEST := $(VENV)/.installed-test
STAMP_MUTANTS := $(VENV)/.installed-mutants

# make produce: the main job (see README). Override any of these.
# The default is a small run (FRAMES per scenario at 480x270). SCALE=1, or
# --scale in PRODUCE_ARGS, sizes the run by the paper's frame counts instead,
# at full HD unless WIDTH/HEIGHT are given; an option given in PRODUCE_ARGS
# (--frames-per-scenario, --width, --height) replaces the one made here.
DOMAINS ?= all
OUT     ?= output
FRAMES  ?= 2
SCALE   ?=
SEED    ?= 0
PRODUCE_ARGS ?=
_FULL   := $(if $(SCALE)$(findstring --scale,$(PRODUCE_ARGS)),1)
WIDTH   ?= $(if $(_FULL),1920,480)
HEIGHT  ?= $(if $(_FULL),1080,270)
_given   = $(findstring $(1),$(PRODUCE_ARGS))
_SIZE    = $(if $(SCALE),--scale $(SCALE),$(if $(_FULL)$(call _given,--frames-per-scenario),,--frames-per-scenario $(FRAMES))) \
	$(if $(call _given,--width),,--width $(WIDTH)) $(if $(call _given,--height),,--height $(HEIGHT))

.PHONY: help venv venv-test bytecode produce test mutants bench report clean

help: ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F ':.*## ' '{printf "  make %-9s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "error: $(PYTHON) not found; install Python 3.11 or pass PYTHON=..."; exit 2; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# pyrender 0.1.45 pins PyOpenGL==3.1.0, which breaks EGL; install it without
	# its pins (its real dependencies are listed in pyproject.toml).
	$(BIN)/pip install --quiet --no-deps pyrender==0.1.45
	$(BIN)/pip install --quiet -e .
	@echo "note: pip's warning that pyrender wants PyOpenGL==3.1.0 is expected; newer PyOpenGL is what makes EGL work"
	@touch $(STAMP)

$(STAMP_TEST): $(STAMP) pyproject.toml
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $(STAMP_TEST)

venv: $(STAMP) ## create .venv with the project and what producing needs

# The project's byte-code, refreshed before every run (half a second when it is current). Where
# PYTHONDONTWRITEBYTECODE is set, Python never writes it itself: every CLI process and Ray worker
# compiled the ~22,000 lines it imports, ~0.3 CPU-s each, at every start (docs/bench_render.md).
PY_DIRS := storage domains outputs manifests roots render_workers exports analysis pipeline benchmarks reports tests
bytecode: $(STAMP)
	@$(BIN)/python -m compileall -q -j 0 $(PY_DIRS) >/dev/null

venv-test: $(STAMP_TEST) ## add the test extras (torch, polars, duckdb, moto, datasets...) to .venv

produce: $(STAMP) bytecode ## render DOMAINS (default all) into OUT; FRAMES/WIDTH/HEIGHT size the run, SCALE=1 is the full dataset
	$(BIN)/idda produce --domains '$(DOMAINS)' --out '$(OUT)' $(_SIZE) --seed $(SEED) $(PRODUCE_ARGS)

# Two pytest workers (pytest-xdist), whole files to each. On 2 cores the suite
# keeps both busy (92% of the machine over a fresh clone's `make test`), so a
# third worker gains nothing: 1,228 s for 919 tests with 3, 1,244 s for 906
# with 2. On more cores, TEST_WORKERS=N; TEST_WORKERS=0 runs it in one process.
# The 30 slowest tests are listed at the end (issue 35: the suite's budget is 15 minutes).
TEST_WORKERS ?= 2

test: $(STAMP_TEST) bytecode ## add the test extras to .venv, then run the test suite (TEST_WORKERS=2 processes)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=30

$(STAMP_MUTANTS): $(STAMP_TEST) pyproject.toml
	$(BIN)/pip install --quiet -e '.[test,mutants]'
	@touch $(STAMP_MUTANTS)

# MUTANTS: modules to mutate (default: all of tests/mutants.py's list, in order), e.g. MUTANTS=storage/atomic.py
MUTANTS ?=
mutants: $(STAMP_MUTANTS) ## mutation testing (mutmut) of the data-protecting modules against their fast tests; score per module (docs/mutants.md). Not part of `make test`; CPU-heavy
	nice $(BIN)/python -m tests.mutants $(MUTANTS)

bench: $(STAMP_TEST) bytecode ## run the benchmarks; figures go to docs/
	$(BIN)/python -m benchmarks.run

report: $(STAMP_TEST) bytecode ## render a 105-scenario sample and write docs/worlds.md (class shares, distances, contact sheets) and docs/weathers.md's pictures
	$(BIN)/python -m reports.worlds
	$(BIN)/python -m reports.weathers

clean: ## remove the .venv and caches (never your output)
	rm -rf $(VENV) .pytest_cache .hypothesis
	find $(PY_DIRS) -name __pycache__ -type d -prune -exec rm -rf {} +
