//! `ivp export --onnx`: the exported graph, run by tract (a pure-Rust ONNX runtime), gives ivp's
//! vectors within 1e-4 of the largest, on odd sizes, 320x240 and a tile's size; a perturbed weight
//! makes the same comparison fail; bad input gets a clear error.

use std::path::{Path, PathBuf};
use std::process::Command;

use candle_core::{DType, Device, Tensor};
use ivp_core::nn::model::{IvpNet, ModelConfig, NetInput, Variant};
use ivp_train::checkpoint::{load_model, save_model};
use ivp_train::onnx::export_onnx;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A committed trained model of the width the recipe trains (results/ablate/full/seed0, of the
/// ablation's recipe): what the graph must reproduce is a trained network's, not a random one's.
fn trained_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results/ablate/full/seed0/model.safetensors")
}

/// The sizes the graph is checked at: odd sides, a 320x240 frame and one inference tile (a core of
/// 32 with 32 pixels of context on each side).
const SIZES: [(usize, usize); 3] = [(37, 53), (240, 320), (96, 96)];

/// Network inputs of one (height, width): a prior of a few pixels, depths of 0.5 to 20 that are 0
/// in the holes, and holes on about a third of the pixels in runs along rows.
fn inputs(h: usize, w: usize, seed: u64) -> [Tensor; 3] {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut next = move || rng.random::<f32>();
    let n = h * w;
    let hole: Vec<f32> = (0..n).map(|i| f32::from((i / 5 + (i / w) / 3).is_multiple_of(3) && next() < 0.9)).collect();
    let depth: Vec<f32> = hole.iter().map(|&m| if m > 0.0 { 0.0 } else { 0.5 + 19.5 * next() }).collect();
    let prior: Vec<f32> = (0..2 * n).map(|_| 8.0 * next() - 4.0).collect();
    let t = |v: Vec<f32>, c: usize| Tensor::from_vec(v, (1, c, h, w), &Device::Cpu).unwrap();
    [t(prior, 2), t(depth, 1), t(hole, 1)]
}

fn ivp_vectors(net: &IvpNet, [prior, depth, hole]: &[Tensor; 3]) -> Vec<f32> {
    let (_, _, h, w) = hole.dims4().unwrap();
    let warped = Tensor::zeros((1, 3, h, w), DType::F32, &Device::Cpu).unwrap();
    let input = NetInput { prior, warped_depth: depth, mask: hole, warped: &warped, last: None, last_warped: None };
    net.masked_output(&input).unwrap().flatten_all().unwrap().to_vec1().unwrap()
}

fn tract_vectors(graph: &Path, inputs: &[Tensor; 3]) -> Vec<f32> {
    use tract_onnx::prelude::*;
    let mut model = tract_onnx::onnx().model_for_path(graph).unwrap();
    for (i, t) in inputs.iter().enumerate() {
        model = model.with_input_fact(i, InferenceFact::dt_shape(f32::datum_type(), t.dims())).unwrap();
    }
    let runnable = model.into_optimized().unwrap().into_runnable().unwrap();
    let values: TVec<TValue> = inputs
        .iter()
        .map(|t| {
            let data: Vec<f32> = t.flatten_all().unwrap().to_vec1().unwrap();
            tract_onnx::prelude::Tensor::from_shape(t.dims(), &data).unwrap().into()
        })
        .collect();
    let outputs = runnable.run(values).unwrap();
    assert_eq!(outputs.len(), 1, "the graph has one output, `vectors`");
    assert_eq!(outputs[0].shape(), [1, 2, inputs[0].dim(2).unwrap(), inputs[0].dim(3).unwrap()]);
    outputs[0].to_plain_array_view::<f32>().unwrap().iter().copied().collect()
}

/// The largest difference and the largest |vector| of ivp's vectors.
fn compare(ours: &[f32], theirs: &[f32]) -> (f32, f32) {
    assert_eq!(ours.len(), theirs.len());
    let scale = ours.iter().fold(1f32, |m, v| m.max(v.abs()));
    let worst = ours.iter().zip(theirs).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    (worst, scale)
}

