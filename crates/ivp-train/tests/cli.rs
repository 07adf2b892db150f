//! The `ivp` program end to end on the real Blender clips of the repository (data/blender-dev).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use ivp_core::WorldToCamera;
use ivp_data::{read_poses, read_rgb, write_poses, Clip, POSES_FILE};

fn blender_dev() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/blender-dev");
    assert!(dir.is_dir(), "{} is missing: it is part of the repository (data/README.md)", dir.display());
    dir
}

fn ivp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ivp")).args(args).arg("--quiet").output().expect("running ivp")
}

fn ok(args: &[&str]) -> String {
    let out = ivp(args);
    assert!(out.status.success(), "ivp {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A copy of a clip whose poses are rewritten by `f`.
fn clip_with_poses(src: &Path, dst: &Path, f: impl Fn(&WorldToCamera) -> WorldToCamera) {
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(dst.join(sub)).unwrap();
        for entry in std::fs::read_dir(src.join(sub)).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), dst.join(sub).join(entry.file_name())).unwrap();
        }
    }
    std::fs::copy(src.join("CameraIntrinsics.csv"), dst.join("CameraIntrinsics.csv")).unwrap();
    let poses: Vec<_> = read_poses(&src.join(POSES_FILE)).unwrap().iter().map(f).collect();
    write_poses(&dst.join(POSES_FILE), &poses).unwrap();
}

#[test]
fn warp_writes_image_holes_and_depth() {
    let out = tempfile::tempdir().unwrap();
    let clip = blender_dev().join("clip_000");
    let stdout = ok(&["warp", "--clip", s(&clip), "--from", "5", "--to", "6", "--out", s(out.path())]);
    assert!(stdout.contains("disocclusions"), "{stdout}");
    let warped = read_rgb(out.path().join("warped.png")).unwrap();
    let holes = image_gray(&out.path().join("holes.png"));
    assert_eq!((warped.width(), warped.height()), (320, 240));
    assert!(holes.iter().all(|&h| h == 0 || h == 128 || h == 255));
    assert!(holes.contains(&255), "a warp of this clip has disocclusions");
    // Disocclusions stay black; new regions are filled.
    for (p, &h) in warped.pixels().iter().zip(&holes) {
        if h == 255 {
            assert_eq!(*p, [0.0; 3]);
        }
    }
    let depth = ivp_data::read_depth_exr(out.path().join("depth.exr")).unwrap();
    assert_eq!((depth.width(), depth.height()), (320, 240));
}

fn image_gray(path: &Path) -> Vec<u8> {
    let img = read_rgb(path).unwrap();
    img.pixels().iter().map(|p| (p[0] * 255.0).round() as u8).collect()
}

/// Exported warps scored with --external score exactly as the internal `warp` method.
#[test]
fn exported_targets_score_like_the_internal_method() {
    let out = tempfile::tempdir().unwrap();
    let data = blender_dev();
    let exported = out.path().join("exported");
    ok(&["warp", "--data", s(&data), "--export-targets", "--out", s(&exported)]);
    assert!(exported.join("clip_002/0008.png").is_file());
    assert!(exported.join("clip_002/0008_holes.png").is_file());
    let json = out.path().join("scores.json");
    let table = ok(&[
        "eval",
        "--data",
        s(&data),
        "--methods",
        "warp,fill",
        "--external",
        &format!("exported={}", s(&exported)),
        "--json",
        s(&json),
    ]);
    assert!(table.contains("| fill"), "{table}");
    let scores: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let (a, b) = (&scores["methods"]["warp"], &scores["methods"]["exported"]);
    for key in ["mse", "d_mse", "ssim", "d_ssim", "tc", "tc_tracks", "frames", "d_frames"] {
        assert_eq!(a[key], b[key], "{key}");
    }
    assert!(a["ms_per_frame"].as_f64().unwrap() > 0.0);
    assert!(a["ms_by_stage"]["warp"].as_f64().is_some());
    // The times' machine, in the JSON and under the table.
    let vectors = scores["machine"]["vectors"].as_str().unwrap();
    assert!(scores["threads"].as_u64().unwrap() >= 1);
    assert!(table.contains(&format!("times on {} ({vectors})", scores["machine"]["cpu"].as_str().unwrap())), "{table}");
}

