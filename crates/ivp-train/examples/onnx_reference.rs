//! ivp's side of the ONNX check (examples/onnx/check.sh, run by `.ci/run`): the network inputs and
//! the vectors ivp computes from them (`IvpNet::masked_output`), for the graph that `ivp export
//! --onnx` writes to reproduce within 1e-4 of the largest vector (examples/onnx/check_vectors.py).
//!
//!     onnx_reference TRAINED_MODEL OUT_DIR
//!
//! writes to OUT_DIR:
//! - `models/NAME.safetensors`, the models to export: `trained` (a copy of TRAINED_MODEL, which
//!   must be of the `full` variant), `perturbed` (the same with its `e3` weights 0.1% larger: the
//!   negative control), and `no-tg`, `no-depth`, `full` (seeded, width 0.125, a half-width depth
//!   head: every vector variant, and every width read from the file);
//! - `cases/NAME.safetensors`, one per comparison: the graph's inputs `prior`, `depth`, `hole` and
//!   ivp's `vectors`;
//! - `manifest.json`: each model's configuration, and each case's file, graph and whether the graph
//!   must match ivp's vectors (`match`) or not (`differ`: the perturbed graph against the trained
//!   network's vectors).
//!
//! Built by `cargo test --workspace` (which builds the examples) to target/debug/examples/.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use candle_core::{DType, Device, Tensor};
use ivp_core::nn::model::{IvpNet, ModelConfig, NetInput, Variant};
use ivp_train::checkpoint::{load_model, network_from, restore_parameters, save_model};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::json;

/// The sizes the graph is checked at: odd sides, a 320x240 frame and one inference tile (a core of
/// 32 with 32 pixels of context on each side).
const SIZES: [(usize, usize); 3] = [(37, 53), (240, 320), (96, 96)];

/// The odd size every vector variant is also checked at, with its inputs' seed.
const VARIANT_SIZE: (usize, usize, u64) = (45, 31, 7);

/// Network inputs of one (height, width): a prior of a few pixels, depths of 0.5 to 20 that are 0
/// in the holes, and holes on about a third of the pixels in runs along rows.
fn inputs(h: usize, w: usize, seed: u64) -> Result<[Tensor; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut next = move || rng.random::<f32>();
    let n = h * w;
    let hole: Vec<f32> = (0..n).map(|i| f32::from((i / 5 + (i / w) / 3).is_multiple_of(3) && next() < 0.9)).collect();
    let depth: Vec<f32> = hole.iter().map(|&m| if m > 0.0 { 0.0 } else { 0.5 + 19.5 * next() }).collect();
    let prior: Vec<f32> = (0..2 * n).map(|_| 8.0 * next() - 4.0).collect();
    let t = |v: Vec<f32>, c: usize| Tensor::from_vec(v, (1, c, h, w), &Device::Cpu);
    Ok([t(prior, 2)?, t(depth, 1)?, t(hole, 1)?])
}

fn ivp_vectors(net: &IvpNet, [prior, depth, hole]: &[Tensor; 3]) -> Result<Tensor> {
    let (_, _, h, w) = hole.dims4()?;
    let warped = Tensor::zeros((1, 3, h, w), DType::F32, &Device::Cpu)?;
    let input = NetInput { prior, warped_depth: depth, mask: hole, warped: &warped, last: None, last_warped: None };
    Ok(net.masked_output(&input)?)
}

/// The cases and models written so far, for the manifest.
struct Writer {
    out: PathBuf,
    models: serde_json::Map<String, serde_json::Value>,
    cases: Vec<serde_json::Value>,
}

impl Writer {
    fn model(&mut self, name: &str, config: &ModelConfig) {
        let entry = json!({
            "file": format!("models/{name}.safetensors"),
            "graph": format!("models/{name}.onnx"),
            "variant": config.variant.as_str(),
            "width_mult": config.width_mult,
            "depth_head_mult": config.depth_head_mult,
        });
        self.models.insert(name.to_string(), entry);
    }

