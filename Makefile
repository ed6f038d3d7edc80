# optiacoustic: every target creates and uses the project's own virtual environment.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out/demo

.PHONY: demo test bench install clean docs-figures

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,bench]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/oas demo --out $(OUT)
	@echo "report: $(OUT)/index.html"

test: $(STAMP)
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) benchmarks/run_all.py --out docs/benchmarks.md

docs-figures: $(STAMP)
	$(PY) docs/make_figures.py

clean:
	rm -rf $(VENV) out build src/*.egg-info .pytest_cache
