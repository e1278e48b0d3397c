#!/usr/bin/env bash
# Fine-tune the shipped model of every sensor side by side on one GPU machine (16 cores), in one command.
#
#   OUT=out_dir [RUN_SECONDS=limit per run] tools/gpu_train_sensors.sh [TRAIN_MINUTES] [SCANS] [SEQUENCES_PER_PRESET]
#
# Each sensor gets its own freshly simulated, randomised drives (seed 300: neither the training seed 100
# nor the evaluation suite's seeds), its own cache and its own training process, started from
# checkpoints/fastmos_beams_last.pt (weights and normalisation, a new schedule). The runs stop after
# TRAIN_MINUTES of training; best.pt of each run and one tar of logs, metrics and last.pt land in $OUT.
# Needs numpy, torch, PyYAML and embreex (a wheel in .whl/ is installed into /tmp/site if present).
set -u
echo "cores: $(nproc)"
minutes=${1:-3.5}
scans=${2:-60}
per_preset=${3:-8}
out=${OUT:?set OUT to the folder the results go to}
if ! python3 -c "import embreex" 2>/dev/null && ls .whl/embreex-*.whl >/dev/null 2>&1; then
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
        .whl/embreex-*.whl && export PYTHONPATH=/tmp/site:${PYTHONPATH:-} || exit 1
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-} PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1
python3 - <<'EOF' || exit 1
import torch, embreex, numpy, yaml
print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "numpy", numpy.__version__, flush=True)
EOF

train=""
for p in b t e; do
    for i in $(seq 0 $((per_preset - 1))); do train="$train,$p$(printf %02d "$i")"; done
done
train="[${train#,}]"
start=$(date +%s)
for pair in hdl64:fastmos_beams vlp16:fastmos_vlp16 vlp32c:fastmos_vlp32c os1-64:fastmos_os164 \
            os1-128:fastmos_os1128; do
    sensor=${pair%%:*}
    config=${pair#*:}
    name=g_${config#fastmos_}
    timeout "${RUN_SECONDS:-100000}" python3 tools/train_models.py --config "configs/$config.yaml" --data "data/$name" --scans "$scans" \
        --seed 300 --jobs 3 --runs runs_gpu \
        --variant "$name sensor=$sensor train_sequences=$train valid_sequences=[bv0,tv0,ev0] \
init_from=checkpoints/fastmos_beams_last.pt epochs=60 max_minutes=$minutes lr=0.0005 lr_decay=0.95 \
warmup_epochs=0.5 workers=3 cache_workers=3 threads=2 valid_stride=1 cache_dir=data/gcache" \
        > "runs_gpu_$name.out" 2>&1 &
done
wait
echo "all runs ended after $(( $(date +%s) - start )) s"
for f in runs_gpu_*.out; do echo "== $f"; grep -v "^caching" "$f" | tail -4; done
for d in runs_gpu/g_*/; do
    d=${d%/}
    [ -f "$d/best.pt" ] && cp "$d/best.pt" "$out/$(basename "$d")_best.pt"
    tail -n 25 "runs_gpu/$(basename "$d").log"
done
tar -cf "$out/runs_gpu.tar" --exclude=best.pt --exclude=".*.tmp" runs_gpu runs_gpu_*.out 2>/dev/null
ls -la "$out"
