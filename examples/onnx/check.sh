#!/usr/bin/env bash
# The exported ONNX graph, run by onnxruntime from Python (run_onnx.py), reproduces
# `ivp eval --iterations 1`'s D-MSE on data/blender-dev/clip_001 (targets 6, 8, 10) within 0.5%.
# Usage: examples/onnx/check.sh [IVP_BINARY]   (default: target/debug/ivp, as the tests build it)
set -euo pipefail
cd "$(dirname "$0")/../.."
ivp=${1:-target/debug/ivp}
model=results/ablate/full/seed0/model.safetensors
clip=data/blender-dev/clip_001
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

"$ivp" --quiet export --checkpoint "$model" --onnx "$work/model.onnx"
for t in 6 8 10; do
  "$ivp" --quiet infer --clip "$clip" --target "$t" --out "$work/$t" --network-inputs --model "$model" --iterations 1 >/dev/null
done
python3 examples/onnx/run_onnx.py "$work/model.onnx" "$work"/{6,8,10}/network_inputs.safetensors | tee "$work/python.txt"
"$ivp" --quiet eval --data "$clip" --targets 6,8,10 --methods ivp --iterations 1 --model "$model" --json "$work/eval.json" >/dev/null
python3 - "$work/python.txt" "$work/eval.json" <<'PY'
import json, re, sys
python = float(re.search(r"mean D-MSE over \d+ targets: ([0-9.]+)", open(sys.argv[1]).read()).group(1))
ivp = json.load(open(sys.argv[2]))["methods"]["ivp"]["d_mse"]
gap = abs(python - ivp) / ivp
print(f"ONNX + onnxruntime + numpy: D-MSE {python:.2f}; ivp eval --iterations 1: {ivp:.2f}; gap {100 * gap:.3f}%")
sys.exit(0 if gap <= 0.005 else f"the ONNX path's D-MSE differs from ivp's by {100 * gap:.2f}% (> 0.5%)")
PY
