# make setup: idempotent; creates .venv, installs dependencies, builds alignment_msgs,
# installs this package (editable). Each step reruns only when its inputs changed.
SHELL := /bin/bash
# The ROS 2 Jazzy wheels are CPython 3.11 builds: take python3.11 where it exists.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV := $(CURDIR)/.venv
BIN := $(VENV)/bin
# The interface packages: tf2_msgs (the standard one, which the ROS 2 wheels lack) and
# alignment_msgs (this suite's).
INTERFACES := tf2_msgs alignment_msgs
MSG_SOURCES := $(wildcard interfaces/*/msg/*.msg interfaces/*/srv/*.srv interfaces/*/CMakeLists.txt interfaces/*/package.xml)
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST

.PHONY: setup demo test bench figures mutants clean

setup: $(VENV)/.stamp-compiled $(VENV)/.stamp-foxglove $(VENV)/.stamp-chromium

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' || { \
	  echo "make: $(PYTHON) is not Python 3.11, which the ROS 2 Jazzy wheels need." >&2; \
	  echo "Install it (Debian/Ubuntu: apt install python3.11 python3.11-venv, or pyenv)" >&2; \
	  echo "or point to it: make PYTHON=/path/to/python3.11 ..." >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)

$(VENV)/.stamp-deps: requirements.txt | $(BIN)/python
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -r requirements.txt
	touch $@

# Built with colcon, as on a ROS install, into the venv (merged install).
$(VENV)/.stamp-msgs: $(VENV)/.stamp-deps $(MSG_SOURCES)
	rm -rf $(addprefix build/,$(INTERFACES)) && mkdir -p build
	export VIRTUAL_ENV=$(VENV) PATH=$(BIN):$$PATH AMENT_PREFIX_PATH=$(VENV) && \
	  $(BIN)/colcon --log-base build/colcon-log build --paths $(addprefix interfaces/,$(INTERFACES)) \
	    --build-base build --install-base $(VENV) --merge-install --parallel-workers 2 \
	    --cmake-args -DPython3_EXECUTABLE=$(BIN)/python -DBUILD_TESTING=OFF -DCMAKE_PREFIX_PATH=$(VENV) \
	    > build/colcon.log 2>&1 || { tail -n 60 build/colcon.log; exit 1; }
	$(BIN)/python -c "import alignment_msgs.msg, alignment_msgs.srv, tf2_msgs.msg"
	touch $@

$(VENV)/.stamp-package: $(VENV)/.stamp-msgs setup.py setup.cfg
	$(BIN)/pip install --quiet --no-build-isolation --no-deps -e .
	touch $@

# The detector's compiled (numba) code, into its on-disk cache: 15-20 s, once. The old
# cache goes first: numba checks only each function's own file, so a function would keep
# its compiled copy of a changed callee in another file.
$(VENV)/.stamp-compiled: $(VENV)/.stamp-package $(wildcard calib_core/marks/*.py)
	rm -f calib_core/marks/__pycache__/*.nbi calib_core/marks/__pycache__/*.nbc
	$(BIN)/python -m calib_core.marks.precompile
	touch $@

# Foxglove's own decoders (npm), for the test that every bag opens in Foxglove. Without
# Node.js the step says so and that test is skipped.
$(VENV)/.stamp-foxglove: tools/foxglove/package.json tools/foxglove/package-lock.json | $(BIN)/python
	@if command -v npm > /dev/null; then \
	  cd tools/foxglove && npm ci --no-audit --no-fund --loglevel=error && touch $@; \
	else echo "make: no npm: the Foxglove decoder test will be skipped (apt install nodejs npm)"; fi

# Debian's Chromium, for the test that renders the HTML reports headless: installed where
# this machine can (root with apt-get); elsewhere the step says so and that test is skipped.
$(VENV)/.stamp-chromium: | $(BIN)/python
	@if command -v chromium > /dev/null; then touch $@; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get > /dev/null; then \
	  mkdir -p build && { apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
	    apt-get install -y -qq --no-install-recommends chromium; } > build/apt.log 2>&1 \
	  && touch $@ || { tail -n 20 build/apt.log; \
	    echo "make: chromium not installed: the HTML report's browser test will be skipped"; }; \
	else echo "make: no chromium (apt install chromium): the HTML report's browser test will be skipped"; fi

demo: setup
	$(BIN)/machine-align demo --out out/demo

# The figures docs/ embeds, from one named run of the current code (about 4 minutes):
# the demo (its log becomes bench_results/demo_run.log), the hexapod loop route, real run a.
figures: setup
	$(BIN)/python -m machine_alignment.figures --out out/figures

# Two workers, one test module each (a module's DDS graph stays on its own ROS domain);
# one BLAS thread per worker: two workers already fill the two cores, and OpenBLAS's
# threads spinning against each other made the camera fits 2-10x slower.
test: setup
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \
	  $(BIN)/python -m pytest -q -rs -n 2 --dist loadfile --no-loadscope-reorder --durations=15 test

bench: setup
	$(BIN)/python -m machine_alignment.bench.vision --out bench_results
	$(BIN)/python -m machine_alignment.bench.mark_scenes --out bench_results
	$(BIN)/python -m machine_alignment.bench.hexapod --out bench_results
	$(BIN)/python -m machine_alignment.bench.closed_loop --out bench_results
	$(BIN)/python -m machine_alignment.bench.closed_loop_axis --out bench_results
	$(BIN)/python -m machine_alignment.bench.closed_loop_channels --out bench_results
	$(BIN)/python -m machine_alignment.bench.closed_loop_rotary --out bench_results
	$(BIN)/python -m machine_alignment.bench.camera_real --out bench_results
	$(BIN)/python -m machine_alignment.bench.closed_loop_speed --out bench_results
	$(BIN)/python -m machine_alignment.bench.command_speed --out bench_results
	$(BIN)/python -m machine_alignment.bench.stage --out bench_results
	$(BIN)/python -m machine_alignment.bench.grid --out bench_results
	$(BIN)/python -m machine_alignment.bench.grid_uncertainty --out bench_results
	$(BIN)/python -m machine_alignment.bench.grid_gantry --out bench_results
	$(BIN)/python -m machine_alignment.bench.platform --out bench_results
	$(BIN)/python -m machine_alignment.bench.plan_platform --out bench_results
	$(BIN)/python -m machine_alignment.bench.plan_five_axis --out bench_results
	$(BIN)/python -m machine_alignment.bench.plan_hexapod --out bench_results
	$(BIN)/python -m machine_alignment.bench.plan_stage --out bench_results
	$(BIN)/python -m machine_alignment.bench.five_axis --out bench_results
	$(BIN)/python -m machine_alignment.bench.five_axis_description --out bench_results
	$(BIN)/python -m machine_alignment.bench.rotary_calibration --out bench_results
	$(BIN)/python -m machine_alignment.bench.user_descriptions --out bench_results
	$(BIN)/python -m machine_alignment.bench.performance --out bench_results

# Deliberate bugs, one at a time on a scratch copy: which do the tests miss?
mutants: setup
	$(BIN)/python tools/mutants.py

clean:
	rm -rf build out .pytest_cache
