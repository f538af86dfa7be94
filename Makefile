# Thermal-error compensation retrofit: top-level workflow.
#   make demo   set up, train on the example runs, build the firmware (STM32F405 + native),
#               replay a run through the native firmware over a pty, write the report
#   make test   every test suite: Python (host, codegen, HIL) and C (firmware, cmocka)
#   make cnc    replay a run through the box into a headless LinuxCNC (external offsets)
#   make probe  probing in service on that LinuxCNC: the residual at each probe, static vs updated
#   make faults single ordinary events (restart, power cut, loose connector, runaway or stuck
#               sensor, ZERO in a hold, forged line, garbage, stale, reconnect) against the rule
#               "never worse than the clean run by more than one step limit" (build/faults/)
#   make flash  flash the STM32F405 with build/model.h through OpenOCD (ST-LINK)

PY      := .venv/bin/python
HOST    := .venv/bin/host
STAMP   := .venv/.installed
BUILD   := build
EXAMPLES := examples
MODEL_JSON := $(BUILD)/model.json
MODEL_H    := $(BUILD)/model.h
# Demo data: train on two example protocols, replay/judge on a third the model never saw.
DEMO_TRAIN := $(EXAMPLES)/sim_constant.csv $(EXAMPLES)/sim_step.csv
DEMO_TEST  := $(EXAMPLES)/sim_random.csv
DEMO_TARGETS := --target dx_um --target dy_um --target dz_um

.PHONY: setup system-deps test test-python test-firmware test-floors lint demo train firmware firmware-native \
        firmware-stm32 hil flash bench examples report clean cnc probe faults

setup: $(STAMP)

system-deps:
	bash scripts/install-system-deps.sh

$(STAMP): pyproject.toml scripts/install-system-deps.sh
	bash scripts/install-system-deps.sh
	python3 -m venv .venv
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[all,test]'
	touch $(STAMP)

lint: $(STAMP)
	$(PY) -m ruff check thermal_comp tests bench scripts firmware/test

test: $(STAMP) lint test-firmware test-python test-floors faults

test-python: $(STAMP)
	$(PY) -m pytest

# The lowest dependency versions pyproject.toml states, installed exactly (scripts/floors.py),
# and a quick subset that touches each of them: scikit-learn's estimator API, jinja2 (codegen),
# matplotlib (report), numpy/scipy (selection, fitting), pyserial (the protocol decoder).
FLOORS_VENV := .venv-floors
FLOORS_TESTS := tests/host/train/test_sklearn_checks.py tests/host/selection/test_selection.py tests/codegen/test_codegen.py \
                tests/host/analysis/test_report.py tests/contract/test_protocol.py tests/host/box/test_monitor.py \
                tests/host/train/test_model_estimator.py tests/host/selection/test_free_channels.py
$(FLOORS_VENV)/.installed: pyproject.toml scripts/floors.py
	rm -rf $(FLOORS_VENV)
	python3 -m venv $(FLOORS_VENV)
	python3 scripts/floors.py > $(FLOORS_VENV)/floors.txt
	$(FLOORS_VENV)/bin/python -m pip install -q -r $(FLOORS_VENV)/floors.txt pytest
	touch $@

test-floors: $(FLOORS_VENV)/.installed
	@echo "floors: $$(tr '\n' ' ' < $(FLOORS_VENV)/floors.txt)"
	PYTHONPATH=$(CURDIR) $(FLOORS_VENV)/bin/python -m pytest -q -p no:cacheprovider \
	    -W ignore::DeprecationWarning $(FLOORS_TESTS)

test-firmware: $(STAMP)
	$(MAKE) -C firmware test

examples: $(STAMP)
	$(PY) -m thermal_comp.host.sim.examples $(EXAMPLES)

train: $(STAMP)
	$(HOST) train $(DEMO_TRAIN) $(DEMO_TARGETS) --out $(BUILD)

firmware-stm32: $(STAMP)
	$(MAKE) -C firmware BOARD=stm32f405 MODEL=../$(MODEL_H)

firmware-native: $(STAMP)
	$(MAKE) -C firmware BOARD=native MODEL=../$(MODEL_H)

firmware: firmware-stm32 firmware-native

hil: $(STAMP)
	@test -f $(MODEL_JSON) || $(MAKE) train
	$(PY) -m thermal_comp.hil replay --model $(MODEL_JSON) --data $(DEMO_TEST)

flash: $(STAMP)
	@test -f $(MODEL_H) || { echo "No $(MODEL_H): run 'host train ...' (or 'make train') first."; exit 2; }
	$(MAKE) -C firmware BOARD=stm32f405 MODEL=../$(MODEL_H) flash

report: $(STAMP)
	$(HOST) report $(MODEL_JSON) --runs $(DEMO_TRAIN) $(DEMO_TEST) -o report

# The box's corrections through a headless LinuxCNC on external offsets (docs/linuxcnc.md).
cnc: $(STAMP)
	$(PY) -m thermal_comp.cnc

# Probing in service (issue 42) on the same headless LinuxCNC: a probe on a reference artifact
# every hour of the replayed run, MEAS to the box, the residual at each probe, static against
# updated (build/cnc-probe/summary.json).
probe: $(STAMP)
	$(PY) -m thermal_comp.cnc --probe

# The fault campaign of issue 41: native box + the component's logic, and the controller's
# events through a real headless LinuxCNC; a table and build/faults/summary.json.
faults: $(STAMP)
	$(PY) -m thermal_comp.cnc.faults --quiet

bench: $(STAMP)
	$(PY) -m bench

demo: $(STAMP)
	$(PY) -m thermal_comp.host.demo

clean:
	rm -rf $(BUILD) report bench/results $(FLOORS_VENV)
	$(MAKE) -C firmware clean
