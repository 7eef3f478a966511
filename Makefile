# Two commands for a fresh machine (see README): `make demo` and `make test`.
PY ?= python3
PIP := $(PY) -m pip
DATA ?= data
REPORTS ?= reports

.PHONY: install demo test lint bench clean

install:
	$(PIP) install -q -c constraints.txt -e ".[train,dev]"

# The main job on the simulated rig: a moving robot, 31 markers 1.2 cm apart; the paper's SVM
# pipeline with its ablations, then the network and the SVM trained on the same split, exported
# to ONNX and compared in onnxruntime.
demo: install
	$(PY) -m sonicskin simulate --scenario moving --out $(DATA)/moving --overwrite
	$(PY) -m sonicskin evaluate --data $(DATA)/moving --out $(REPORTS)/moving
	$(PY) -m sonicskin compare --data $(DATA)/moving --out $(REPORTS)/compare-moving

test: install
	$(PY) -m pytest -q

lint:
	$(PY) -m ruff check sonicskin models training export tests benchmarks

bench:
	$(PY) benchmarks/bench_pipeline.py

clean:
	rm -rf $(DATA) $(REPORTS) .pytest_cache
