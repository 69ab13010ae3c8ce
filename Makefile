# Bloom: `make` builds every scene in configs/ end to end; `make test` runs the tests.
# Each stage writes one artifact under outputs/<scene>/; make reruns only what changed.
SHELL := bash
.SHELLFLAGS := -eu -o pipefail -c
.DELETE_ON_ERROR:
.SUFFIXES:
MAKEFLAGS += --warn-undefined-variables --no-builtin-rules

PYTHON ?= python3
VENV := .venv
BLOOM := $(VENV)/bin/bloom
INSTALLED := $(VENV)/.installed
OUT := outputs
SCENES ?= $(sort $(basename $(notdir $(wildcard configs/*.toml))))
PYTEST_ARGS ?=
# make test spreads the test files over the cores (pytest-xdist; at most 4 workers)
TEST_JOBS ?= -n auto --maxprocesses 4 --dist loadfile
# real flower models other people made (make models)
MODELS ?= ../shared/external-meshes

# A stage's artifacts depend on the library and on the stage's own module.
LIB := $(wildcard pipeline/*.py pipeline/*/*.py pipeline/*/*/*.py) stages/cli.py stages/common.py

.PHONY: all test test-studio test-extended lint bench accuracy stability models elastic docs venv clean clean-venv help
all: $(SCENES:%=$(OUT)/%/render/bloom.mp4) $(SCENES:%=$(OUT)/%/report.json) $(SCENES:%=$(OUT)/%/bloom.usdc)  ## build every scene: artifacts, frames, MP4, report, USD

help:  ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | sed -E 's/:.*## /\t/'

venv: $(INSTALLED)  ## create .venv and install bloom into it
$(INSTALLED): pyproject.toml constraints.txt
	test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check \
		-c constraints.txt -e '.[test]'
	touch $@

test: $(INSTALLED)  ## run the test suite
	$(VENV)/bin/python -m pytest $(TEST_JOBS) $(PYTEST_ARGS)

test-studio: $(INSTALLED)  ## the studio-sized models (../shared/external-meshes, a 100k-face flower) through the geometry stages (~8 min)
	$(VENV)/bin/python -m pytest $(TEST_JOBS) -m studio tests $(PYTEST_ARGS)

test-extended: $(INSTALLED)  ## whole builds killed and resumed: a killed make, a lost Dask worker; each petal's own solver resumed (~4 min)
	$(VENV)/bin/python -m pytest -m extended tests $(PYTEST_ARGS)

bench: $(INSTALLED)  ## print what each effect costs, as ratios to the bare simulation
	$(BLOOM) bench

accuracy: $(INSTALLED)  ## what accuracy costs in time, with and without contact: outputs/accuracy/accuracy.csv, .png (~5 min)
	$(BLOOM) study accuracy --out $(OUT)/accuracy

stability: $(INSTALLED)  ## the hard cases, slow ones included; prints the README's table (~30 s)
	$(BLOOM) study stability

elastic: $(INSTALLED)  ## every default scene with the paper's springs and with the shell, side by side: outputs/elastic/elastic.md, .png (~6 min)
	$(BLOOM) study elastic --out $(OUT)/elastic

models: $(INSTALLED)  ## real flower models, scene.mesh only, judged; the table into docs/performance.md (~50 min: the rose bed ~28)
	$(BLOOM) study models --dir $(MODELS) --out $(OUT)/models --timeout 2400 --into docs/performance.md

docs: $(INSTALLED)  ## the key table of docs/guide.md, made anew from the config schema
	$(BLOOM) config --keys --markdown --into docs/guide.md

lint: $(INSTALLED)  ## ruff over the code
	$(VENV)/bin/ruff check pipeline stages tests

# The input mesh of a scene is named in its config (scene.mesh): record it as a dependency.
$(OUT)/%/mesh.d: configs/%.toml | $(INSTALLED)
	@mkdir -p $(@D)
	@echo "$(OUT)/$*/remesh.h5: $$($(BLOOM) config $< --mesh-path)" > $@

ifeq ($(filter test test-studio lint bench accuracy stability models elastic docs venv clean clean-venv help,$(MAKECMDGOALS)),)
-include $(SCENES:%=$(OUT)/%/mesh.d)
endif

# The pipeline, in order.
$(OUT)/%/remesh.h5: configs/%.toml stages/remesh.py $(LIB) | $(INSTALLED)
	@mkdir -p $(@D)/logs
	$(call RUN,remesh,$(BLOOM) remesh --config $< --out $@)

$(OUT)/%/axis.h5: $(OUT)/%/remesh.h5 configs/%.toml stages/axis.py $(LIB)
	@mkdir -p $(@D)/logs
	$(call RUN,axis,$(BLOOM) axis $< --config configs/$*.toml --out $@)

$(OUT)/%/growth.h5: $(OUT)/%/axis.h5 configs/%.toml stages/growth.py $(LIB)
	@mkdir -p $(@D)/logs
	$(call RUN,growth,$(BLOOM) growth $< --config configs/$*.toml --out $@)

$(OUT)/%/sim.h5: $(OUT)/%/growth.h5 configs/%.toml stages/simulate.py $(LIB)
	@mkdir -p $(@D)/logs
	$(call RUN,simulate,$(BLOOM) simulate $< --config configs/$*.toml --out $@ --resume)

$(OUT)/%/render/bloom.mp4: $(OUT)/%/sim.h5 configs/%.toml stages/render.py $(LIB)
	@mkdir -p $(OUT)/$*/logs
	$(call RUN,render,$(BLOOM) render $< --config configs/$*.toml --out $(OUT)/$*/render)

$(OUT)/%/report.json: $(OUT)/%/sim.h5 stages/report.py $(LIB)
	@mkdir -p $(@D)/logs
	$(call RUN,report,$(BLOOM) report $< --out $@)

$(OUT)/%/bloom.usdc: $(OUT)/%/sim.h5 configs/%.toml stages/export.py $(LIB)
	@mkdir -p $(@D)/logs
	$(call RUN,export,$(BLOOM) export $< --config configs/$*.toml --out $@)

# Each stage's log (stderr) also goes to outputs/<scene>/logs/<stage>.log, and stays on
# stderr (stdout stays stdout); pipefail keeps the stage's exit code. (Under make, stderr
# is a pipe, so the stages show no progress bars.)
RUN = { $(2) 2>&1 1>&3 | tee $(OUT)/$*/logs/$(1).log >&2; } 3>&1

# Keep intermediate artifacts: they are the point of the pipeline.
.PRECIOUS: $(OUT)/%/remesh.h5 $(OUT)/%/axis.h5 $(OUT)/%/growth.h5 $(OUT)/%/sim.h5

clean:  ## remove outputs/ (never configs/ or assets/)
	rm -rf $(OUT)

clean-venv:  ## remove the virtual environment
	rm -rf $(VENV)
