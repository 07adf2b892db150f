//! `ivp export --onnx` and `ivp infer --network-inputs` from the command line: the command writes a
//! graph and refuses bad input clearly, and the network inputs are what MODEL.md states. That the
//! graph gives ivp's vectors (every vector variant, within 1e-4 of the largest, with a negative
//! control) is checked from Python with onnxruntime: examples/onnx/check.sh, run by `.ci/run`.

use std::path::{Path, PathBuf};
use std::process::Command;

use candle_core::Device;
use ivp_core::nn::model::{IvpNet, ModelConfig, Variant};
use ivp_train::checkpoint::save_model;

/// A committed trained model of the width the recipe trains (results/ablate/full/seed0, of the
/// ablation's recipe).
fn trained_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../results/ablate/full/seed0/model.safetensors")
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
