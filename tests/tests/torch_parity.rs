//! Exported weights load into `IvpUNet` of shared/bench/torch_reference.py with strict loading and
//! give the same vectors. Runs where python3 has torch and safetensors; says so when it skips.

use std::collections::HashMap;
use std::process::Command;

use candle_core::{Device, Tensor};
use ivp_core::nn::model::{IvpNet, ModelConfig, NetInput, Variant};
use ivp_tests::{python_has, torch_reference_dir};
use ivp_train::checkpoint::{load_model, save_model};

const SCRIPT: &str = r#"
import sys
import torch
from safetensors.torch import load_file, save_file
sys.path.insert(0, sys.argv[1])
from torch_reference import IvpUNet
model, inputs, out, width = sys.argv[2], sys.argv[3], sys.argv[4], float(sys.argv[5])
net = IvpUNet(width)
net.load_state_dict(load_file(model), strict=True)
x = load_file(inputs)
with torch.no_grad():
    vectors = net(x["prior"], x["depth"], x["hole"])
save_file({"vectors": vectors.contiguous()}, out)
"#;

/// Deterministic inputs of an odd size (the decoder crops its upsampled maps).
fn inputs(h: usize, w: usize) -> (Tensor, Tensor, Tensor) {
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    };
    let n = h * w;
    let prior: Vec<f32> = (0..2 * n).map(|_| 6.0 * next() - 3.0).collect();
    let depth: Vec<f32> = (0..n).map(|_| 10.0 * next()).collect();
    let hole: Vec<f32> = (0..n).map(|_| f32::from(next() < 0.3)).collect();
    let t = |v: Vec<f32>, c: usize| Tensor::from_vec(v, (1, c, h, w), &Device::Cpu).unwrap();
    (t(prior, 2), t(depth, 1), t(hole, 1))
}

#[test]
fn exported_weights_give_the_same_vectors_in_pytorch() {
    if !python_has(&["torch", "safetensors"]) {
        eprintln!("skipped: python3 with torch and safetensors is not available (pip install torch safetensors numpy)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (variant, width_mult) in [(Variant::Full, 0.25), (Variant::NoTemporalPrior, 0.125), (Variant::Full, 1.0)] {
        let config = ModelConfig { variant, width_mult };
        let (_, varmap) = IvpNet::seeded(config, 11).unwrap();
        let model = dir.path().join(format!("{variant}-{width_mult}.safetensors"));
        save_model(&model, &varmap, &config, None).unwrap();
        // What ivp computes from the file it wrote, as a user would load it.
        let (net, loaded) = load_model(&model).unwrap();
        assert_eq!(loaded, config);

        let (prior, depth, hole) = inputs(37, 50);
        let ours = net
            .raw_output(&NetInput {
                prior: &prior,
                warped_depth: &depth,
                mask: &hole,
                warped: &Tensor::zeros((1, 3, 37, 50), candle_core::DType::F32, &Device::Cpu).unwrap(),
                last: None,
                last_warped: None,
            })
            .unwrap();
        // `no-tg` feeds zeros in place of the prior: so does the reference here.
        let torch_prior = if variant == Variant::NoTemporalPrior { prior.zeros_like().unwrap() } else { prior };
        let input_file = dir.path().join("inputs.safetensors");
        let tensors = HashMap::from([("prior", torch_prior), ("depth", depth), ("hole", hole)]);
        candle_core::safetensors::save(&tensors, &input_file).unwrap();
        let out_file = dir.path().join("vectors.safetensors");
        let output = Command::new("python3")
            .args(["-c", SCRIPT])
            .arg(torch_reference_dir())
            .args([&model, &input_file, &out_file])
            .arg(width_mult.to_string())
            .output()
            .unwrap();
        assert!(output.status.success(), "python failed: {}", String::from_utf8_lossy(&output.stderr));
        let theirs = candle_core::safetensors::load(&out_file, &Device::Cpu).unwrap().remove("vectors").unwrap();

        assert_eq!(theirs.dims(), ours.dims());
        let (a, b): (Vec<f32>, Vec<f32>) =
            (ours.flatten_all().unwrap().to_vec1().unwrap(), theirs.flatten_all().unwrap().to_vec1().unwrap());
        let scale = b.iter().fold(1f32, |m, v| m.max(v.abs()));
        let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
        assert!(worst <= 1e-4 * scale, "{variant} x{width_mult}: max difference {worst} (largest vector {scale})");
        assert!(b.iter().any(|v| *v != 0.0), "the reference predicted no vector at all");
    }
}
