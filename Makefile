# Two commands on a fresh machine: `make run` (venv + install + default mission), `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
EXTRAS := ros,learn,report,dev

.PHONY: install run test bench montecarlo results clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet -e ".[$(EXTRAS)]"
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/cikan mission --governor conventional --bag runs/bags/$$(date -u +%Y%m%dT%H%M%SZ)_conventional

test: $(STAMP)
	$(BIN)/python -m pytest

bench: $(STAMP)
	$(BIN)/cikan bench --json

montecarlo: $(STAMP)
	$(BIN)/cikan montecarlo --runs 100 --governor conventional --workers 2 --out runs/montecarlo

# The results page: the paper's 100-run evaluation for all six governors, then figures and Table 2.
results: $(STAMP)
	$(BIN)/cikan montecarlo --runs 100 --governor all --workers 2 --out runs/paper
	$(BIN)/cikan report runs/paper --out docs/results --notes docs/results_notes.md \
		--title "Results: the paper's Table 2 and Figures 3-4 reproduced"

clean:
	rm -rf $(VENV) build *.egg-info
