#!/usr/bin/env bash
# The ONNX export checked from Python with onnxruntime, against what the current build of ivp computes:
# 1. check_vectors.py: the graphs `ivp export --onnx` writes give ivp's vectors within 1e-4 of the
#    largest: the committed trained model at 37x53, 320x240 and a tile's 96x96, every vector
#    variant (seeded, small) at 45x31 and those sizes; and the graph of the trained model with one
#    weight 0.1% larger fails that comparison (negative control). ivp's side (inputs, vectors,
#    models) is written at check time by the example crates/ivp-train/examples/onnx_reference.rs.
# 2. run_onnx.py: the graph with everything around it in numpy reproduces
#    `ivp eval --iterations 1`'s D-MSE on data/blender-dev/clip_001 (targets 6, 8, 10) within 0.5%.
# Usage: examples/onnx/check.sh [IVP_BINARY]   (default: target/debug/ivp, as the tests build it;
# the example is read from the folder beside it, examples/onnx_reference, which `cargo test
# --workspace` builds). Each check prints one last line starting with "ONNX"; any failure exits
# non-zero, naming what differed.
set -euo pipefail
cd "$(dirname "$0")/../.."
ivp=${1:-target/debug/ivp}
reference=$(dirname "$ivp")/examples/onnx_reference
model=results/ablate/full/seed0/model.safetensors
clip=data/blender-dev/clip_001
for binary in "$ivp" "$reference"; do
  if [ ! -x "$binary" ]; then
    echo "$binary: missing; build it with cargo test --workspace (or cargo build -p ivp-train --bin ivp --example onnx_reference)" >&2
    exit 1
  fi
done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# 1. ivp's vectors, from every exported graph.
"$reference" "$model" "$work/vectors"
for m in "$work"/vectors/models/*.safetensors; do
  "$ivp" --quiet export --checkpoint "$m" --onnx "${m%.safetensors}.onnx" >/dev/null
done
python3 examples/onnx/check_vectors.py "$work/vectors"

# 2. The D-MSE of the whole infilling, from Python.
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
