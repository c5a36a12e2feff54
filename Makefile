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
# Python with mimalloc preloaded (vsgjax/host.py: XLA:CPU's scratch space is reused instead of
# page-faulted back in on every update); plain Python where mimalloc is not installed.
RUN      = MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa $(shell $(BIN)/python vsgjax/host.py) $(BIN)/python

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

# Two worker processes, whole files each; the MJX tests in a process of their own: three
# full-suite runs died inside XLA's CPU compiler, each in a process that had also run MJX code
# (the failing tests pass alone). Workaround, root cause not proven (README, limitations).
XDIST     = -n 2 --dist loadfile
MJX_TESTS = tests/test_mjx_envs.py tests/test_device_loop.py
NOT_MJX   = $(foreach t,$(MJX_TESTS),--ignore=$(t))

test: setup
	$(RUN) -m pytest -q $(XDIST) $(NOT_MJX) $(PYTEST_ARGS)
	$(RUN) -m pytest -q $(MJX_TESTS) $(PYTEST_ARGS)

test-fast: setup
	$(RUN) -m pytest -q $(XDIST) $(NOT_MJX) -m "not slow" $(PYTEST_ARGS)
	$(RUN) -m pytest -q $(MJX_TESTS) -m "not slow" $(PYTEST_ARGS)

bench: setup
	$(RUN) -m experiments.bench.run_all

lint: setup
	$(BIN)/ruff check vsgjax bbs experiments tests

train: setup
	$(RUN) -m vsgjax.train --task $(TASK) --model $(MODEL) \
		--size $(SIZE) --seed $(SEED) $(if $(SEEDS),--seeds $(SEEDS)) --logdir '$(LOGDIR)' $(ARGS)

evaluate: setup
	$(RUN) -m vsgjax.evaluate $(subst {seed},$(SEED),$(LOGDIR))

clean:
	rm -rf $(VENV) .pytest_cache
