# Two commands for a fresh machine (see README): `make demo` and `make test`.
# Both install into a project virtual environment (.venv, created if missing), never into the
# python3 on PATH. Another environment: `make test VENV=/path/to/env`.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
DATA ?= data
REPORTS ?= reports

.PHONY: install demo test test-fast deploy-check lint bench docs results clean

$(PY):
	$(PYTHON) -m venv $(VENV)

# Re-installs when pyproject.toml or constraints.txt change (constraints.txt: torch is the 2.13.0 CPU build).
$(VENV)/.installed: pyproject.toml constraints.txt | $(PY)
	$(PY) -m pip install -q -c constraints.txt -e ".[train,dev]"
	touch $@

install: $(VENV)/.installed

# The main job on the simulated rig: a moving robot, 31 markers 1.2 cm apart; the paper's SVM
# pipeline with its ablations, then the network and the SVM trained on the same split, exported
# to ONNX and compared in onnxruntime. A smaller run (`python tools/readme.py --check` uses one):
# make demo SIM_OPTS="--set sessions=2 --set touch_s=1" TRAIN_OPTS="--trainer.max_epochs 2"
SIM_OPTS ?=
TRAIN_OPTS ?=
demo: install
	$(PY) -m sonicskin simulate --scenario moving --out $(DATA)/moving --overwrite $(SIM_OPTS)
	$(PY) -m sonicskin evaluate --data $(DATA)/moving --out $(REPORTS)/moving
	$(PY) -m sonicskin compare --data $(DATA)/moving --out $(REPORTS)/compare-moving $(TRAIN_OPTS)

# The whole suite, long runs included (CI runs this target): two pytest-xdist workers, then the runs
# that need the machine to themselves (marked serial: JACK in real time, DDP) alone.
# `make test-fast` leaves out every run marked slow.
TEST_WORKERS ?= 2
# The serial step runs even when the parallel one failed (its failures are reported too); then the target fails.
test: install
	@rc=0; \
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not serial" || rc=$$?; \
	$(PY) -m pytest -q -m serial || rc2=$$?; \
	if [ $$rc -ne 0 ] || [ $${rc2:-0} -ne 0 ]; then \
	  echo "make test: failed (parallel step exit $$rc, serial step exit $${rc2:-0})" >&2; exit 1; fi

test-fast: install
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not slow"

# The deployment install: a wheel into a fresh venv without torch, then info, fit-svm and live.
deploy-check: install
	PY=$(PY) PYTHON=$(PYTHON) .ci/deploy-check

lint: install
	$(PY) -m ruff check sonicskin models training export tests benchmarks

bench: install
	$(PY) benchmarks/bench_pipeline.py

# The outputs and figures of README.md and the manual (docs/*.md, in the order of PAGES in tools/readme.py):
# runs their marked command blocks in one fresh folder and writes what they print into the document that holds
# each marker and docs/*.png, then the stored results (tools/readme.py, tools/results.py; tests/test_readme.py
# and tests/test_results.py check them).
docs: install
	$(PY) tools/readme.py
	$(PY) tools/results.py render

# The README's measured results (tables, benchmark figures, the probe plot): every registered command of
# docs/results/index.yaml run again and stored (tools/results.py; hours on 2 cores). RESULTS="probe seeds" for some.
RESULTS ?= --all
results: install
	$(PY) tools/results.py run $(RESULTS)

clean:
	rm -rf $(DATA) $(REPORTS) .pytest_cache
