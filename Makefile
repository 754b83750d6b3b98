# Two entry points for a fresh machine with only Python 3.11:
#   make test       [DATA=path/to/data]   create .venv, install, run the tests
#   make reproduce  [DATA=path/to/data]   create .venv, install, run the DVC pipeline
# DATA is a local copy of the third-party data (layout of ../shared/data); without it the pipeline
# downloads the pinned files into ~/.cache/tactile6d and the tests that need data are skipped.

PYTHON ?= python3
VENV := .venv
BIN := $(abspath $(VENV))/bin
export PATH := $(BIN):$(PATH)
export DVC_NO_ANALYTICS := 1
# Small (N, 3) @ (3, 3) products are slower on several BLAS threads than on one, much slower on a busy
# machine; the stages parallelise where it pays (rendering workers, JAX devices) instead.
export OPENBLAS_NUM_THREADS := 1
ifneq ($(DATA),)
export TACTILE6D_DATA := $(abspath $(DATA))
endif

.PHONY: install test reproduce params clean-venv tacto-env tacto-check

# torch first and alone: a CPU wheel of 2.13.0 is what the machine has; any other request for torch
# would pull several GB of CUDA packages.
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $@

install: $(VENV)/.installed

# Both cores by default (pytest-xdist; loadfile keeps a file's tests on one worker, so a module's fixtures
# are built once): about half the time of one worker. TEST_WORKERS=1 runs the suite in one worker.
TEST_WORKERS ?= 2

test: install
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

# The target times itself, install included: make expands REPRODUCE_STARTED (`:=`) as it reads this file,
# before it builds the install prerequisite; record_reproduce_time.py writes artifacts/times/make_reproduce.json
# for update_readme.py. repro_progress.py is `dvc repro` numbering the stages as DVC comes to them.
# verify_lock.py --write-digests records the outputs' timing-free digests beside dvc.lock, so that a run on
# another machine can be compared with this one without its files (docs/reproducibility.md, Across machines).
reproduce: REPRODUCE_STARTED := $(shell date +%s)
reproduce: install
	$(BIN)/python scripts/repro_progress.py
	$(BIN)/python scripts/verify_lock.py --write-digests reports/output_digests.json
	$(BIN)/python scripts/record_reproduce_time.py $(REPRODUCE_STARTED)
	$(BIN)/python scripts/update_readme.py

# Refresh the committed params.yaml after editing conf/ (plain `dvc repro` reads params.yaml).
params: install
	$(BIN)/python -m tactile6d.core.config > params.yaml

clean-venv:
	rm -rf $(VENV)

# TACTO, the simulator the paper rendered with, in an environment of its own for scripts/tacto_scenes.py (scenes
# of another tool than this project's renderer). pyrender pins PyOpenGL 3.1.0, whose EGL loading fails on
# Python 3.11, and urdfpy (imported by tacto) pins networkx 2.2: those three are installed without their pins.
TACTO_VENV := .venv-tacto
$(TACTO_VENV)/.installed:
	$(PYTHON) -m venv $(TACTO_VENV)
	$(TACTO_VENV)/bin/python -m pip install --quiet --upgrade pip
	$(TACTO_VENV)/bin/python -m pip install --quiet numpy==2.4.6 scipy==1.17.1 trimesh==5.2.0 h5py==3.16.0 \
		opencv-python-headless==5.0.0.93 PyOpenGL==3.1.7 omegaconf==2.3.1 pybullet==3.2.7 pyglet==1.5.31 \
		freetype-py imageio networkx pillow six lxml pycollada
	$(TACTO_VENV)/bin/python -m pip install --quiet --no-deps pyrender==0.1.45 urdfpy==0.0.22 tacto==0.0.3
	touch $@

tacto-env: $(TACTO_VENV)/.installed

# Issue 34's conditions on scenes TACTO renders (docs/real_sensors.md): the validation scenes of a run's artifacts
# (make reproduce) rendered again by TACTO into $(TACTO_ART), their images compared with this renderer's, then
# estimated under each condition, one JSON line each. About 5 minutes on the 2-core machine.
TACTO_ART ?= artifacts-tacto
tacto-check: install $(TACTO_VENV)/.installed
	$(TACTO_VENV)/bin/python scripts/tacto_scenes.py --artifacts artifacts --scenes validation --out $(TACTO_ART)
	$(BIN)/python scripts/compare_scene_images.py artifacts/scenes/validation.h5 $(TACTO_ART)/scenes/validation_tacto.h5
	$(BIN)/python scripts/real_setup_check.py --artifacts $(TACTO_ART) --scenes validation_tacto --confidence \
		--conditions clean noise light kinematic other-unit
