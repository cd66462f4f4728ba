#!/usr/bin/env bash
# Stage 2 on a CUDA GPU: the agents' tests (the CUDA one included), the update's cost on the
# GPU for the `residual-cpu` and `residual-paper` presets, and a short `residual-paper` training
# run (three 128-pixel views rendered through EGL, the networks on the GPU), as a GPU user
# would start it. Each step has its own time limit, so a slow step cannot hide the others.
#
#     bash results/gpu/gpu_check.sh OUTDIR
#
# Needs the project importable (installed, or PYTHONPATH=src) and `python3` with a CUDA build
# of torch. Writes OUTDIR/{gpu.txt,pytest.log,update_cost_*.txt,train.log,metrics.csv}.
set -u
out=${1:?usage: gpu_check.sh OUTDIR}
mkdir -p "$out"
export MUJOCO_GL=${MUJOCO_GL:-egl} PYTHONUNBUFFERED=1

nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > "$out/gpu.txt" 2>&1
python3 -c "import torch, mujoco; print('torch', torch.__version__, 'cuda', torch.version.cuda, \
'bf16', torch.cuda.is_bf16_supported(), 'mujoco', mujoco.__version__)" >> "$out/gpu.txt" 2>&1
cat "$out/gpu.txt"

timeout 120 python3 -m pytest -q -p no:cacheprovider tests/agents > "$out/pytest.log" 2>&1
tail -3 "$out/pytest.log"

for preset in residual-cpu residual-paper; do
    timeout 75 python3 benchmarks/update_cost.py --preset "$preset" --device cuda --threads 4 \
        --updates 40 --repeats 3 --no-csv > "$out/update_cost_$preset.txt" 2>&1
    cat "$out/update_cost_$preset.txt"
done

# The paper preset as its header says (`--agent.device cuda`), shortened: 6000 env steps of 4
# envs, updates from step 2000, one evaluation of 10 episodes at 3000 and 6000 steps, a 20k
# replay (4.4 GB of images instead of the preset's 22 GB).
run=$(mktemp -d)
timeout 200 python3 -c "from clamgen.cli import main; main()" train-residual \
    --preset residual-paper --agent.device cuda --replay.capacity 20000 \
    --loop.total-env-steps 6000 --loop.learning-starts 2000 --loop.eval-every-steps 3000 \
    --loop.num-eval-episodes 10 --loop.log-every-steps 500 --run-dir "$run" \
    > "$out/train.log" 2>&1
echo "train-residual exit status $?" >> "$out/train.log"
tr '\r' '\n' < "$out/train.log" | grep -v "^\s*$" | tail -8
cp "$run/metrics.csv" "$out/metrics.csv" 2>/dev/null
ls "$run" >> "$out/train.log"
