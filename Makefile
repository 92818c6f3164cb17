# One-command set-up: `make demo` creates .venv, installs everything and runs the
# Car Park demo; `make test` runs the test suite (what CI runs).
VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test benchmark install clean

TF2_REQUIREMENTS := online_em_slam/messages/tf2_build/source/requirements.txt

$(STAMP): requirements.txt $(TF2_REQUIREMENTS) setup.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -r requirements.txt
	$(PY) -m pip install -q --no-deps -e .
	@# tf2_msgs (TFMessage) built from the rosidl wheels, so map -> odom goes on /tf: the code the
	@# installed package runs on first use; one line and the install goes on when it cannot
	-$(PY) -m online_em_slam.messages.tf2_build build --install-requirements
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(PY) -m online_em_slam.experiments.demo

# The numerical tests on two workers (a file's tests stay together: they share fixtures),
# then the live-node tests alone, so their wall-clock tolerances see an unloaded machine.
test: $(STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile -m "not live" test
	$(PY) -m pytest -q -m live test

benchmark: $(STAMP)
	$(PY) -m online_em_slam.experiments.benchmark --runs 20 --particles 100 --output results/benchmark

clean:
	rm -rf $(VENV) out results build *.egg-info
