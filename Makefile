# Two commands on a fresh machine: `make demo` and `make test`.
# TORCH_SPEC pins the CPU wheel that CI machines carry offline; on a normal
# machine the same pin resolves to the regular (CUDA-enabled) PyPI build.
# Override it to use another torch: `make demo TORCH_SPEC=torch`.
PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
BIN := $(VENV)/bin

.PHONY: demo test lint typecheck unit bench results tradeoff-seeds table2 pretrained gpu-wheels clean

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
# then written from their output files (benchmarks/readme_results.py). Where auto
# trains at bf16 (native and measured faster), the demo runs a second time with oneDNN
# capped below bf16, as on a CPU without it (auto then trains at fp32): both times go
# in the section.
BF16_AUTO := import sys, torch; from lenspair.model.precision import choose_precision; sys.exit(choose_precision("auto", torch.device("cpu"), "train").precision != "bf16")
results: demo bench
	if $(BIN)/python -c '$(BF16_AUTO)'; then \
		ONEDNN_MAX_CPU_ISA=AVX512_CORE_VNNI $(BIN)/lenspair demo --out demo_out_fp32; fi
	$(BIN)/python -m benchmarks.readme_results --demo demo_out --demo-fp32 demo_out_fp32 \
		--bench bench_out --readme README.md

# Issue 12: the tradeoff over seeds with a convergence check (4 variants x 3 seeds x 2000
# steps, crop 128, batch 4, learning rate decaying over the second half, on Table 2's
# dataset). Each seed trains in its own one-thread process, side by side (about an hour and
# three quarters on 2 cores, docs/results/tradeoff_seeds_cpu.md); a last run reuses their training and
# times every network alone. 800 constant-rate steps at crop 256 ran on an H100
# (docs/results/gpu_h100.md). Then the paper's Table 2 on simulated pairs (2 pretrainings
# of 1200 steps and 9 fine-tunings of 800: about an hour and a half on 2 CPU cores;
# docs/results/table2.md), the weights (at most 1500 optimiser steps per network, batch 8,
# crop 128: the shipped ones stopped at 800, see their model card; then scored as shipped
# on the demo's test split). Each prints its table and
# writes it beside its runs.
# TRADEOFF_BUDGET, TRADEOFF_VARIANTS and TRADEOFF_OUT run another budget, e.g. the
# 4000- and 8000-step runs of G, GE, GEA and GEA-w0.5 that docs/results/tradeoff_budgets.md
# compares with 800 and 2000 (`make tradeoff-seeds TRADEOFF_BUDGET=4000
# TRADEOFF_VARIANTS=G,GE,GEA,GEA-w0.5 TRADEOFF_OUT=tradeoff_seeds_4000_out`: about 50 minutes
# a variant on a 2-core AMD EPYC; TRADEOFF_BUDGET=8000 TRADEOFF_OUT=tradeoff_seeds_8000_out:
# about 95 minutes for GEA, 90 for G or GE, 80 for GEA-w0.5;
# docs/results/tradeoff_seeds_cpu_{4000,8000}steps.md). A rerun into the
# same folder reuses the variants already trained there and trains only the new ones.
TRADEOFF_BUDGET ?= 2000
TRADEOFF_VARIANTS ?= G,GE,GEA,GEA-w0.5
TRADEOFF_OUT ?= tradeoff_seeds_out
TRADEOFF := table2_out/demo/dataset --budget $(TRADEOFF_BUDGET) --variants $(TRADEOFF_VARIANTS) \
	--config benchmarks/tradeoff_cpu.yaml
tradeoff-seeds: $(VENV)/.installed
	$(BIN)/python -m benchmarks.table2 --out table2_out --frames 60 --splits 0.6,0.15,0.25 --data-only
	mkdir -p $(TRADEOFF_OUT)
	pids=; for k in 0 1 2; do \
		OMP_NUM_THREADS=1 $(BIN)/lenspair tradeoff $(TRADEOFF) --seeds $$k \
			--out $(TRADEOFF_OUT)/seed$$k --no-int8 --latency-runs 1 \
			> $(TRADEOFF_OUT)/seed$$k.log 2>&1 & pids="$$pids $$!"; done; \
	for pid in $$pids; do wait $$pid || exit 1; done
	$(BIN)/lenspair tradeoff $(TRADEOFF) --seeds 0,1,2 --out $(TRADEOFF_OUT)

table2: $(VENV)/.installed
	$(BIN)/python -m benchmarks.table2 --out table2_out --frames 60 --splits 0.6,0.15,0.25 \
		--pretrain-steps 1200 --finetune-steps 800 --seeds 0 1 2 --crop-size 128 --batch-size 4 \
		--config benchmarks/table2_cpu.yaml

pretrained: demo
	$(BIN)/python -m benchmarks.pretrain_weights --channels 1 3 --steps 1500
	$(BIN)/python -m benchmarks.pretrain_weights --rescore --dataset demo_out/dataset
	$(BIN)/python -m benchmarks.model_card

# Issue 11's GPU checks, prepared for a lent GPU machine (benchmarks/gpu_checks.sh says
# how to run them there): lenspair's wheel and Python 3.12 wheels of what the machine's
# image lacks, into .whl/ (git ignores it; the device tool carries it).
GPU_WHEELS := OpenImageIO rosbags apsw ruamel.yaml backports.zstd lz4
gpu-wheels: $(VENV)/.installed
	rm -rf .whl && mkdir .whl
	$(BIN)/pip wheel -q --no-deps --no-build-isolation -w .whl .
	$(BIN)/pip download -q --no-deps --only-binary=:all: --python-version 3.12 \
		--implementation cp --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 \
		--platform manylinux2014_x86_64 -d .whl $(GPU_WHEELS)

clean:
	rm -rf $(VENV) demo_out demo_out_fp32 bench_out build *.egg-info .whl gpu_checks_out
