# Two commands on a fresh machine: `make demo` and `make test`.
# TORCH_SPEC pins the CPU wheel that CI machines carry offline; on a normal
# machine the same pin resolves to the regular (CUDA-enabled) PyPI build.
# Override it to use another torch: `make demo TORCH_SPEC=torch`.
PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test lint typecheck unit bench results clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q "$(TORCH_SPEC)"
	$(BIN)/python -m pip install -q -e ".[dev]"
	touch $@

demo: $(VENV)/.installed
	$(BIN)/lenspair demo --out demo_out

lint: $(VENV)/.installed
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

# mypy cannot follow setuptools' editable-install finder (which maps the stage
# folders capture/, rectify/, ... to lenspair.capture, lenspair.rectify, ...), so
# it checks a tree of symbolic links laid out as the installed package is.
TYPECHECK_TREE := build/typecheck
typecheck: $(VENV)/.installed
	rm -rf $(TYPECHECK_TREE) && mkdir -p $(TYPECHECK_TREE)/lenspair
	for f in lenspair/*.py lenspair/commands lenspair/core; do ln -s "$(CURDIR)/$$f" $(TYPECHECK_TREE)/lenspair/; done
	for p in capture rectify dataset model simulate calib_samples; do ln -s "$(CURDIR)/$$p" $(TYPECHECK_TREE)/lenspair/$$p; done
	$(BIN)/mypy

unit: $(VENV)/.installed
	$(BIN)/python -m pytest -q

test: lint typecheck unit

bench: $(VENV)/.installed
	$(BIN)/python -m benchmarks --out bench_out

# The README's "Measured results" section: demo + benchmarks on this machine,
# then written from their output files (benchmarks/readme_results.py).
results: demo bench
	$(BIN)/python -m benchmarks.readme_results --demo demo_out --bench bench_out --readme README.md

clean:
	rm -rf $(VENV) demo_out bench_out build *.egg-info
