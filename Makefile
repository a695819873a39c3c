# Everything a fresh machine with Python 3.11 and make needs: `make paper` and `make test`.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: paper test lint bench clean

$(STAMP): pyproject.toml gli_clients/python/pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) on PATH (or make PY=python3)"; exit 2; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e gli_clients/python
	$(BIN)/pip install -q -e '.[dev]'
	@touch $(STAMP)

## The paper's physical-layer experiment (Section 3.1): trace, report and figures in out/phy-layer/
paper: $(STAMP)
	$(BIN)/uwsimnet experiment phy-layer --out out/phy-layer

## The test suite (what CI runs)
test: $(STAMP)
	$(BIN)/ruff check uwsimnet_zenoh tests bench
	$(BIN)/python -m pytest -q -p no:cacheprovider

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python bench/bench_engine.py

clean:
	rm -rf $(VENV) out