#[test]
fn the_exported_graph_gives_the_trained_models_vectors_at_every_size() {
    let dir = tempfile::tempdir().unwrap();
    let onnx = dir.path().join("model.onnx");
    let config = export_onnx(&[trained_model()], &onnx).unwrap();
    assert_eq!(config.variant, Variant::Full);
    let (net, _) = load_model(&trained_model()).unwrap();
    for (i, (h, w)) in SIZES.into_iter().enumerate() {
        let inputs = inputs(h, w, i as u64 + 1);
        let ours = ivp_vectors(&net, &inputs);
        let (worst, scale) = compare(&ours, &tract_vectors(&onnx, &inputs));
        eprintln!("{h}x{w}: largest difference {worst:.2e}, largest vector {scale:.1}");
        assert!(worst <= 1e-4 * scale, "{h}x{w}: the graph's vectors differ by {worst} (largest vector {scale})");
        assert!(ours.iter().filter(|v| **v != 0.0).count() > h * w / 10, "{h}x{w}: too few vectors to compare");
    }
}

/// The negative control: the same comparison against a graph whose `e3` weights are 0.1% larger
/// fails (and the perturbed network agrees with its own graph).
#[test]
fn a_perturbed_weight_fails_the_comparison() {
    let dir = tempfile::tempdir().unwrap();
    let (net, config) = load_model(&trained_model()).unwrap();
    let bytes = std::fs::read(trained_model()).unwrap();
    let mut tensors = candle_core::safetensors::load_buffer(&bytes, &Device::Cpu).unwrap();
    let perturbed = (&tensors["e3.weight"] * 1.001).unwrap();
    tensors.insert("e3.weight".into(), perturbed);
    let perturbed_net = ivp_train::checkpoint::network_from(&trained_model(), &tensors, config).unwrap();
    let perturbed_file = dir.path().join("perturbed.safetensors");
    save_perturbed(&perturbed_file, &tensors, config);
    let onnx = dir.path().join("perturbed.onnx");
    export_onnx(&[perturbed_file], &onnx).unwrap();

    let inputs = inputs(37, 53, 1);
    let theirs = tract_vectors(&onnx, &inputs);
    let (worst, scale) = compare(&ivp_vectors(&net, &inputs), &theirs);
    eprintln!("perturbed: largest difference {worst:.2e}, largest vector {scale:.1}");
    assert!(worst > 1e-4 * scale, "a perturbed weight went unnoticed: difference {worst}, largest vector {scale}");
    let (worst, scale) = compare(&ivp_vectors(&perturbed_net.detached(), &inputs), &theirs);
    assert!(worst <= 1e-4 * scale, "the perturbed graph differs from its own network by {worst}");
}

fn save_perturbed(path: &Path, tensors: &std::collections::HashMap<String, Tensor>, config: ModelConfig) {
    let (_, varmap) = IvpNet::seeded(config, 0).unwrap();
    ivp_train::checkpoint::restore_parameters(path, &varmap, tensors).unwrap();
    save_model(path, &varmap, &config, None).unwrap();
}

/// `no-tg` reads zeros in place of the prior and `no-depth` zeros in place of the depth head,
/// inside the graph: the inputs stay the same three. Width 0.125 and a half-width depth head keep
/// it small and check that every width is read from the file.
#[test]
fn every_vector_variant_is_exported() {
    let dir = tempfile::tempdir().unwrap();
    for variant in [Variant::NoTemporalPrior, Variant::NoDepth, Variant::Full] {
        let config = ModelConfig::new(variant, 0.125).with_depth_head_mult(0.5);
        let (_, varmap) = IvpNet::seeded(config, 3).unwrap();
        let model = dir.path().join(format!("{variant}.safetensors"));
        save_model(&model, &varmap, &config, None).unwrap();
        let onnx = dir.path().join(format!("{variant}.onnx"));
        assert_eq!(export_onnx(std::slice::from_ref(&model), &onnx).unwrap(), config);
        let (net, _) = load_model(&model).unwrap();
        let inputs = inputs(45, 31, 7);
        let (worst, scale) = compare(&ivp_vectors(&net, &inputs), &tract_vectors(&onnx, &inputs));
        assert!(worst <= 1e-4 * scale, "{variant}: the graph's vectors differ by {worst} (largest vector {scale})");
    }
}

fn ivp(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ivp")).args(args).output().unwrap()
}

