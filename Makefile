# vsgjax: see README.md. Every target that needs Python depends on `setup`.
PY      ?= python3
VENV    := .venv
BIN     := $(VENV)/bin
STAMP   := $(VENV)/.installed
TASK    ?= bbs_basic
MODEL   ?= vsg
SIZE    ?= auto
SEED    ?= 0
SEEDS   ?=
# {seed} is filled in per seed (SEEDS=0,1,2 trains three seeds in one process)
LOGDIR  ?= runs/$(TASK)-$(MODEL)-s{seed}
ARGS    ?=
PYTEST_ARGS ?=
# Python with mimalloc preloaded (vsgjax/allocator.py: XLA:CPU's scratch space is reused instead of
# page-faulted back in on every update); plain Python where mimalloc is not installed.
RUN      = MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa $(shell $(BIN)/python vsgjax/allocator.py) $(BIN)/python
# Each target prints the short command it runs (`python ...`), not the environment and preload.
SAY      = @printf '%s\n'

.PHONY: setup test test-fast bench lint train evaluate clean

# Idempotent: reinstalls only when pyproject.toml changed; installs the headless
# OpenGL library dm_control needs for rendering on machines with no GPU or display.
setup: $(STAMP)
$(STAMP): pyproject.toml
	@test -d $(VENV) || $(PY) -m venv $(VENV)
	@bash experiments/setup_headless_gl.sh
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[dev]"
	@touch $(STAMP)

# Two worker processes, whole files each (tests/conftest.py frees compiled programs after
# every file: a long process that kept them all ran out of memory mappings in XLA's compiler).
XDIST = -n 2 --dist loadfile

test: setup
	$(SAY) 'python -m pytest -q $(XDIST) $(PYTEST_ARGS)'
	@$(RUN) -m pytest -q $(XDIST) $(PYTEST_ARGS)

test-fast: setup
	$(SAY) 'python -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)'
	@$(RUN) -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)

bench: setup
	$(SAY) 'python -m experiments.bench.run_all'
	@$(RUN) -m experiments.bench.run_all

lint: setup
	$(BIN)/ruff check vsgjax bbs experiments tests

TRAIN_ARGS = --task $(TASK) --model $(MODEL) --size $(SIZE) --seed $(SEED) \
	$(if $(SEEDS),--seeds $(SEEDS)) --logdir '$(LOGDIR)' $(ARGS)

train: setup
	$(SAY) "python -m vsgjax.train $(TRAIN_ARGS)"
	@$(RUN) -m vsgjax.train $(TRAIN_ARGS)

evaluate: setup
	$(SAY) 'python -m vsgjax.evaluate $(subst {seed},$(SEED),$(LOGDIR))'
	@$(RUN) -m vsgjax.evaluate $(subst {seed},$(SEED),$(LOGDIR))

clean:
	rm -rf $(VENV) .pytest_cache
