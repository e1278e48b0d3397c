#!/usr/bin/env bash
# Train the per-sensor models side by side on one lent GPU machine (16 cores), in one command that ends
# by a deadline.
#
#   OUT=out_dir [DEADLINE=seconds] [SCANS=100] [PER_PRESET=12] [WORK=/dev/shm/ros2_mos] \
#       tools/gpu_train_sensors.sh [SENSOR...]
#
# 1. Simulates PER_PRESET randomised drives per preset (b*, t*, e*, s* slow_traffic) plus the validation drives bv0/tv0/ev0
#    of every sensor, seed 300 (neither the CPU recipe's seed 100 nor the evaluation suite's seeds), one
#    sensor after another with every core.
# 2. Starts one training process per run: each sensor's model fine-tuned from its starting checkpoint
#    (dataset poses + pose noise, its config's crop width), and for the VLP-16 also a 2x wider FastMOS from
#    scratch (its 16 x 1024 image leaves the CPU budget room for it). Each run builds its input cache with
#    4 workers and then trains with 3 loader workers.
# 3. Stops every run DEADLINE seconds after the start (a run keeps best.pt and last.pt of its last whole
#    epoch) and copies best.pt of each run plus one tar of logs, metrics and configs to $OUT.
#
# The round-5 lesson: the loader sets the pace, not the GPU (a crop costs ~5 ms on one core), so the runs
# share the cores and not much else. The round-7 lesson: on the lent machine (gVisor) simulating and caching
# in the repository's folder ran 10-15x slower than here, and no epoch ran (benchmarks/experiments.md). The
# data and caches now go to WORK (memory-backed /dev/shm by default; an untested guess that file writes were
# the cost), and one drive is timed first: the script stops early if a drive takes longer than 20 s.
# Needs numpy, torch, PyYAML and embreex (a wheel in .whl/ is installed into /tmp/site if present).
# A dry run on a CPU: SCANS=12 PER_PRESET=1 DEADLINE=240.
set -u
start=$(date +%s)
out=${OUT:?set OUT to the folder the results go to}
deadline=${DEADLINE:-520}
scans=${SCANS:-100}
per_preset=${PER_PRESET:-12}
sensors=("$@")
[ ${#sensors[@]} -gt 0 ] || sensors=(vlp16 vlp32c os1-64 os1-128)
echo "cores: $(nproc)"
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
for p in b t e s; do
    for i in $(seq 0 $((per_preset - 1))); do train="$train,$p$(printf %02d "$i")"; done
done
train="[${train#,}]"
# Each sensor's latest CPU recipe and the checkpoint its shipped model came from (benchmarks/experiments.md).
config_of() { case $1 in vlp16) echo fastmos_vlp16_free;; vlp32c) echo fastmos_vlp32c_far;; os1-64) echo fastmos_os164_slow;;
              os1-128) echo fastmos_os1128_slow;; hdl64) echo fastmos_beams_free16;;
              *) echo "unknown sensor $1" >&2; return 1;; esac; }
init_of() { case $1 in vlp16) echo checkpoints/fastmos_vlp16_free_best.pt;;
                       vlp32c) echo checkpoints/fastmos_vlp32c_far_best.pt;;
                       os1-64) echo checkpoints/fastmos_os164_slow_best.pt;;
                       os1-128) echo checkpoints/fastmos_os1128_slow_best.pt;;
                       *) echo checkpoints/fastmos_beams_free16_best.pt;; esac; }
work=${WORK:-/dev/shm/ros2_mos}
mkdir -p "$work" || exit 1
common="train_sequences=$train valid_sequences=[bv0,tv0,ev0] poses=dataset valid_stride=2 workers=3 \
cache_workers=4 threads=1 cache_dir=$work/cache"
probe=$(date +%s)
python3 tools/train_models.py --config "configs/$(config_of "${sensors[0]}").yaml" --data "$work/probe" \
    --scans "$scans" --seed 301 --jobs 1 --simulate-only --variant "probe train_sequences=[b00] valid_sequences=[]" \
    || exit 1
probe=$(( $(date +%s) - probe ))
echo "one ${sensors[0]} drive of $scans scans: $probe s"
[ "$probe" -le 20 ] || { echo "simulation too slow here for the deadline; stopping"; exit 1; }

for sensor in "${sensors[@]}"; do
    config=$(config_of "$sensor") || exit 2
    python3 tools/train_models.py --config "configs/$config.yaml" --data "$work/g_$sensor" --scans "$scans" \
        --seed 300 --jobs "$(nproc)" --simulate-only --variant "sim $common" || exit 1
done
echo "simulation done after $(( $(date +%s) - start )) s"

left=$(( deadline - ($(date +%s) - start) ))
minutes=$(python3 -c "print(max(0.2, ($left - 100) / 60))")  # caching takes about 100 s of the time left
for sensor in "${sensors[@]}"; do
    config=$(config_of "$sensor")
    variants=(--variant "g_$sensor $common init_from=$(init_of "$sensor") epochs=40 max_minutes=$minutes \
lr=0.0005 lr_decay=0.93 warmup_epochs=0.5")
    if [ "$sensor" = vlp16 ]; then
        variants+=(--variant "g_${sensor}_wide $common network_kwargs={\"widths\":[32,64,96],\"full_res_channels\":16} \
init_from=null epochs=40 max_minutes=$minutes lr=0.003 lr_decay=0.92 warmup_epochs=1")
    fi
    timeout "$left" python3 tools/train_models.py --config "configs/$config.yaml" --data "$work/g_$sensor" \
        --scans "$scans" --seed 300 --jobs 4 --runs runs_gpu "${variants[@]}" > "runs_gpu_$sensor.out" 2>&1 &
done
wait
echo "all runs ended after $(( $(date +%s) - start )) s"
for f in runs_gpu_*.out; do echo "== $f"; grep -v "^caching" "$f" | tail -3; done
for d in runs_gpu/g_*/; do
    d=${d%/}
    [ -f "$d/best.pt" ] && cp "$d/best.pt" "$out/$(basename "$d")_best.pt"
    tail -n 4 "runs_gpu/$(basename "$d").log"
done
tar -cf "$out/runs_gpu.tar" --exclude=best.pt --exclude=last.pt --exclude=".*.tmp" runs_gpu runs_gpu_*.out 2>/dev/null
ls -la "$out"