#[test]
fn eval_names_unknown_methods_and_missing_external_frames() {
    let data = blender_dev();
    let out = ivp(&["eval", "--data", s(&data), "--methods", "copy,magic"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown method `magic`"));

    let empty = tempfile::tempdir().unwrap();
    let out = ivp(&["eval", "--data", s(&data), "--methods", "copy", "--external", &format!("x={}", s(empty.path()))]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("0006.png"), "{err}");
}

#[test]
fn check_passes_a_good_clip() {
    let stdout = ok(&["check", "--clip", s(&blender_dev().join("clip_001"))]);
    assert!(stdout.contains("OK"), "{stdout}");
}

#[test]
fn check_diagnoses_camera_to_world_poses() {
    let tmp = tempfile::tempdir().unwrap();
    clip_with_poses(&blender_dev().join("clip_003"), tmp.path(), |e| WorldToCamera(e.0.inverse()));
    assert!(Clip::open(tmp.path()).is_ok());
    let out = ivp(&["check", "--clip", s(tmp.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "{stdout}");
    assert!(stdout.contains("PROBLEM") && stdout.contains("camera-to-world"), "{stdout}");
}

#[test]
fn check_diagnoses_opengl_axes() {
    let tmp = tempfile::tempdir().unwrap();
    let flip = glam::DMat4::from_diagonal(glam::DVec4::new(1.0, -1.0, -1.0, 1.0));
    clip_with_poses(&blender_dev().join("clip_000"), tmp.path(), |e| WorldToCamera(flip * e.0));
    let out = ivp(&["check", "--clip", s(tmp.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "{stdout}");
    assert!(stdout.contains("OpenGL axes (y up"), "{stdout}");
}

#[test]
fn check_names_unusable_depth_instead_of_blaming_the_poses() {
    let tmp = tempfile::tempdir().unwrap();
    clip_with_poses(&blender_dev().join("clip_000"), tmp.path(), |e| *e);
    let depth_file = tmp.path().join("depth/0001.exr");
    let (w, h) = (320, 240);
    for (value, what) in [(f32::NAN, "NaN"), (f32::INFINITY, "sky"), (0.0, "zero"), (-1.0, "negative"), (1e-9, "tiny")]
    {
        ivp_data::write_depth_exr(&depth_file, &ivp_core::DepthMap::filled(w, h, [value])).unwrap();
        let out = ivp(&["check", "--clip", s(tmp.path())]);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(!out.status.success(), "{what}: {stdout}");
        assert!(stdout.contains("PROBLEM: no usable depth in 1 of"), "{what}: {stdout}");
        assert!(stdout.contains(s(&depth_file)) && stdout.contains("NO USABLE DEPTH"), "{what}: {stdout}");
        assert!(!stdout.contains("fits best if"), "{what}: {stdout}");
    }
    // A quarter of a frame NaN: usable, reported per frame, and the readings are still compared.
    let real = ivp_data::read_depth_exr(blender_dev().join("clip_000/depth/0001.exr")).unwrap();
    let mut depth = real.clone();
    for (i, z) in depth.pixels_mut().iter_mut().enumerate() {
        if i % 4 == 0 {
            *z = [f32::NAN];
        }
    }
    ivp_data::write_depth_exr(&depth_file, &depth).unwrap();
    let stdout = String::from_utf8_lossy(&ivp(&["check", "--clip", s(tmp.path())]).stdout).into_owned();
    assert!(stdout.contains("frame    1: suspicious depth") && stdout.contains("25.0% invalid"), "{stdout}");
    assert!(stdout.contains("warping frames"), "{stdout}");

    // `eval` and `warp` refuse the frame with an error naming the file, instead of scoring holes.
    ivp_data::write_depth_exr(&depth_file, &ivp_core::DepthMap::filled(w, h, [f32::NAN])).unwrap();
    let out = ivp(&["warp", "--clip", s(tmp.path()), "--from", "1", "--to", "2", "--out", s(&tmp.path().join("w"))]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(s(&depth_file)) && err.contains("no usable depth"), "{err}");
}

#[test]
fn check_names_non_rigid_poses_and_bad_intrinsics() {
    let tmp = tempfile::tempdir().unwrap();
    let scale = glam::DMat4::from_scale(glam::DVec3::splat(1.2));
    clip_with_poses(&blender_dev().join("clip_001"), tmp.path(), |e| WorldToCamera(scale * e.0));
    let out = ivp(&["check", "--clip", s(tmp.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "{stdout}");
    assert!(stdout.contains("PROBLEM") && stdout.contains("not a rigid transform"), "{stdout}");
    assert!(stdout.contains(s(&tmp.path().join(POSES_FILE))) && stdout.contains("line 1"), "{stdout}");

    clip_with_poses(&blender_dev().join("clip_001"), tmp.path(), |e| *e);
    let k = tmp.path().join("CameraIntrinsics.csv");
    std::fs::write(&k, "0.9,0,0.5\n0,1.2,0.5\n0,0,1\n").unwrap();
    let out = ivp(&["check", "--clip", s(tmp.path())]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(!out.status.success(), "{stdout}");
    assert!(stdout.contains("normalised intrinsics; give them in pixels") && stdout.contains(s(&k)), "{stdout}");
}

#[test]
fn a_stray_far_numbered_frame_is_named_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    clip_with_poses(&blender_dev().join("clip_000"), tmp.path(), |e| *e);
    let stray = tmp.path().join("rgb/99999999.png");
    std::fs::copy(tmp.path().join("rgb/0000.png"), &stray).unwrap();
    std::fs::copy(tmp.path().join("depth/0000.exr"), tmp.path().join("depth/99999999.exr")).unwrap();
    let start = std::time::Instant::now();
    let out = ivp(&["warp", "--clip", s(tmp.path()), "--from", "0", "--to", "1", "--out", s(&tmp.path().join("w"))]);
    assert!(!out.status.success());
    assert!(start.elapsed().as_secs_f64() < 10.0, "took {:?}", start.elapsed());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(s(&stray)) && err.contains("lies far from"), "{err}");
}

#[test]
fn eval_refuses_a_model_with_broken_weights() {
    use ivp_core::nn::model::{IvpNet, ModelConfig, Variant};
    let tmp = tempfile::tempdir().unwrap();
    let config = ModelConfig::new(Variant::Full, 0.125);
    let (_, varmap) = IvpNet::seeded(config, 1).unwrap();
    let model = tmp.path().join("broken.safetensors");
    let vars = varmap.data().lock().unwrap();
    let bias = &vars["e2.bias"];
    bias.set(&(bias.as_tensor() * f64::NAN).unwrap()).unwrap();
    drop(vars);
    ivp_train::checkpoint::save_model(&model, &varmap, &config, None).unwrap();
    let out = ivp(&["eval", "--data", s(&blender_dev().join("clip_000")), "--methods", "fill", "--model", s(&model)]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(s(&model)) && err.contains("tensor `e2.bias`") && err.contains("non-finite"), "{err}");
}

/// Files under `dir`, relative, with their bytes.
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                out.push((path.strip_prefix(dir).unwrap().to_path_buf(), std::fs::read(&path).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn generate_is_byte_identical_for_a_seed_and_its_clips_check_out() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b, c) = (tmp.path().join("a"), tmp.path().join("b"), tmp.path().join("c"));
    let args = |out: &Path, seed: &str| {
        [
            "generate",
            "--out",
            s(out),
            "--clips",
            "2",
            "--frames",
            "4",
            "--width",
            "96",
            "--height",
            "72",
            "--seed",
            seed,
        ]
        .map(String::from)
        .to_vec()
    };
    for (out, seed) in [(&a, "3"), (&b, "3"), (&c, "4")] {
        let argv = args(out, seed);
        ok(&argv.iter().map(String::as_str).collect::<Vec<_>>());
    }
    let (ta, tb, tc) = (tree(&a), tree(&b), tree(&c));
    assert_eq!(ta.len(), 2 * (4 + 4 + 2), "2 clips: 4 PNG, 4 EXR, poses, intrinsics");
    assert!(ta == tb, "same seed, different bytes");
    assert!(ta != tc, "different seeds, same bytes");
    let stdout = ok(&["check", "--clip", s(&a.join("clip_0001"))]);
    assert!(stdout.contains("OK"), "{stdout}");
    // Near columns and fine textures each change the scenes of a seed; a probability outside
    // [0, 1] is refused by the flag's name.
    for (flag, bad) in [("--near-column-probability", "1.5"), ("--fine-texture-probability", "2")] {
        let changed = tmp.path().join(&flag[2..]);
        let mut argv = args(&changed, "3");
        argv.extend([flag, "1"].map(String::from));
        ok(&argv.iter().map(String::as_str).collect::<Vec<_>>());
        assert!(tree(&changed) != ta, "{flag} 1 changed nothing");
        argv[2] = s(&tmp.path().join(format!("{}-refused", &flag[2..]))).to_string();
        *argv.last_mut().unwrap() = bad.to_string();
        let refused = ivp(&argv.iter().map(String::as_str).collect::<Vec<_>>());
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success() && stderr.contains(flag), "{flag} {bad}: {stderr}");
    }
}

#[test]
fn show_sample_draws_a_sheet_deterministically() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a.png"), tmp.path().join("b.png"));
    let data = blender_dev();
    for out in [&a, &b] {
        let stdout = ok(&["show-sample", "--seed", "5", "--crop", "64", "--data", s(&data), "--out", s(out)]);
        assert!(stdout.contains("clip_"), "{stdout}");
    }
    let sheet = read_rgb(&a).unwrap();
    assert!(sheet.width() > 4 * 64 && sheet.height() > 2 * 64);
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let synthetic = tmp.path().join("synthetic.png");
    ok(&["show-sample", "--seed", "1", "--crop", "32", "--out", s(&synthetic)]);
    assert!(synthetic.is_file());
}

/// A tiny training run through the command line, then every command that reads its model.
#[test]
fn train_export_eval_infer_and_upsample_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let config = dir.path().join("tiny.toml");
    std::fs::write(
        &config,
        "width_mult = 0.125\nsteps = 3\nbatch = 2\ncrop = 32\nvalidation_clips = 1\nvalidation_hd_clips = 0\nlog_every = 1\n\
         checkpoint_every = 1\naverage_checkpoints = 2\nselect_from = 1.0\n",
    )
    .unwrap();
    let stdout = ok(&["train", "--synthetic", "--config", s(&config), "--steps", "2", "--out", s(&run)]);
    assert!(
        stdout.contains("model written to") && stdout.contains("(the mean of the parameters of steps 1, 2)"),
        "{stdout}"
    );
    let written = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(written.contains("steps = 2") && written.contains("crop = 32"), "flags override the file: {written}");
    let model = run.join("model.safetensors");

    let exported = dir.path().join("exported.safetensors");
    let (first, ckpt) =
        (run.join("checkpoints/step_00000001.safetensors"), run.join("checkpoints/step_00000002.safetensors"));
    ok(&["export", "--checkpoint", s(&first), s(&ckpt), "--out", s(&exported)]);
    // The export of the model's window holds the model's tensors, each with its values.
    let tensors = |path: &std::path::Path| -> Vec<(String, Vec<usize>, Vec<f32>)> {
        let mut all: Vec<_> = candle_core::safetensors::load(path, &candle_core::Device::Cpu)
            .unwrap()
            .into_iter()
            .map(|(name, t)| (name, t.dims().to_vec(), t.flatten_all().unwrap().to_vec1().unwrap()))
            .collect();
        all.sort_by(|a, b| a.0.cmp(&b.0));
        all
    };
    let (from_export, from_model) = (tensors(&exported), tensors(&model));
    assert!(from_export.len() > 10 && from_export == from_model, "the export differs from the model");

    // A branch of the run from its first checkpoint says what it changes.
    let branch = dir.path().join("branch");
    let args = ["--config", s(&config), "--steps", "2", "--mse-weight", "20", "--out", s(&branch)];
    let stdout = ok(&[&["train", "--synthetic", "--branch-from", s(&first)][..], &args].concat());
    let expected = format!("branching from {} at step 1; changed: mse_weight: 10.0 -> 20.0\n", s(&first));
    assert!(stdout.contains(&expected), "{stdout}");
    assert!(branch.join("model.safetensors").is_file());

    let clip = blender_dev().join("clip_000");
    let table = ok(&[
        "eval",
        "--data",
        s(&clip),
        "--methods",
        "fill,ivp",
        "--model",
        s(&model),
        "--model",
        &format!("again={}", s(&exported)),
        "--targets",
        "6",
    ]);
    for name in ["| fill", "| ivp", "| again"] {
        assert!(table.contains(name), "{table}");
    }
    // The same weights score the same.
    let row = |name: &str| table.lines().find(|l| l.starts_with(name)).unwrap().split('|').nth(3).unwrap().to_string();
    assert_eq!(row("| ivp "), row("| again "));

    let infer = dir.path().join("infer");
    let stdout = ok(&["infer", "--clip", s(&clip), "--model", s(&model), "--target", "6", "--out", s(&infer)]);
    assert!(stdout.contains("mean absolute error"), "{stdout}");
    for file in ["infilled.png", "holes.png", "vectors.png", "error.png"] {
        let image = read_rgb(infer.join(file)).unwrap();
        assert_eq!((image.width(), image.height()), (320, 240), "{file}");
    }
    // The far blur's strength is a finite number of 0 or more.
    for bad in ["-1", "nan", "inf"] {
        let argv =
            ["infer", "--clip", s(&clip), "--model", s(&model), "--target", "6", "--out", s(&infer), "--far-blur", bad];
        let refused = ivp(&argv);
        let stderr = String::from_utf8_lossy(&refused.stderr);
        assert!(!refused.status.success() && stderr.contains("--far-blur must be"), "--far-blur {bad}: {stderr}");
    }

    let up = dir.path().join("up");
    let stdout = ok(&["upsample", "--clip", s(&clip), "--model", s(&model), "--out", s(&up)]);
    assert!(stdout.contains("12 frames (6 predicted"), "{stdout}");
    let clip_frames = Clip::open(&clip).unwrap();
    let mean_abs_error = |a: &ivp_core::RgbImage, b: &ivp_core::RgbImage| -> f64 {
        let sum: f64 = a
            .pixels()
            .iter()
            .zip(b.pixels())
            .map(|(p, q)| (0..3).map(|c| (p[c] - q[c]).abs() as f64).sum::<f64>())
            .sum();
        sum / (3 * a.len()) as f64
    };
    for t in 0..12 {
        let frame = read_rgb(up.join(format!("frames/{t:04}.png"))).unwrap();
        let truth = clip_frames.load_frame(t).unwrap().image;
        if t % 2 == 0 {
            // Rendered frames pass through unchanged.
            assert_eq!(frame.pixels(), truth.quantized_to_8bit().pixels());
        } else {
            // A predicted frame is the frame before it moved into the new view: nearer the truth
            // than repeating that frame, though not the truth itself.
            let repeated = clip_frames.load_frame(t - 1).unwrap().image;
            let (predicted, copied) = (mean_abs_error(&frame, &truth), mean_abs_error(&repeated, &truth));
            assert!(
                predicted < 0.5 * copied && predicted > 0.0,
                "frame {t}: error {predicted} against {copied} for a copy"
            );
        }
    }
    let gif = std::fs::read(up.join("preview.gif")).unwrap();
    assert!(gif.starts_with(b"GIF89a"));

    // Dense and sparse inference of one target, and a tile shape that is refused with a reason.
    let dense = dir.path().join("dense");
    ok(&["infer", "--clip", s(&clip), "--model", s(&model), "--target", "6", "--dense", "--out", s(&dense)]);
    // Sparse and dense predictions agree: the tiles hold every hole and the context the network
    // reads, so few hole pixels change (PERFORMANCE.md: vectors within 0.5 px at 100% of the
    // hole pixels at 320x240, D-MSE within 0.2%).
    let holes = read_rgb(infer.join("holes.png")).unwrap();
    let (sparse_frame, dense_frame) =
        (read_rgb(infer.join("infilled.png")).unwrap(), read_rgb(dense.join("infilled.png")).unwrap());
    let hole_pixels: Vec<usize> = (0..holes.len()).filter(|&i| holes.pixels()[i][0] == 1.0).collect();
    let differing = hole_pixels.iter().filter(|&&i| sparse_frame.pixels()[i] != dense_frame.pixels()[i]).count();
    assert!(hole_pixels.len() > 50, "{} hole pixels", hole_pixels.len());
    assert!(
        (differing as f64) <= 0.01 * hole_pixels.len() as f64,
        "{differing} of {} hole pixels differ between sparse and dense inference",
        hole_pixels.len()
    );
    let known_equal = (0..holes.len())
        .filter(|&i| holes.pixels()[i][0] == 0.0)
        .all(|i| sparse_frame.pixels()[i] == dense_frame.pixels()[i]);
    assert!(known_equal, "known pixels are the warp's in both");
    let out = ivp(&[
        "infer",
        "--clip",
        s(&clip),
        "--model",
        s(&model),
        "--target",
        "6",
        "--tile-core",
        "24",
        "--out",
        s(&dense),
    ]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("multiples of 16"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // This generated frame's holes are all thin runs (ALGORITHMS.md §6.5): the rule fills them
    // and the network never runs, unless --thin-run 0 leaves them to it.
    let bench_320 = |extra: &[&str]| {
        let args = ["bench", "frame", "--height", "240", "--width", "320", "--width-mult", "0.125", "--runs", "1"];
        let json = ok(&[&args[..], &["--iterations", "2"], extra].concat());
        let report: serde_json::Value = serde_json::from_str(json.trim()).unwrap();
        (json, report)
    };
    let (json, thin) = bench_320(&[]);
    assert!(thin["hole_fraction"].as_f64().unwrap() > 0.0 && thin["tiles"].as_u64() == Some(0), "{json}");
    assert_eq!(thin["stages"]["network"]["median_ms"].as_f64(), Some(0.0), "{json}");
    let (json, report) = bench_320(&["--thin-run", "0"]);
    assert_eq!(report["coverage"], "sparse");
    let median = |stage: &str| report["stages"][stage]["median_ms"].as_f64().unwrap_or(f64::NAN);
    for stage in ["warp", "holes", "prior", "network", "infill"] {
        assert!(median(stage).is_finite() && median(stage) <= median("total"), "{stage}: {json}");
    }
    // The generated frame has holes (smaller ones have none), so the network ran on some tiles.
    assert!(report["hole_fraction"].as_f64().unwrap() > 0.0 && report["tiles"].as_u64().unwrap() > 0, "{json}");
    assert!(median("network") > 0.0 && median("total") > 0.0, "{json}");

    // The frames of a clip on disk, each target by stage with its holes, tiles and error (this
    // clip's slivers reach the network only without the thin-run rule).
    let bench_args = ["bench", "frame", "--data", s(&clip), "--targets", "6,8", "--model", s(&model), "--runs", "1"];
    let json = ok(&[&bench_args[..], &["--thin-run", "0"]].concat());
    let report: serde_json::Value = serde_json::from_str(json.trim()).unwrap();
    let frames = report["frames"].as_array().unwrap();
    assert_eq!((report["case"].as_str(), frames.len()), (Some("clip"), 2), "{json}");
    for (frame, t) in frames.iter().zip([6, 8]) {
        assert_eq!(frame["target"], t);
        assert!(frame["hole_fraction"].as_f64().unwrap() > 0.0, "{json}");
        let read = frame["pixels_read_fraction"].as_f64().unwrap();
        assert!(read > 0.0 && read < 3.0, "sparse tiles read a part of the frame per pass: {json}");
        assert!(frame["d_mse"].as_f64().is_some() && frame["d_mse_fill"].as_f64().is_some(), "{json}");
        // Every time names the CPU it was measured on (the network runs twice as fast with AVX-512).
        assert!(["avx512", "avx2"].contains(&frame["machine"]["vectors"].as_str().unwrap()), "{json}");
        assert!(!frame["machine"]["cpu"].as_str().unwrap().is_empty(), "{json}");
    }
    let totals: Vec<f64> = frames.iter().map(|f| f["stages"]["total"]["median_ms"].as_f64().unwrap()).collect();
    let over = &report["total_over_frames"];
    assert_eq!(over["min_ms"].as_f64().unwrap(), totals.iter().cloned().fold(f64::INFINITY, f64::min), "{json}");
    let out = ivp(&["bench", "frame", "--data", s(&clip), "--targets", "2", "--model", s(&model)]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("target 2 needs frames"));

    // Bad model files are refused with their name.
    let out = ivp(&["infer", "--clip", s(&clip), "--model", s(&config), "--target", "6", "--out", s(&infer)]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains(s(&config)));
}

/// A network with a narrower depth head trains, and its model file says so and runs.
#[test]
fn a_narrower_depth_head_trains_and_its_model_runs() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let config = dir.path().join("tiny.toml");
    std::fs::write(
        &config,
        "width_mult = 0.125\nsteps = 1\nbatch = 2\ncrop = 32\nvalidation_clips = 1\nvalidation_hd_clips = 0\n",
    )
    .unwrap();
    let stdout = ok(&["train", "--synthetic", "--config", s(&config), "--depth-head-mult", "0.5", "--out", s(&run)]);
    assert!(stdout.contains("training full (width 0.125, depth head 0.5)"), "{stdout}");
    let model = run.join("model.safetensors");
    let (_, loaded) = ivp_train::checkpoint::load_model(&model).unwrap();
    assert_eq!((loaded.width_mult, loaded.depth_head_mult), (0.125, 0.5));
    let clip = blender_dev().join("clip_000");
    let table = ok(&["eval", "--data", s(&clip), "--methods", "fill", "--model", s(&model), "--targets", "6"]);
    assert!(table.contains("| ivp "), "{table}");

    let out = ivp(&["train", "--synthetic", "--depth-head-mult", "0.3", "--out", s(&dir.path().join("bad"))]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("depth-head multiplier 0.3"), "{stderr}");
}
