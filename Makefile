# Two commands on a fresh machine: `make run` (venv + install + default mission), `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
EXTRAS := ros,learn,report,dev

.PHONY: install run test bench montecarlo clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet -e ".[$(EXTRAS)]"
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/cikan mission --offline --governor conventional

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/cikan bench --json

montecarlo: $(STAMP)
	$(BIN)/cikan montecarlo --runs 100 --governor conventional --out runs/montecarlo

clean:
	rm -rf $(VENV) build *.egg-info