fn stderr(output: &std::process::Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

#[test]
fn the_command_writes_a_graph_and_refuses_bad_input_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let model = trained_model();
    let model = model.to_str().unwrap();

    let out = ivp(&["export", "--checkpoint", model, "--onnx", &path("m.onnx")]);
    assert!(out.status.success(), "{}", stderr(&out));
    assert!(String::from_utf8_lossy(&out.stdout).contains("ONNX opset 17"));
    assert!(!dir.path().join("m.safetensors").exists());

    // The intensity variant predicts colours: refused, naming the variant, and nothing written.
    let config = ModelConfig::new(Variant::Intensity, 0.125);
    let (_, varmap) = IvpNet::seeded(config, 1).unwrap();
    save_model(Path::new(&path("intensity.safetensors")), &varmap, &config, None).unwrap();
    let out = ivp(&["export", "--checkpoint", &path("intensity.safetensors"), "--onnx", &path("i.onnx")]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("`intensity` variant predicts colours"), "{}", stderr(&out));
    assert!(!dir.path().join("i.onnx").exists());

    // A file that is not a model.
    std::fs::write(path("notes.txt"), "not a model").unwrap();
    let out = ivp(&["export", "--checkpoint", &path("notes.txt"), "--onnx", &path("n.onnx")]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("notes.txt") && stderr(&out).contains("safetensors"), "{}", stderr(&out));

    // An unknown variant in the metadata.
    let mut text = std::fs::read(model).unwrap();
    let at = text.windows(4).position(|w| w == b"full").expect("the metadata names the variant");
    text[at..at + 4].copy_from_slice(b"fuul");
    std::fs::write(path("fuul.safetensors"), &text).unwrap();
    let out = ivp(&["export", "--checkpoint", &path("fuul.safetensors"), "--onnx", &path("f.onnx")]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("unknown model variant `fuul`"), "{}", stderr(&out));

    // An output folder that does not exist.
    let out = ivp(&["export", "--checkpoint", model, "--onnx", &path("missing/m.onnx")]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("missing/m.onnx: cannot write: its folder does not exist"), "{}", stderr(&out));

    // Neither output.
    let out = ivp(&["export", "--checkpoint", model]);
    assert!(!out.status.success());
    assert!(stderr(&out).contains("--out <OUT>|--onnx <ONNX>"), "{}", stderr(&out));
}

/// `ivp infer --network-inputs` writes the graph's inputs as MODEL.md states them: the hole mask of
/// holes.png's disocclusions, depth 0 on every pixel not known, and the frames beside them.
#[test]
fn infer_writes_the_network_inputs_of_a_target() {
    let dir = tempfile::tempdir().unwrap();
    let clip = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/blender-dev/clip_001");
    let model = trained_model();
    let out = ivp(&[
        "infer",
        "--clip",
        clip.to_str().unwrap(),
        "--target",
        "6",
        "--out",
        dir.path().to_str().unwrap(),
        "--network-inputs",
        "--model",
        model.to_str().unwrap(),
        "--iterations",
        "1",
    ]);
    assert!(out.status.success(), "{}", stderr(&out));
    let tensors = candle_core::safetensors::load(dir.path().join("network_inputs.safetensors"), &Device::Cpu).unwrap();
    let values = |name: &str, channels: usize| -> Vec<f32> {
        let t = &tensors[name];
        assert_eq!(t.dims(), [1, channels, 240, 320], "{name}");
        t.flatten_all().unwrap().to_vec1().unwrap()
    };
    let (hole, depth, known) = (values("hole", 1), values("depth", 1), values("known", 1));
    let holes_png = image::open(dir.path().join("holes.png")).unwrap().to_luma8();
    let disocclusions: Vec<f32> = holes_png.pixels().map(|p| f32::from(p.0[0] == 255)).collect();
    assert_eq!(hole, disocclusions, "`hole` is holes.png's disocclusions");
    assert!(hole.iter().sum::<f32>() > 100.0, "target 6 of clip_001 has disocclusions");
    for i in 0..hole.len() {
        assert_eq!(known[i] == 0.0, holes_png.as_raw()[i] != 0, "pixel {i}: known is the warp's coverage");
        assert!(known[i] > 0.0 || depth[i] == 0.0, "pixel {i}: depth must be 0 where not known");
    }
    assert!(values("prior", 2).iter().any(|v| *v != 0.0), "the target has a prior");
    let threshold = values("threshold", 1);
    for i in 0..hole.len() {
        assert!(hole[i] > 0.0 || threshold[i] == 0.0, "pixel {i}: a threshold off the disocclusions");
        assert!(threshold[i].is_finite() && threshold[i] >= 0.0, "pixel {i}: threshold {}", threshold[i]);
    }
    let with_threshold = threshold.iter().filter(|t| **t > 0.0).count();
    assert!(with_threshold > 100, "most disocclusion pixels have a background threshold: {with_threshold}");
    for name in ["warped", "fill", "truth"] {
        values(name, 3);
    }
}