    /// One comparison: `net`'s vectors of `inputs` against the graph of `graph` (a model's name).
    fn case(&mut self, name: &str, graph: &str, expect: &str, net: &IvpNet, inputs: &[Tensor; 3]) -> Result<()> {
        let [prior, depth, hole] = inputs;
        let vectors = ivp_vectors(net, inputs)?;
        let file = format!("cases/{name}.safetensors");
        let tensors =
            [("prior", prior.clone()), ("depth", depth.clone()), ("hole", hole.clone()), ("vectors", vectors)];
        candle_core::safetensors::save(&HashMap::from(tensors), self.out.join(&file))?;
        self.cases.push(json!({ "name": name, "file": file, "graph": graph, "expect": expect }));
        Ok(())
    }
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [trained, out] = args.as_slice() else {
        anyhow::bail!("usage: onnx_reference TRAINED_MODEL OUT_DIR");
    };
    let (trained, out) = (Path::new(trained), PathBuf::from(out));
    std::fs::create_dir_all(out.join("models"))?;
    std::fs::create_dir_all(out.join("cases"))?;
    let mut writer = Writer { out: out.clone(), models: Default::default(), cases: Vec::new() };

    // The trained model at every size: what the graph must reproduce is a trained network's.
    let (net, config) = load_model(trained)?;
    ensure!(
        config.variant == Variant::Full,
        "{}: a `full` model is expected, not `{}`",
        trained.display(),
        config.variant
    );
    std::fs::copy(trained, out.join("models/trained.safetensors"))
        .with_context(|| format!("copying {}", trained.display()))?;
    writer.model("trained", &config);
    for (i, (h, w)) in SIZES.into_iter().enumerate() {
        writer.case(&format!("trained-{h}x{w}"), "trained", "match", &net, &inputs(h, w, i as u64 + 1)?)?;
    }

    // The negative control: the graph of the same model with its `e3` weights 0.1% larger must
    // differ from the trained network's vectors, and match its own network's.
    let bytes = std::fs::read(trained)?;
    let mut tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu)?;
    let perturbed = (&tensors["e3.weight"] * 1.001)?;
    tensors.insert("e3.weight".into(), perturbed);
    let perturbed_net = network_from(trained, &tensors, config)?.detached();
    let perturbed_file = out.join("models/perturbed.safetensors");
    let (_, varmap) = IvpNet::seeded(config, 0)?;
    restore_parameters(&perturbed_file, &varmap, &tensors)?;
    save_model(&perturbed_file, &varmap, &config, None)?;
    writer.model("perturbed", &config);
    let control = inputs(37, 53, 1)?;
    writer.case("perturbed-vs-trained-37x53", "perturbed", "differ", &net, &control)?;
    writer.case("perturbed-vs-perturbed-37x53", "perturbed", "match", &perturbed_net, &control)?;

    // Every vector variant: `no-tg` reads zeros in place of the prior and `no-depth` zeros in place
    // of the depth head, inside the graph (the inputs stay the same three).
    for variant in [Variant::NoTemporalPrior, Variant::NoDepth, Variant::Full] {
        let config = ModelConfig::new(variant, 0.125).with_depth_head_mult(0.5);
        let (_, varmap) = IvpNet::seeded(config, 3)?;
        let file = out.join(format!("models/{variant}.safetensors"));
        save_model(&file, &varmap, &config, None)?;
        writer.model(variant.as_str(), &config);
        let (net, _) = load_model(&file)?;
        let (h, w, seed) = VARIANT_SIZE;
        let sizes =
            std::iter::once((h, w, seed)).chain(SIZES.into_iter().enumerate().map(|(i, (h, w))| (h, w, i as u64 + 1)));
        for (h, w, seed) in sizes {
            writer.case(&format!("{variant}-{h}x{w}"), variant.as_str(), "match", &net, &inputs(h, w, seed)?)?;
        }
    }

    let manifest = json!({ "models": writer.models, "cases": writer.cases });
    std::fs::write(out.join("manifest.json"), serde_json::to_string_pretty(&manifest)?)?;
    println!("{} cases of {} models in {}", writer.cases.len(), writer.models.len(), out.display());
    Ok(())
}
