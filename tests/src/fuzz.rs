//! The fuzzing harness: what the fuzz targets in `fuzz/` run on each input, and what
//! `tests/fuzz_corpus.rs` replays on the committed corpus (`fuzz/corpus/<target>/`).
//!
//! Each run must end in `Ok` or in an error that names the file it is about; a panic, a hang or an
//! allocation far beyond the input's size (libFuzzer's `-malloc_limit_mb`) is a finding.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device, Tensor};
use ivp_core::nn::model::NetInput;
use ivp_core::{DepthMap, Intrinsics, RgbImage, WorldToCamera};
use ivp_data::{write_clip, Clip, Frame};
use ivp_train::checkpoint::{load_checkpoint, load_model};

/// Frame size of the base clip: small, so that a run costs microseconds.
const WIDTH: usize = 24;
const HEIGHT: usize = 16;

/// What an input of the `clip` target replaces in the base clip, chosen by its first byte (modulo
/// the count); the rest of the input is the new content. The last entry adds a frame file whose
/// *name* is the rest of the input (a valid PNG inside): frame numbering is input too.
const CLIP_FILES: [&str; 5] =
    ["TransformationMatrices.csv", "CameraIntrinsics.csv", "depth/0001.exr", "rgb/0001.png", "rgb/"];

/// A small valid clip in a temporary folder; every run damages one file and puts it back.
pub struct ClipHarness {
    dir: tempfile::TempDir,
}

impl Default for ClipHarness {
    fn default() -> Self {
        Self::new()
    }
}

impl ClipHarness {
    pub fn new() -> Self {
        let dir = tempfile::tempdir().expect("a temporary folder");
        let frames: Vec<Frame> = (0..3)
            .map(|n| Frame {
                image: RgbImage::from_fn(WIDTH, HEIGHT, |u, v| {
                    [u as f32 / WIDTH as f32, v as f32 / HEIGHT as f32, ((u + v + n) % 5) as f32 / 4.0]
                }),
                // A near box in front of a far wall, so that the motion opens holes.
                depth: DepthMap::from_fn(WIDTH, HEIGHT, |u, _| [if (8..14).contains(&u) { 2.0 } else { 6.0 }]),
            })
            .collect();
        let poses: Vec<WorldToCamera> = (0..3)
            .map(|n| {
                let mut m = [0.0; 16];
                for i in 0..4 {
                    m[i * 5] = 1.0;
                }
                m[3] = 0.05 * n as f64;
                WorldToCamera::from_row_major(m)
            })
            .collect();
        let k = Intrinsics::new(20.0, 20.0, (WIDTH as f64 - 1.0) / 2.0, (HEIGHT as f64 - 1.0) / 2.0);
        write_clip(dir.path(), &frames, &poses, Some(&k)).expect("the base clip is valid");
        Self { dir }
    }

    /// The base clip's files, the seeds of the `clip` corpus: selector byte, then content.
    pub fn seeds(&self) -> Vec<Vec<u8>> {
        let mut seeds: Vec<Vec<u8>> = CLIP_FILES[..4]
            .iter()
            .enumerate()
            .map(|(i, f)| [vec![i as u8], std::fs::read(self.dir.path().join(f)).expect("a base file")].concat())
            .collect();
        seeds.push([vec![4u8], b"0003.png".to_vec()].concat());
        seeds
    }

    /// Opens and checks the clip with one file replaced by `input`, then restores the file.
    pub fn run(&self, input: &[u8]) -> Result<(), String> {
        let Some((&selector, content)) = input.split_first() else { return Ok(()) };
        let clip = self.dir.path();
        let target = CLIP_FILES[usize::from(selector) % CLIP_FILES.len()];
        if target == "rgb/" {
            // A stray frame file: its name is the input.
            let name: String =
                String::from_utf8_lossy(content).chars().filter(|c| !matches!(c, '/' | '\\' | '\0')).collect();
            if name.is_empty() || name == "." || name == ".." || name.len() > 200 {
                return Ok(());
            }
            let stray = clip.join("rgb").join(&name);
            if stray.exists() {
                return Ok(()); // a base file: replacing it is the other selectors' job
            }
            std::fs::copy(clip.join("rgb/0000.png"), &stray).map_err(|e| e.to_string())?;
            let outcome = open_and_check(clip);
            std::fs::remove_file(&stray).expect("removing the stray frame");
            return outcome;
        }
        let path = clip.join(target);
        let original = std::fs::read(&path).expect("a base file");
        std::fs::write(&path, content).expect("writing the damaged file");
        let outcome = open_and_check(clip);
        std::fs::write(&path, original).expect("restoring the base file");
        outcome
    }
}

