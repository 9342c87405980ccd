#!/usr/bin/env bash
# Issue 11's checks on a GPU, prepared as one short command for a lent GPU machine
# (the device tool: one NVIDIA GPU, its own Python 3.12 with PyTorch, no network).
#
#   make gpu-wheels        # here: lenspair's wheel and Python 3.12 wheels of what the
#                          # device image lacks (OpenImageIO, rosbags and its needs)
#                          # into .whl/, which git ignores
#   device run: command "bash benchmarks/gpu_checks.sh", carry [".whl"], timeout_s 600
#
# Each check runs even when one before it failed; the exit status is the number of
# checks that failed. What comes back under $OUT: gpu_checks.log (every check's
# output, its exit status and wall seconds), training.json (bench_training: training
# steps/s at every native precision and under torch.compile; inference latency at
# batch 1, 540x360 and 720x480, and throughput at batch 8, at every precision) and
# demo_report.md (the quick demo run on the GPU). The checks, in order:
#   env       the GPU, torch, CUDA, lenspair, and the precisions `auto` chooses
#   bench     python -m benchmarks.bench_training --device cuda --compile
#   demo      lenspair demo --quick (train, eval, tradeoff, restore on the GPU)
#   torchrun  torchrun --nproc_per_node 1 -m lenspair train (DDP with NCCL, 1 GPU)
#   fp16      lenspair train --precision fp16 (autocast + GradScaler, checkpoints, validation)
#   tests     the tests that skip without CUDA, run where CUDA is
# torchrun with one process runs the launcher and process-group path; with a world
# size of 1 the networks are not wrapped in DDP (2-process DDP is tested on the CPU).
# Not yet run on a GPU: expect a few minutes (torch.compile took 43 s of
# bench_training on an H100, docs/results/gpu_h100.md); the CPU rehearsal below takes
# about 75 s on 2 cores.
#
# A rehearsal on a CPU (tiny sizes, no compile, bf16 in place of fp16, the local
# environment instead of .whl):
#   GPU_CHECKS_DEVICE=cpu PYTHON=.venv/bin/python OUT=/tmp/gc bash benchmarks/gpu_checks.sh
set -uo pipefail

DEVICE=${GPU_CHECKS_DEVICE:-cuda}
PY=${PYTHON:-python3}
OUT=${OUT:-gpu_checks_out}
REPO=$(cd "$(dirname "$0")/.." && pwd)
WORK=$(mktemp -d /tmp/gpu_checks.XXXXXX)
mkdir -p "$OUT"
LOG="$OUT/gpu_checks.log"
: >"$LOG"
export PYTHONUNBUFFERED=1 MPLBACKEND=Agg

if [ -d "$REPO/.whl" ] && [ "$DEVICE" = cuda ]; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
        --target "$WORK/site" "$REPO"/.whl/*.whl >>"$LOG" 2>&1 ||
        { echo "gpu_checks: installing .whl/ failed (see $LOG)" | tee -a "$LOG"; exit 100; }
    export PYTHONPATH="$WORK/site${PYTHONPATH:+:$PYTHONPATH}"
fi
# Run from a copy of the benchmarks and tests only: from the repository root, its
# lenspair/ folder would shadow the installed package (whose stages map to the
# root's capture/, model/, ... folders).
mkdir -p "$WORK/src"
cp -r "$REPO/benchmarks" "$REPO/tests" "$REPO/pyproject.toml" "$WORK/src/"
cd "$WORK/src" || exit 100

failed=0
check() { # check NAME COMMAND...: run, log output, exit status and wall seconds
    local name=$1 start rc ms
    shift
    echo "=== $name: $*" >>"$LOG"
    start=$(date +%s%N)
    "$@" >>"$LOG" 2>&1
    rc=$?
    ms=$((($(date +%s%N) - start) / 1000000))
    printf '=== %s: exit %d, %d.%d s\n' "$name" "$rc" $((ms / 1000)) $((ms % 1000 / 100)) |
        tee -a "$LOG"
    [ "$rc" -eq 0 ] || failed=$((failed + 1))
}

if [ "$DEVICE" = cuda ]; then
    BENCH=(--steps 20 --warmup 5 --compile)
    TRAIN=(--crop-size 256 --batch-size 8 --max-steps 40)
    HALF=fp16
else
    BENCH=(--steps 1 --warmup 0 --batch 2 --crop 64)
    TRAIN=(--crop-size 64 --batch-size 2 --max-steps 4)
    HALF=bf16
fi
DATA="$WORK/demo/dataset"

ENV_REPORT="
import torch, lenspair
from lenspair.model.precision import choose_precision
device = torch.device('$DEVICE')
name = torch.cuda.get_device_name(device) if device.type == 'cuda' else 'cpu'
print('torch', torch.__version__, 'cuda', torch.version.cuda, 'device', name)
print('lenspair', lenspair.__version__, 'from', lenspair.__file__)
for use in ('train', 'infer'):
    print(use, choose_precision('auto', device, use).as_dict())
"
command -v nvidia-smi >/dev/null && nvidia-smi -L >>"$LOG" 2>&1
check env "$PY" -c "$ENV_REPORT"
check bench "$PY" -m benchmarks.bench_training --device "$DEVICE" "${BENCH[@]}" --out "$OUT"
check demo "$PY" -m lenspair demo --quick --out "$WORK/demo"
cp "$WORK/demo/report.md" "$OUT/demo_report.md" 2>/dev/null
check torchrun "$PY" -m torch.distributed.run --standalone --nproc_per_node 1 -m lenspair \
    train "$DATA" --out "$WORK/ddp1" --device "$DEVICE" "${TRAIN[@]}"
check "$HALF" "$PY" -m lenspair train "$DATA" --out "$WORK/$HALF" --device "$DEVICE" \
    --precision "$HALF" "${TRAIN[@]}"
check tests "$PY" -m pytest -q -p no:cacheprovider -p no:randomly \
    tests/model/test_device.py tests/model/test_detector.py tests/model/test_precision.py

echo "gpu_checks: $failed check(s) failed; log in $LOG" | tee -a "$LOG"
exit "$failed"
