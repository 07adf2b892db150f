"""Checks that ivp's exported ONNX graphs, run by onnxruntime, give ivp's vectors.

    python3 examples/onnx/check_vectors.py DIR

DIR is what `onnx_reference` (crates/ivp-train/examples/onnx_reference.rs) writes, with each model
of `DIR/models/` exported beside it by `ivp export --onnx` (check.sh does both): a manifest of
models and cases, and per case the graph's inputs `prior`, `depth`, `hole` and the `vectors` ivp
computed from them (`IvpNet::masked_output`). For each case the graph runs on the inputs, and its
vectors must be those of ivp within 1e-4 of the largest |vector| (at least 1):

- a `match` case fails when they differ by more, when the graph's output is not one `vectors` of
  shape (N, 2, H, W), or when ivp's vectors have too few non-zero values to compare (a tenth of
  the pixels);
- a `differ` case (the negative control: a graph of the model with one weight 0.1% larger,
  against the unperturbed network's vectors) fails when they agree within the tolerance.

Each graph's metadata must also name its model's variant and widths. Exits non-zero, naming every
case that failed; never skips one. Needs numpy, onnxruntime and safetensors.
"""

import json
import os
import sys

import numpy as np
from safetensors.numpy import load_file

TOLERANCE = 1e-4
INPUTS = ("prior", "depth", "hole")


def compare(ours, theirs):
    """The largest difference and the largest |vector| of ivp's vectors (at least 1), in f32."""
    scale = max(np.float32(1), np.abs(ours).max(initial=0))
    worst = np.abs(ours - theirs).max(initial=0)
    return float(worst), float(scale)


def check_metadata(name, model, session):
    """Problems with a graph's metadata against its model's configuration."""
    meta = session.get_modelmeta().custom_metadata_map
    problems = []
    if meta.get("ivp.variant") != model["variant"]:
        problems.append(f"graph of `{name}`: variant {meta.get('ivp.variant')!r}, expected {model['variant']!r}")
    for key in ("width_mult", "depth_head_mult"):
        value = meta.get(f"ivp.{key}")
        if value is None or float(value) != float(model[key]):
            problems.append(f"graph of `{name}`: {key} {value!r}, expected {model[key]}")
    return problems


def check_case(case, session, directory):
    """Runs one case: a line describing it (None when the graph could not be compared), its problem
    (None when it passes), and its largest difference against the tolerance."""
    t = load_file(os.path.join(directory, case["file"]))
    ours = t["vectors"]
    n, _, h, w = t["hole"].shape
    outputs = [o.name for o in session.get_outputs()]
    if outputs != ["vectors"]:
        return None, f"{case['name']}: the graph's outputs are {outputs}, not one `vectors`", None
    (theirs,) = session.run(["vectors"], {name: t[name] for name in INPUTS})
    if theirs.shape != (n, 2, h, w) or theirs.dtype != np.float32:
        return None, f"{case['name']}: the graph gives {theirs.dtype} {theirs.shape}, expected float32 {(n, 2, h, w)}", None
    worst, scale = compare(ours, theirs)
    within = worst <= TOLERANCE * scale
    numbers = f"largest difference {worst:.2e} {'<=' if within else '>'} tolerance {TOLERANCE * scale:.2e}"
    line = f"{case['name']} (graph `{case['graph']}`, expected to {case['expect']}): {numbers}, largest vector {scale:.2f}"
    problem = None
    if case["expect"] == "match":
        nonzero = int(np.count_nonzero(ours))
        if not within:
            problem = (f"{case['name']}: the graph of `{case['graph']}` differs from ivp's vectors by {worst:.3e} "
                       f"(> {TOLERANCE:g} x largest vector {scale:.3f})")
        elif nonzero <= h * w // 10:
            problem = f"{case['name']}: too few vectors to compare ({nonzero} non-zero of {h}x{w})"
    elif case["expect"] == "differ":
        if within:
            problem = (f"{case['name']}: negative control: the graph of `{case['graph']}` (one weight 0.1% larger) "
                       f"agrees with the unperturbed network within the tolerance ({numbers}): the comparison "
                       "would not see such a change")
    else:
        problem = f"{case['name']}: unknown expectation {case['expect']!r}"
    return line, problem, numbers


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    import onnxruntime as ort

    directory = sys.argv[1]
    with open(os.path.join(directory, "manifest.json")) as f:
        manifest = json.load(f)
    models, cases = manifest["models"], manifest["cases"]
    problems = []
    if not cases or not any(c["expect"] == "differ" for c in cases):
        problems.append(f"{directory}: the manifest has {len(cases)} cases and no negative control")
    sessions = {}
    for name, model in models.items():
        graph = os.path.join(directory, model["graph"])
        if not os.path.exists(graph):
            problems.append(f"graph of `{name}`: {graph} is missing (not exported?)")
            continue
        sessions[name] = ort.InferenceSession(graph, providers=["CPUExecutionProvider"])
        if [i.name for i in sessions[name].get_inputs()] != list(INPUTS):
            problems.append(f"graph of `{name}`: inputs {[i.name for i in sessions[name].get_inputs()]}, expected {list(INPUTS)}")
        problems += check_metadata(name, model, sessions[name])
    counts = {"match": 0, "differ": 0}
    control = []
    for case in cases:
        if case["graph"] not in sessions:
            problems.append(f"{case['name']}: no graph `{case['graph']}`")
            continue
        line, problem, numbers = check_case(case, sessions[case["graph"]], directory)
        if line:
            print(line)
        if problem:
            problems.append(problem)
        else:
            counts[case["expect"]] += 1
            if case["expect"] == "differ":
                control.append(f"{case['name']}: {numbers}")
    if problems:
        for problem in problems:
            print(f"FAILED: {problem}", file=sys.stderr)
        sys.exit(f"the ONNX graphs' vectors check failed: {len(problems)} problem(s) above")
    print(f"ONNX graphs + onnxruntime: ivp's vectors within {TOLERANCE:g} of the largest in {counts['match']} cases "
          f"({len(models)} models); the graph of a 0.1% larger weight fails it ({', '.join(control)})")


if __name__ == "__main__":
    main()
