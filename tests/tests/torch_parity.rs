//! Parity with the PyTorch reference network, sampler and losses (the project's
//! `torch_reference.py`), two ways:
//! - the committed fixtures in `tests/fixtures/torch_parity/` (weights, inputs and what PyTorch
//!   computed from them in one training step, made once by `make_fixture.py` there) are replayed
//!   here without torch: the vectors, the predicted frame, the loss terms and every gradient;
//! - live, where python3 has torch and safetensors: weights that ivp exports load into the
//!   reference with strict loading and give the same vectors. Without torch it says that it
//!   skipped, and `.ci/run` counts it as skipped, not passed.

use std::collections::HashMap;
use std::process::Command;

use candle_core::{Device, Tensor, Var};
use ivp_core::nn::loss::{ivp_loss, LossWeights};
use ivp_core::nn::model::{named_parameters, IvpNet, ModelConfig, NetInput, Variant};
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
    // Without torch (or the reference) this returns early: cargo counts it as passed, so `.ci/run`
    // reports it as skipped instead, and the committed fixtures above still check parity.
    let reference = torch_reference_dir().join("torch_reference.py");
    if !python_has(&["torch", "safetensors"]) || !reference.is_file() {
        eprintln!(
            "SKIPPED: the live comparison with PyTorch needs python3 with torch and safetensors \
             (pip install torch safetensors numpy) and {}",
            reference.display()
        );
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for (variant, width_mult) in [(Variant::Full, 0.25), (Variant::NoTemporalPrior, 0.125), (Variant::Full, 1.0)] {
        let config = ModelConfig::new(variant, width_mult);
        let (_, varmap) = IvpNet::seeded(config, 11).unwrap();
        let model = dir.path().join(format!("{variant}-{width_mult}.safetensors"));
        save_model(&model, &varmap, &config, None).unwrap();
        // What ivp computes from the file it wrote, as a user would load it.
        let (net, loaded) = load_model(&model).unwrap();
        assert_eq!(loaded, config);

        let (prior, depth, hole) = inputs(37, 50);
        let ours = net
            .masked_output(&NetInput {
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

/// The committed fixtures: file, variant and width multiplier.
const FIXTURES: [(&str, Variant, f64); 2] =
    [("full-0.25.safetensors", Variant::Full, 0.25), ("no-tg-0.125.safetensors", Variant::NoTemporalPrior, 0.125)];

/// Largest absolute difference between two tensors of the same shape, and the largest magnitude
/// of the reference (at least `floor`, so that tiny references are compared absolutely).
fn difference(ours: &Tensor, theirs: &Tensor, what: &str, floor: f32) -> (f32, f32) {
    assert_eq!(ours.dims(), theirs.dims(), "{what}: shapes differ");
    let a: Vec<f32> = ours.flatten_all().unwrap().to_vec1().unwrap();
    let b: Vec<f32> = theirs.flatten_all().unwrap().to_vec1().unwrap();
    let worst = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0f32, f32::max);
    (worst, b.iter().fold(floor, |m, v| m.max(v.abs())))
}

#[test]
fn committed_fixtures_match_a_pytorch_training_step() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/torch_parity");
    for (file, variant, width_mult) in FIXTURES {
        let mut fixture = candle_core::safetensors::load(dir.join(file), &Device::Cpu)
            .unwrap_or_else(|e| panic!("{}: {e}", dir.join(file).display()));
        let mut take = |name: &str| fixture.remove(name).unwrap_or_else(|| panic!("{file}: no tensor `{name}`"));

        // The reference's weights, loaded strictly: every parameter present with its shape.
        let config = ModelConfig::new(variant, width_mult);
        let (net, varmap) = IvpNet::seeded(config, 0).unwrap();
        let parameters = named_parameters(&varmap);
        for (name, var) in &parameters {
            var.set(&take(&format!("param.{name}"))).unwrap_or_else(|e| panic!("{file}: `{name}`: {e}"));
        }
        let (prior, depth, hole) = (take("input.prior"), take("input.depth"), take("input.hole"));
        let truth = take("input.truth");
        let warped = Var::from_tensor(&take("input.warped")).unwrap();

        // One training step: vectors, predicted frame, losses, gradients.
        let input = NetInput {
            prior: &prior,
            warped_depth: &depth,
            mask: &hole,
            warped: warped.as_tensor(),
            last: None,
            last_warped: None,
        };
        let output = net.forward(&input).unwrap();
        let vectors = output.vectors.expect("a vector variant");
        let loss = ivp_loss(&output.frame, &truth, &hole, Some(&vectors), &LossWeights::default()).unwrap();
        let gradients = loss.total.backward().unwrap();

        let (worst, scale) = difference(&vectors, &take("ref.vectors"), "vectors", 1.0);
        assert!(worst <= 1e-4 * scale, "{file}: vectors differ by {worst} (largest {scale})");
        assert!(scale > 1e-3, "{file}: the reference predicted no vector at all");
        let (worst, _) = difference(&output.frame, &take("ref.predicted"), "predicted frame", 1.0);
        assert!(worst <= 1e-4, "{file}: predicted frames differ by {worst}");
        for (name, ours) in [("mse", &loss.mse), ("ssim", &loss.ssim), ("smooth", &loss.smooth), ("total", &loss.total)]
        {
            let (ours, theirs) =
                (ours.to_scalar::<f32>().unwrap(), take(&format!("ref.{name}")).to_vec1::<f32>().unwrap()[0]);
            assert!((ours - theirs).abs() <= 1e-5 * theirs.abs().max(1.0), "{file}: loss {name}: {ours} vs {theirs}");
        }
        let (mut checked, mut worst_gradient) = (0, 0f32);
        for (name, var) in
            parameters.iter().map(|(n, v)| (format!("grad.{n}"), v)).chain([("grad.input.warped".to_string(), &warped)])
        {
            let ours = gradients.get(var.as_tensor()).unwrap_or_else(|| panic!("{file}: no gradient for {name}"));
            let (worst, scale) = difference(ours, &take(&name), &name, 1e-6);
            assert!(worst <= 1e-4 * scale, "{file}: {name} differs by {worst} (largest {scale})");
            worst_gradient = worst_gradient.max(worst / scale);
            checked += 1;
        }
        assert_eq!(checked, parameters.len() + 1);
        eprintln!("{file}: {checked} gradients, worst relative difference {worst_gradient:.1e}");
        assert!(fixture.is_empty(), "{file}: tensors not compared: {:?}", fixture.keys().collect::<Vec<_>>());
    }
}

#[test]
fn committed_loss_fixture_matches_at_the_kinks() {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/torch_parity/losses.safetensors");
    let mut fixture =
        candle_core::safetensors::load(&path, &Device::Cpu).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut take = |name: &str| fixture.remove(name).unwrap_or_else(|| panic!("losses: no tensor `{name}`"));
    let prediction = Var::from_tensor(&take("input.prediction")).unwrap();
    let vectors = Var::from_tensor(&take("input.vectors")).unwrap();
    let (truth, hole) = (take("input.truth"), take("input.hole"));
    let loss =
        ivp_loss(prediction.as_tensor(), &truth, &hole, Some(vectors.as_tensor()), &LossWeights::default()).unwrap();
    for (name, ours) in [("mse", &loss.mse), ("ssim", &loss.ssim), ("smooth", &loss.smooth)] {
        let (ours, theirs) =
            (ours.to_scalar::<f32>().unwrap(), take(&format!("ref.{name}")).to_vec1::<f32>().unwrap()[0]);
        assert!((ours - theirs).abs() <= 1e-5, "loss {name}: {ours} vs {theirs}");
    }
    let gradients = loss.total.backward().unwrap();
    for (name, var) in [("prediction", &prediction), ("vectors", &vectors)] {
        let ours = gradients.get(var.as_tensor()).expect("a gradient");
        let (worst, scale) = difference(ours, &take(&format!("grad.input.{name}")), name, 1e-6);
        assert!(worst <= 1e-4 * scale, "gradient of the {name}: differs by {worst} (largest {scale})");
    }
    assert!(fixture.is_empty(), "losses: tensors not compared: {:?}", fixture.keys().collect::<Vec<_>>());
}