/// `Clip::open`, every frame loaded, and `ivp check`'s analysis: errors must name a path in the
/// clip (the clip folder or one of its files).
fn open_and_check(clip: &Path) -> Result<(), String> {
    let result = (|| -> anyhow::Result<()> {
        let opened = Clip::open(clip)?;
        for i in 0..opened.len() {
            opened.load_frame(i)?;
        }
        let report = ivp_train::check::check_clip(&opened)?;
        let _ = report.verdict();
        Ok(())
    })();
    result.map_err(|e| {
        let message = format!("{e:#}");
        assert!(message.contains(&clip.display().to_string()), "an error that names no file of the clip: {message}");
        message
    })
}

/// Model files: `load_model` and `load_checkpoint` on the input's bytes; a model that loads must
/// run on a small frame and give finite vectors.
pub struct ModelHarness {
    dir: tempfile::TempDir,
}

impl Default for ModelHarness {
    fn default() -> Self {
        Self::new()
    }
}

impl ModelHarness {
    pub fn new() -> Self {
        Self { dir: tempfile::tempdir().expect("a temporary folder") }
    }

    pub fn file(&self) -> PathBuf {
        self.dir.path().join("model.safetensors")
    }

    pub fn run(&self, input: &[u8]) -> Result<(), String> {
        let path = self.file();
        std::fs::write(&path, input).expect("writing the model file");
        let names_file = |e: &dyn std::fmt::Display| {
            let message = e.to_string();
            assert!(message.contains(&path.display().to_string()), "an error that names no file: {message}");
            message
        };
        let checkpoint = load_checkpoint(&path).map(drop).map_err(|e| names_file(&e));
        let (net, _) = match load_model(&path) {
            Ok(loaded) => loaded,
            Err(e) => return checkpoint.and(Err(names_file(&e))),
        };
        let zeros = |c: usize| Tensor::zeros((1, c, 12, 20), DType::F32, &Device::Cpu).expect("a tensor");
        let (prior, depth, mask, warped) =
            (zeros(2), zeros(1).affine(1.0, 3.0).unwrap(), zeros(1).affine(1.0, 1.0).unwrap(), zeros(3));
        let input = NetInput {
            prior: &prior,
            warped_depth: &depth,
            mask: &mask,
            warped: &warped,
            last: Some(&warped),
            last_warped: Some(&warped),
        };
        let output = net.masked_output(&input).map_err(|e| e.to_string())?;
        let values: Vec<f32> = output.flatten_all().and_then(|t| t.to_vec1()).map_err(|e| e.to_string())?;
        assert!(values.iter().all(|v| v.is_finite()), "a model that loaded gives non-finite output");
        Ok(())
    }
}

/// Writes the seeds of both corpora into `corpus/<target>/`: the base clip's files, and model
/// files and a checkpoint as ivp writes them (the smallest network, so that inputs stay small).
pub fn write_seeds(corpus: &Path) -> std::io::Result<()> {
    let clip = corpus.join("clip");
    std::fs::create_dir_all(&clip)?;
    for (i, seed) in ClipHarness::new().seeds().iter().enumerate() {
        std::fs::write(clip.join(format!("seed-{i}")), seed)?;
    }
    let model = corpus.join("model");
    std::fs::create_dir_all(&model)?;
    let dir = tempfile::tempdir()?;
    for (i, variant) in
        [ivp_core::nn::model::Variant::Full, ivp_core::nn::model::Variant::Intensity].into_iter().enumerate()
    {
        let config = ivp_core::nn::model::ModelConfig::new(variant, 0.03125);
        let (_, varmap) = ivp_core::nn::model::IvpNet::seeded(config, 1).map_err(std::io::Error::other)?;
        let path = dir.path().join("m.safetensors");
        ivp_train::checkpoint::save_model(&path, &varmap, &config, Some(7)).map_err(std::io::Error::other)?;
        let bytes = std::fs::read(&path)?;
        std::fs::write(model.join(format!("seed-{i}")), &bytes)?;
        // Its header alone: mutations of the metadata and shapes are where the size bombs were.
        let header = 8 + u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        std::fs::write(model.join(format!("seed-{i}-header")), &bytes[..header.min(bytes.len())])?;
    }
    Ok(())
}
