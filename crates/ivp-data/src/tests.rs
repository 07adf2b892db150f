//! Tests of the whole crate on small clips built in temporary folders.

use std::fs;
use std::path::{Path, PathBuf};

use exr::prelude as ex;
use exr::prelude::traits::*;
use glam::{DMat4, DQuat, DVec3};
use ivp_core::{DepthMap, Intrinsics, RgbImage, WorldToCamera};

use super::*;

// ---------------------------------------------------------------------------------------------
// Helpers

fn temp() -> tempfile::TempDir {
    tempfile::tempdir().expect("temporary folder")
}

/// A frame whose colours are off the 8-bit grid (to exercise quantisation) and whose depth has
/// awkward f32 values, a NaN and an infinity (to check depth is stored bit-exactly).
fn tiny_frame(w: usize, h: usize, seed: usize) -> Frame {
    let image = RgbImage::from_fn(w, h, |u, v| {
        let x = ((u * 7 + v * 13 + seed * 5) % 97) as f32 / 96.3;
        [x.min(1.0), (u as f32 + 0.37) / w as f32, (v as f32 + 0.11) / h as f32]
    });
    let mut depth = DepthMap::from_fn(w, h, |u, v| [1.0 + u as f32 * 0.1 + v as f32 / 3.0 + seed as f32 * 1e-3]);
    depth.set(0, 0, [f32::NAN]);
    depth.set(1, 0, [f32::INFINITY]);
    Frame { image, depth }
}

fn tiny_pose(k: usize) -> WorldToCamera {
    let rotation = DQuat::from_rotation_y(0.1 * k as f64) * DQuat::from_rotation_x(0.03 * k as f64);
    WorldToCamera(DMat4::from_rotation_translation(rotation, DVec3::new(0.1 * k as f64 + 1e-17, -0.2, 1.0 / 3.0)))
}

const W: usize = 8;
const H: usize = 6;

fn tiny_intrinsics() -> Intrinsics {
    Intrinsics::new(9.5, 10.25, 3.5, 2.5)
}

/// Writes a clip of `n` tiny frames (with intrinsics) and returns what was written.
fn write_tiny_clip(dir: &Path, n: usize) -> (Vec<Frame>, Vec<WorldToCamera>) {
    let frames: Vec<Frame> = (0..n).map(|i| tiny_frame(W, H, i)).collect();
    let poses: Vec<WorldToCamera> = (0..n).map(tiny_pose).collect();
    write_clip(dir, &frames, &poses, Some(&tiny_intrinsics())).expect("write_clip");
    (frames, poses)
}

fn open_err(dir: &Path) -> DataError {
    Clip::open(dir).expect_err("the clip should be refused")
}

/// The message names the file (full path) and contains every `fragment`.
fn assert_message(err: &DataError, file: &Path, fragments: &[&str]) {
    let msg = err.to_string();
    assert!(msg.contains(&file.display().to_string()), "message does not name {}: {msg}", file.display());
    for f in fragments {
        assert!(msg.contains(f), "message lacks `{f}`: {msg}");
    }
}

fn bits(d: &DepthMap) -> Vec<u32> {
    d.as_flat().iter().map(|x| x.to_bits()).collect()
}

fn truncate_file(path: &Path, keep: usize) {
    let bytes = fs::read(path).unwrap();
    assert!(keep < bytes.len());
    fs::write(path, &bytes[..keep]).unwrap();
}

fn write_poses_csv(dir: &Path, text: &str) -> PathBuf {
    let path = dir.join(POSES_FILE);
    fs::write(&path, text).unwrap();
    path
}

const IDENTITY_ROW: &str = "1,0,0,0,0,1,0,0,0,0,1,0,0,0,0,1";

/// Writes an EXR with the given f32 channels (name, constant value).
fn write_exr_channels(path: &Path, w: usize, h: usize, channels: &[(&str, f32)]) {
    let list: Vec<ex::AnyChannel<ex::FlatSamples>> = channels
        .iter()
        .map(|&(name, value)| ex::AnyChannel::new(name, ex::FlatSamples::F32(vec![value; w * h])))
        .collect();
    let channels = ex::AnyChannels::sort(ex::SmallVec::from_vec(list));
    let layer = ex::Layer::new((w, h), ex::LayerAttributes::default(), ex::Encoding::UNCOMPRESSED, channels);
    ex::Image::from_layer(layer).write().to_file(path).unwrap();
}

fn blender_clip(n: usize) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/blender-dev")).join(format!("clip_{n:03}"))
}

// ---------------------------------------------------------------------------------------------
// Round trips

#[test]
fn write_clip_then_open_and_load_round_trips() {
    let dir = temp();
    let (frames, poses) = write_tiny_clip(dir.path(), 3);
    let clip = Clip::open(dir.path()).unwrap();
    assert_eq!((clip.len(), clip.width(), clip.height()), (3, W, H));
    assert_eq!(clip.format(), ClipFormat::IiscVeed);
    assert_eq!(clip.path(), dir.path());
    assert_eq!(*clip.intrinsics(), tiny_intrinsics());
    assert_eq!(clip.poses(), &poses[..], "poses must round-trip exactly");
    assert_eq!(clip.pose(2), &poses[2]);
    assert_eq!(clip.frame_numbers(), vec![0, 1, 2]);
    for (i, written) in frames.iter().enumerate() {
        let loaded = clip.load_frame(i).unwrap();
        assert_eq!(loaded.image, written.image.quantized_to_8bit(), "frame {i}");
        assert_ne!(loaded.image, written.image, "the test image should be off the 8-bit grid");
        assert_eq!(bits(&loaded.depth), bits(&written.depth), "frame {i}: depth must be bit-exact");
    }
}

#[test]
fn write_clip_is_byte_deterministic_and_leaves_no_temporary_files() {
    let (a, b) = (temp(), temp());
    write_tiny_clip(a.path(), 2);
    write_tiny_clip(b.path(), 2);
    write_tiny_clip(b.path(), 2); // overwriting gives the same bytes again
    for rel in ["rgb/0000.png", "rgb/0001.png", "depth/0000.exr", "depth/0001.exr", POSES_FILE, INTRINSICS_FILE] {
        assert_eq!(fs::read(a.path().join(rel)).unwrap(), fs::read(b.path().join(rel)).unwrap(), "{rel}");
    }
    for sub in ["", "rgb", "depth"] {
        for entry in fs::read_dir(b.path().join(sub)).unwrap() {
            let name = entry.unwrap().file_name().to_string_lossy().into_owned();
            assert!(!name.ends_with(".tmp"), "temporary file left: {name}");
        }
    }
}

#[test]
fn write_clip_csv_numbers_round_trip_at_full_precision() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let text = fs::read_to_string(dir.path().join(POSES_FILE)).unwrap();
    assert_eq!(text.lines().count(), 2);
    assert!(text.contains("0.3333333333333333"), "{text}");
    assert_eq!(read_poses(&dir.path().join(POSES_FILE)).unwrap()[1], tiny_pose(1));
}

#[test]
fn write_clip_replaces_an_earlier_longer_clip() {
    let dir = temp();
    write_tiny_clip(dir.path(), 4);
    let frames = vec![tiny_frame(W, H, 9); 2];
    write_clip(dir.path(), &frames, &[tiny_pose(0), tiny_pose(1)], Some(&tiny_intrinsics())).unwrap();
    let clip = Clip::open(dir.path()).unwrap();
    assert_eq!(clip.len(), 2);
    assert!(!dir.path().join("rgb/0003.png").exists() && !dir.path().join("depth/0002.exr").exists());
}

#[test]
fn write_clip_refuses_inconsistent_arguments() {
    let dir = temp();
    let frames = vec![tiny_frame(W, H, 0), tiny_frame(W, H, 1)];
    let k = tiny_intrinsics();
    assert!(write_clip(dir.path(), &frames, &[tiny_pose(0)], Some(&k)).is_err(), "pose count");
    assert!(write_clip(dir.path(), &[], &[], Some(&k)).is_err(), "no frames");
    let odd = vec![tiny_frame(W, H, 0), tiny_frame(W + 1, H, 1)];
    assert!(write_clip(dir.path(), &odd, &[tiny_pose(0), tiny_pose(1)], Some(&k)).is_err(), "sizes");
    let err = write_clip(dir.path(), &frames, &[tiny_pose(0), tiny_pose(1)], None).unwrap_err();
    assert_message(&err, dir.path(), &["1920x1080"]);
    let singular = WorldToCamera(DMat4::ZERO);
    assert!(write_clip(dir.path(), &frames, &[tiny_pose(0), singular], Some(&k)).is_err(), "singular pose");
    assert!(!dir.path().join("rgb").exists(), "nothing is written when the arguments are refused");
}

#[test]
fn clip_without_intrinsics_file_uses_the_iisc_veed_camera_at_1080p() {
    let dir = temp();
    let frame = Frame { image: RgbImage::filled(1920, 1080, [0.5; 3]), depth: DepthMap::filled(1920, 1080, [2.0]) };
    write_clip(dir.path(), &[frame], &[tiny_pose(0)], None).unwrap();
    let clip = Clip::open(dir.path()).unwrap();
    assert_eq!(*clip.intrinsics(), Intrinsics::iisc_veed_default());
    assert_eq!(clip.load_depth(0).unwrap().at(1919, 1079), 2.0);
}

#[test]
fn blender_dev_clip_000_loads() {
    let path = blender_clip(0);
    let clip = Clip::open(&path).unwrap();
    assert_eq!((clip.len(), clip.width(), clip.height()), (12, 320, 240));
    assert!((clip.intrinsics().fx - 287.7).abs() < 0.05, "{:?}", clip.intrinsics());
    assert_eq!(clip.poses().len(), 12);
    for i in [0, 11] {
        let frame = clip.load_frame(i).unwrap();
        assert_eq!((frame.image.width(), frame.image.height()), (320, 240));
        assert!(frame.depth.as_flat().iter().all(|&z| z.is_finite() && z > 0.0), "frame {i}: depth finite > 0");
        assert!(frame.image.as_flat().iter().all(|&c| (0.0..=1.0).contains(&c)));
    }
}

#[test]
fn every_blender_dev_clip_opens() {
    for n in 0..4 {
        let clip = Clip::open(blender_clip(n)).unwrap();
        assert_eq!(clip.len(), 12);
    }
}

// ---------------------------------------------------------------------------------------------
// Frame numbering

#[test]
fn missing_depth_frame_is_named() {
    let dir = temp();
    write_tiny_clip(dir.path(), 4);
    let missing = dir.path().join("depth/0002.exr");
    fs::remove_file(&missing).unwrap();
    assert_message(&open_err(dir.path()), &missing, &["missing depth"]);
}

#[test]
fn gap_in_frame_numbers_is_named() {
    let dir = temp();
    write_tiny_clip(dir.path(), 4);
    fs::remove_file(dir.path().join("depth/0001.exr")).unwrap();
    fs::remove_file(dir.path().join("rgb/0001.png")).unwrap();
    assert_message(&open_err(dir.path()), &dir.path().join("rgb/0001.png"), &["gaps"]);
}

#[test]
fn stray_far_numbered_frame_is_refused_without_allocating() {
    for number in ["99999999", "18446744073709551615"] {
        let dir = temp();
        write_tiny_clip(dir.path(), 3);
        let stray = dir.path().join(format!("rgb/{number}.png"));
        fs::copy(dir.path().join("rgb/0000.png"), &stray).unwrap();
        fs::copy(dir.path().join("depth/0000.exr"), dir.path().join(format!("depth/{number}.exr"))).unwrap();
        let start = std::time::Instant::now();
        let err = open_err(dir.path());
        assert!(start.elapsed().as_secs_f64() < 1.0, "listing the gaps took {:?}", start.elapsed());
        assert_message(&err, &stray, &["gaps", "rgb/0003.png", "more frames", "lies far from the other 3 frames"]);
    }
    // A stray below the others is named too.
    let dir = temp();
    write_tiny_clip(dir.path(), 3);
    for n in 0..3 {
        for (sub, ext) in [("rgb", "png"), ("depth", "exr")] {
            let from = dir.path().join(format!("{sub}/{n:04}.{ext}"));
            fs::rename(&from, dir.path().join(format!("{sub}/{}.{ext}", 50_000_000 + n))).unwrap();
        }
    }
    fs::copy(dir.path().join("rgb/50000000.png"), dir.path().join("rgb/0000.png")).unwrap();
    fs::copy(dir.path().join("depth/50000000.exr"), dir.path().join("depth/0000.exr")).unwrap();
    assert_message(&open_err(dir.path()), &dir.path().join("rgb/0000.png"), &["(frame 0) lies far from"]);
}

#[test]
fn extra_image_frame_is_named() {
    let dir = temp();
    write_tiny_clip(dir.path(), 3);
    fs::copy(dir.path().join("rgb/0000.png"), dir.path().join("rgb/0003.png")).unwrap();
    // The message names the depth file the extra image would need.
    assert_message(&open_err(dir.path()), &dir.path().join("depth/0003.exr"), &["missing depth"]);
}

#[test]
fn extra_frame_without_pose_is_refused() {
    let dir = temp();
    write_tiny_clip(dir.path(), 3);
    fs::copy(dir.path().join("rgb/0000.png"), dir.path().join("rgb/0003.png")).unwrap();
    fs::copy(dir.path().join("depth/0000.exr"), dir.path().join("depth/0003.exr")).unwrap();
    assert_message(&open_err(dir.path()), &dir.path().join(POSES_FILE), &["3 poses", "4 frames"]);
}

#[test]
fn unrelated_files_in_frame_folders_are_ignored() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    fs::write(dir.path().join("rgb/notes.txt"), "hi").unwrap();
    fs::write(dir.path().join("rgb/.DS_Store"), "x").unwrap();
    assert_eq!(Clip::open(dir.path()).unwrap().len(), 2);
}

#[test]
fn folder_without_frames_is_refused() {
    let dir = temp();
    assert_message(&open_err(dir.path()), dir.path(), &["neither rgb/"]);
    fs::create_dir_all(dir.path().join("rgb")).unwrap();
    fs::create_dir_all(dir.path().join("depth")).unwrap();
    assert_message(&open_err(dir.path()), dir.path(), &["no frame files"]);
    assert!(matches!(Clip::open(dir.path().join("nope")), Err(DataError::Io { .. })));
}

// ---------------------------------------------------------------------------------------------
// Sizes

#[test]
fn depth_of_another_size_is_refused_at_open() {
    let dir = temp();
    write_tiny_clip(dir.path(), 3);
    let path = dir.path().join("depth/0001.exr");
    write_depth_exr(&path, &DepthMap::filled(W, H + 1, [1.0])).unwrap();
    let err = open_err(dir.path());
    assert!(matches!(err, DataError::SizeMismatch { found: (W, 7), expected: (W, H), .. }), "{err}");
    assert_message(&err, &path, &["8x7", "8x6"]);
}

#[test]
fn image_of_another_size_is_refused_at_open() {
    let dir = temp();
    write_tiny_clip(dir.path(), 3);
    let path = dir.path().join("rgb/0002.png");
    write_rgb_png(&path, &RgbImage::zeros(W + 2, H)).unwrap();
    assert_message(&open_err(dir.path()), &path, &["10x6"]);
}

#[test]
fn file_replaced_after_open_is_reported_by_load() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let clip = Clip::open(dir.path()).unwrap();
    let path = dir.path().join("rgb/0001.png");
    write_rgb_png(&path, &RgbImage::zeros(3, 3)).unwrap();
    assert_message(&clip.load_image(1).unwrap_err(), &path, &["3x3"]);
    assert_message(&clip.load_image(5).unwrap_err(), dir.path(), &["out of range"]);
}

// ---------------------------------------------------------------------------------------------
// Poses and intrinsics

#[test]
fn non_finite_pose_is_refused_with_its_line() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n1,0,0,nan,0,1,0,0,0,0,1,0,0,0,0,1\n"));
    assert_message(&open_err(dir.path()), &path, &["line 2", "not a finite number"]);
    write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n1,0,0,inf,0,1,0,0,0,0,1,0,0,0,0,1\n"));
    assert_message(&open_err(dir.path()), &path, &["line 2", "`inf`"]);
}

#[test]
fn singular_pose_is_refused_with_its_line() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = write_poses_csv(dir.path(), &format!("1,0,0,0,0,0,0,0,0,0,1,0,0,0,0,1\n{IDENTITY_ROW}\n"));
    assert_message(&open_err(dir.path()), &path, &["line 1", "not invertible"]);
}

#[test]
fn malformed_pose_rows_are_refused_with_their_line() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n1,0,0,0,0,1,0,0,0,0,1,0,0,0,0\n"));
    assert_message(&open_err(dir.path()), &path, &["line 2", "expected 16 numbers, found 15"]);
    write_poses_csv(dir.path(), &format!("{IDENTITY_ROW},1\n{IDENTITY_ROW}\n"));
    assert_message(&open_err(dir.path()), &path, &["line 1", "found 17"]);
    write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n1,0,0,abc,0,1,0,0,0,0,1,0,0,0,0,1\n"));
    assert_message(&open_err(dir.path()), &path, &["line 2", "field 4", "`abc` is not a number"]);
}

#[test]
fn pose_csv_tolerates_spaces_blank_lines_and_crlf() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let spaced = IDENTITY_ROW.replace(',', ", ");
    write_poses_csv(dir.path(), &format!("{spaced}\r\n\r\n{}\r\n\n", IDENTITY_ROW.replace(',', " ")));
    let clip = Clip::open(dir.path()).unwrap();
    assert_eq!(clip.pose(1).0, DMat4::IDENTITY);
}

#[test]
fn missing_pose_file_is_named() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join(POSES_FILE);
    fs::remove_file(&path).unwrap();
    assert_message(&open_err(dir.path()), &path, &["cannot read"]);
}

#[test]
fn missing_intrinsics_with_a_size_other_than_1080p_is_refused() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join(INTRINSICS_FILE);
    fs::remove_file(&path).unwrap();
    assert_message(&open_err(dir.path()), &path, &["1920x1080", "8x6"]);
}

#[test]
fn malformed_intrinsics_are_refused() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join(INTRINSICS_FILE);
    for (text, fragment) in [
        ("0,0,4\n0,10,3\n0,0,1\n", "fx, fy > 0"),
        ("10,0,4\n0,10,3\n", "found 2 rows"),
        ("10,0,4\n0,10\n0,0,1\n", "expected 3 numbers, found 2"),
        ("10,0,4\n0,10,x\n0,0,1\n", "`x` is not a number"),
        ("10,0.5,4\n0,10,3\n0,0,1\n", "K must be"),
    ] {
        fs::write(&path, text).unwrap();
        assert_message(&open_err(dir.path()), &path, &[fragment]);
    }
}

// ---------------------------------------------------------------------------------------------
// Single files

#[test]
fn truncated_png_is_reported_with_its_path() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join("rgb/0001.png");
    let len = fs::metadata(&path).unwrap().len() as usize;
    truncate_file(&path, len / 2);
    // The header survives, so open accepts the clip; loading the pixels fails.
    let clip = Clip::open(dir.path()).unwrap();
    assert_message(&clip.load_image(1).unwrap_err(), &path, &["cannot decode"]);
    assert!(matches!(read_rgb(&path), Err(DataError::Image { .. })));
    truncate_file(&path, 20);
    assert_message(&open_err(dir.path()), &path, &[]);
}

#[test]
fn truncated_exr_is_reported_with_its_path() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join("depth/0000.exr");
    let len = fs::metadata(&path).unwrap().len() as usize;
    truncate_file(&path, len - 20);
    let err = Clip::open(dir.path()).and_then(|clip| clip.load_depth(0)).unwrap_err();
    assert_message(&err, &path, &["EXR"]);
    truncate_file(&path, 30);
    assert_message(&open_err(dir.path()), &path, &["EXR"]);
    assert_message(&read_depth_exr(&path).unwrap_err(), &path, &["EXR"]);
}

#[test]
fn exr_without_a_usable_channel_names_the_channels_found() {
    let dir = temp();
    let path = dir.path().join("rg.exr");
    write_exr_channels(&path, 4, 3, &[("R", 1.0), ("G", 2.0)]);
    let err = read_depth_exr(&path).unwrap_err();
    assert!(matches!(&err, DataError::NoDepthChannel { channels, .. } if channels == &["G", "R"]), "{err}");
    assert_message(&err, &path, &["found channels [G, R]"]);
    // `open` checks the channel from the header already.
    write_tiny_clip(dir.path(), 2);
    let depth = dir.path().join("depth/0001.exr");
    write_exr_channels(&depth, W, H, &[("R", 1.0), ("G", 2.0)]);
    assert!(matches!(open_err(dir.path()), DataError::NoDepthChannel { .. }));
}

#[test]
fn exr_channel_rule_prefers_z_then_depth_z_then_y_then_b() {
    let dir = temp();
    let path = dir.path().join("d.exr");
    let cases: [(&[(&str, f32)], f32); 5] = [
        (&[("R", 1.0), ("G", 2.0), ("B", 3.0), ("Z", 4.0)], 4.0),
        (&[("R", 1.0), ("G", 2.0), ("B", 3.0)], 3.0),
        (&[("B", 3.0), ("Y", 5.0), ("depth.Z", 6.0)], 6.0),
        (&[("B", 3.0), ("Y", 5.0)], 5.0),
        (&[("V", 7.0)], 7.0),
    ];
    for (channels, expected) in cases {
        write_exr_channels(&path, 5, 2, channels);
        let depth = read_depth_exr(&path).unwrap();
        assert_eq!((depth.width(), depth.height()), (5, 2));
        assert!(depth.as_flat().iter().all(|&z| z == expected), "{channels:?}");
    }
}

#[test]
fn pick_depth_channel_follows_the_channel_rule() {
    let names = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    assert_eq!(pick_depth_channel(&names(&["whatever"])), Some(0));
    assert_eq!(pick_depth_channel(&names(&["B", "G", "R", "Z"])), Some(3));
    assert_eq!(pick_depth_channel(&names(&["A", "B"])), Some(1));
    assert_eq!(pick_depth_channel(&names(&["G", "R"])), None);
    assert_eq!(pick_depth_channel(&[]), None);
}

#[test]
fn depth_exr_round_trip_is_bit_exact_with_channel_y() {
    let dir = temp();
    let path = dir.path().join("d.exr");
    let depth = tiny_frame(W, H, 3).depth;
    write_depth_exr(&path, &depth).unwrap();
    assert_eq!(bits(&read_depth_exr(&path).unwrap()), bits(&depth));
    let meta = ex::MetaData::read_from_file(&path, false).unwrap();
    let names: Vec<String> = meta.headers[0].channels.list.iter().map(|c| c.name.to_string()).collect();
    assert_eq!(names, ["Y"]);
    assert_eq!(meta.headers[0].channels.list[0].sample_type, ex::SampleType::F32);
}

#[test]
fn sixteen_bit_png_is_read() {
    let dir = temp();
    let path = dir.path().join("rgb16.png");
    let img = image::ImageBuffer::<image::Rgb<u16>, Vec<u16>>::from_fn(3, 2, |u, v| {
        image::Rgb([65535, 0, if u == 0 && v == 0 { 32768 } else { 257 }])
    });
    img.save(&path).unwrap();
    let read = read_rgb(&path).unwrap();
    assert_eq!((read.width(), read.height()), (3, 2));
    assert_eq!(read.get(0, 0), [1.0, 0.0, 32768.0 / 65535.0]);
    assert_eq!(read.get(2, 1), [1.0, 0.0, 257.0 / 65535.0]);

    let gray16 = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(2, 2, image::Luma([65535]));
    gray16.save(&path).unwrap();
    assert_eq!(read_rgb(&path).unwrap().get(1, 1), [1.0; 3]);
}

#[test]
fn gray_rgba_and_jpeg_are_read_as_rgb() {
    let dir = temp();
    let gray = dir.path().join("g.png");
    write_gray_png(&gray, 3, 2, &[0, 51, 102, 153, 204, 255]).unwrap();
    let read = read_rgb(&gray).unwrap();
    assert_eq!(read.get(1, 0), [0.2; 3]);
    assert_eq!(read.get(2, 1), [1.0; 3]);
    assert!(write_gray_png(&gray, 3, 3, &[0; 6]).is_err(), "wrong value count");

    let rgba = dir.path().join("a.png");
    image::RgbaImage::from_pixel(2, 2, image::Rgba([255, 0, 51, 7])).save(&rgba).unwrap();
    assert_eq!(read_rgb(&rgba).unwrap().get(0, 1), [1.0, 0.0, 0.2]);

    let jpeg = dir.path().join("c.jpg");
    image::RgbImage::from_pixel(16, 16, image::Rgb([200, 100, 50])).save(&jpeg).unwrap();
    let c = read_rgb(&jpeg).unwrap().get(5, 5);
    assert!((c[0] - 200.0 / 255.0).abs() < 0.02 && (c[2] - 50.0 / 255.0).abs() < 0.02, "{c:?}");
}

#[test]
fn missing_image_file_names_its_path() {
    let dir = temp();
    let path = dir.path().join("none.png");
    assert_message(&read_rgb(&path).unwrap_err(), &path, &["cannot open image"]);
    assert_message(&read_depth_exr(dir.path().join("none.exr")).unwrap_err(), &dir.path().join("none.exr"), &[]);
}

// ---------------------------------------------------------------------------------------------
// SceneNet RGB-D

const SCENENET_NUMBERS: [u64; 5] = [0, 25, 50, 75, 100];

/// A synthetic SceneNet trajectory (320x240): frame `n` has ray length 2000 mm + n at pixel (0, 0),
/// no reading at pixel (1, 0), 1500 mm elsewhere. Pose row k has translation x = k.
fn write_scenenet_trajectory(dir: &Path, with_poses: bool) {
    fs::create_dir_all(dir.join("photo")).unwrap();
    fs::create_dir_all(dir.join("depth")).unwrap();
    for n in SCENENET_NUMBERS {
        image::RgbImage::from_pixel(320, 240, image::Rgb([n as u8, 128, 255]))
            .save(dir.join(format!("photo/{n}.jpg")))
            .unwrap();
        let depth = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(320, 240, |u, v| match (u, v) {
            (0, 0) => image::Luma([2000 + n as u16]),
            (1, 0) => image::Luma([0]),
            _ => image::Luma([1500]),
        });
        depth.save(dir.join(format!("depth/{n}.png"))).unwrap();
    }
    if with_poses {
        let rows: Vec<String> =
            (0..SCENENET_NUMBERS.len()).map(|k| format!("1,0,0,{k},0,1,0,0,0,0,1,0,0,0,0,1")).collect();
        write_poses_csv(dir, &rows.join("\n"));
    }
}

#[test]
fn scenenet_trajectory_loads_in_numeric_order_with_planar_metres() {
    let dir = temp();
    write_scenenet_trajectory(dir.path(), true);
    let clip = Clip::open(dir.path()).unwrap();
    assert_eq!(clip.format(), ClipFormat::SceneNet);
    assert_eq!((clip.len(), clip.width(), clip.height()), (5, 320, 240));
    assert_eq!(clip.frame_numbers(), SCENENET_NUMBERS.to_vec(), "numeric, not lexicographic, order");
    assert_eq!(*clip.intrinsics(), Intrinsics::scenenet_default());

    let k = Intrinsics::scenenet_default();
    for (i, n) in SCENENET_NUMBERS.into_iter().enumerate() {
        assert_eq!(clip.pose(i).0.w_axis.x, i as f64, "row k = k-th frame");
        let depth = clip.load_depth(i).unwrap();
        // Corner pixel: ray 2.0 m (+ n mm) through (0, 0), |K^-1 [0, 0, 1]| computed by hand.
        let (x, y) = ((0.0 - 160.0) / k.fx, (0.0 - 120.0) / k.fy);
        let expected = (2.0 + n as f64 / 1000.0) / (x * x + y * y + 1.0).sqrt();
        assert!((depth.at(0, 0) as f64 - expected).abs() < 1e-6, "frame {n}: {} vs {expected}", depth.at(0, 0));
        assert!(depth.at(0, 0) < 2.0, "planar depth is shorter than the ray off-centre");
        assert!(depth.at(1, 0).is_nan(), "0 mm = no reading = invalid");
        // Principal point: planar depth == ray length.
        assert!((depth.at(160, 120) - 1.5).abs() < 1e-6);
        let image = clip.load_image(i).unwrap();
        assert!((image.get(10, 10)[2] - 1.0).abs() < 0.02);
    }
}

#[test]
fn scenenet_conversion_helper() {
    let k = Intrinsics::new(100.0, 100.0, 0.0, 0.0);
    assert!(ray_mm_to_planar(0, 5, 5, &k).is_nan());
    assert_eq!(ray_mm_to_planar(1000, 0, 0, &k), 1.0);
    let z = ray_mm_to_planar(5000, 300, 400, &k); // |K^-1 [u, v, 1]| = sqrt(9 + 16 + 1)
    assert!((z as f64 - 5.0 / 26f64.sqrt()).abs() < 1e-6);
}

#[test]
fn scenenet_trajectory_needs_poses_and_contiguous_numbers() {
    let dir = temp();
    write_scenenet_trajectory(dir.path(), false);
    assert_message(&open_err(dir.path()), &dir.path().join(POSES_FILE), &["cannot read"]);
    write_scenenet_trajectory(dir.path(), true);
    fs::remove_file(dir.path().join("photo/50.jpg")).unwrap();
    fs::remove_file(dir.path().join("depth/50.png")).unwrap();
    assert_message(&open_err(dir.path()), &dir.path().join("photo/50.jpg"), &["gaps"]);
    fs::copy(dir.path().join("photo/0.jpg"), dir.path().join("photo/50.jpg")).unwrap();
    fs::copy(dir.path().join("depth/0.png"), dir.path().join("depth/50.png")).unwrap();
    fs::copy(dir.path().join("photo/0.jpg"), dir.path().join("photo/30.jpg")).unwrap();
    fs::copy(dir.path().join("depth/0.png"), dir.path().join("depth/30.png")).unwrap();
    assert_message(&open_err(dir.path()), &dir.path().join("photo/30.jpg"), &["step by 25"]);
}

#[test]
fn scenenet_depth_must_be_16_bit() {
    let dir = temp();
    let path = dir.path().join("d.png");
    write_gray_png(&path, 2, 2, &[1, 2, 3, 4]).unwrap();
    let err = read_scenenet_depth(&path, &Intrinsics::scenenet_default()).unwrap_err();
    assert_message(&err, &path, &["16-bit"]);
}

// ---------------------------------------------------------------------------------------------
// Datasets

#[test]
fn find_clips_lists_nested_clips_sorted() {
    let root = temp();
    for rel in ["b/seq02/render", "a", "b/seq01/render"] {
        let dir = root.path().join(rel);
        fs::create_dir_all(&dir).unwrap();
        fs::write(dir.join(POSES_FILE), "").unwrap();
    }
    fs::create_dir_all(root.path().join("c/empty")).unwrap();
    let clips = find_clips(root.path()).unwrap();
    let expected: Vec<PathBuf> =
        ["a", "b/seq01/render", "b/seq02/render"].iter().map(|r| root.path().join(r)).collect();
    assert_eq!(clips, expected);
}

#[test]
fn find_clips_accepts_a_clip_as_root() {
    let dir = temp();
    write_tiny_clip(dir.path(), 1);
    assert_eq!(find_clips(dir.path()).unwrap(), vec![dir.path().to_path_buf()]);
    assert_eq!(find_clips(blender_clip(0).parent().unwrap()).unwrap().len(), 4);
}

#[test]
fn find_clips_refuses_missing_or_empty_roots() {
    let root = temp();
    fs::create_dir_all(root.path().join("x/y")).unwrap();
    let err = find_clips(root.path()).unwrap_err();
    assert!(matches!(err, DataError::NoClip { .. }));
    assert_message(&err, root.path(), &["no clip"]);
    let missing = root.path().join("missing");
    assert_message(&find_clips(&missing).unwrap_err(), &missing, &["cannot open"]);
}

// ---------------------------------------------------------------------------------------------
// Trust: depth, rigid poses, plausible intrinsics

/// Overwrites the depth of frame `n` of a tiny clip with `values` repeated over the frame.
fn overwrite_depth(dir: &Path, n: usize, values: &[f32]) -> PathBuf {
    let path = dir.join("depth").join(format!("{n:04}.exr"));
    let depth = DepthMap::from_fn(W, H, |u, v| [values[(v * W + u) % values.len()]]);
    write_depth_exr(&path, &depth).unwrap();
    path
}

#[test]
fn frame_without_usable_depth_is_refused_naming_the_file() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    for (values, what) in [
        (vec![f32::NAN], "NaN"),
        (vec![f32::INFINITY], "sky"),
        (vec![0.0], "missing"),
        (vec![-1.0], "negative"),
        (vec![1e-9], "tiny"),
        (vec![1e9], "huge"),
    ] {
        let path = overwrite_depth(dir.path(), 1, &values);
        let clip = Clip::open(dir.path()).unwrap();
        let err = clip.load_frame(1).expect_err(what);
        assert_message(&err, &path, &["no usable depth"]);
        assert_eq!(clip.depth_stats(1).unwrap().usable, 0, "{what}: counted without an error");
        assert!(clip.load_frame(0).is_ok());
    }
}

#[test]
fn depth_counts_are_exposed_per_frame() {
    let dir = temp();
    write_tiny_clip(dir.path(), 1);
    // 48 pixels: 12 each of usable, sky, missing, NaN.
    overwrite_depth(dir.path(), 0, &[2.0, f32::INFINITY, 0.0, f32::NAN]);
    let clip = Clip::open(dir.path()).unwrap();
    let (depth, stats) = clip.load_depth_with_stats(0).unwrap();
    assert_eq!(depth.len(), 48);
    assert_eq!(stats, DepthStats { pixels: 48, usable: 12, far: 12, missing: 12, implausible: 0, invalid: 12 });
    assert!(stats.is_suspicious(), "a quarter of the frame is NaN");
    // The tiny frames of `write_tiny_clip` hold one NaN and one +inf: counted, not suspicious.
    let dir = temp();
    write_tiny_clip(dir.path(), 1);
    let (_, stats) = Clip::open(dir.path()).unwrap().load_depth_with_stats(0).unwrap();
    assert_eq!((stats.usable, stats.far, stats.invalid), (46, 1, 1));
    assert!(!stats.is_suspicious());
}

fn pose_row(m: DMat4) -> String {
    WorldToCamera(m).to_row_major().iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(",")
}

#[test]
fn non_rigid_poses_are_refused_with_their_line() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let rigid = tiny_pose(3).0;
    let path = dir.path().join(POSES_FILE);
    for (bad, fragment) in [
        (DMat4::from_scale(DVec3::splat(1.5)) * rigid, "not orthonormal"),
        (DMat4::from_scale(DVec3::new(1.0, 1.0, 1.01)) * rigid, "not orthonormal"),
        (DMat4::from_scale(DVec3::new(1.0, -1.0, 1.0)) * rigid, "determinant -1"),
        (DMat4::from_translation(DVec3::new(1e300, 0.0, 0.0)) * rigid, "translation"),
        (DMat4::from_translation(DVec3::new(0.0, 2e5, 0.0)) * rigid, "implausible"),
    ] {
        write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n{}\n", pose_row(bad)));
        assert_message(&open_err(dir.path()), &path, &["line 2", fragment]);
    }
    let mut bottom = rigid;
    bottom.x_axis.w = 0.01;
    write_poses_csv(dir.path(), &format!("{}\n{IDENTITY_ROW}\n", pose_row(bottom)));
    assert_message(&open_err(dir.path()), &path, &["line 1", "bottom row"]);
    // Rounding to 7 significant digits (a float32 export) stays within the tolerance.
    let rounded: Vec<String> = rigid.transpose().to_cols_array().iter().map(|x| format!("{x:.6e}")).collect();
    write_poses_csv(dir.path(), &format!("{IDENTITY_ROW}\n{}\n", rounded.join(",")));
    Clip::open(dir.path()).unwrap();
    let err = write_clip(dir.path(), &[tiny_frame(W, H, 0)], &[WorldToCamera(rigid * 2.0)], Some(&tiny_intrinsics()))
        .unwrap_err();
    assert!(err.to_string().contains("not a rigid transform"), "{err}");
}

#[test]
fn implausible_intrinsics_are_refused_saying_why() {
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    let path = dir.path().join(INTRINSICS_FILE);
    for (text, fragment) in [
        ("0.3,0,0.5\n0,0.35,0.5\n0,0,1\n", "looks like normalised intrinsics"),
        ("0.2,0,4\n0,10,3\n0,0,1\n", "fx 0.2 is implausibly small"),
        ("1e300,0,4\n0,10,3\n0,0,1\n", "fx 1e300 is implausibly large"),
        ("10,0,4\n0,1000,3\n0,0,1\n", "fy 1e3 is implausibly large"),
        ("10,0,40\n0,10,3\n0,0,1\n", "cx 40 lies outside the 8x6 frame"),
        ("10,0,4\n0,10,-3\n0,0,1\n", "cy -3 lies outside"),
    ] {
        fs::write(&path, text).unwrap();
        assert_message(&open_err(dir.path()), &path, &[fragment]);
    }
    // A little outside the frame is fine (a cropped image).
    fs::write(&path, "10,0,8.5\n0,10,-0.5\n0,0,1\n").unwrap();
    Clip::open(dir.path()).unwrap();
}

#[test]
fn durable_and_atomic_writes_replace_the_whole_file_and_leave_no_temporary_behind() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.safetensors");
    for write in [write_atomically, write_durably] {
        write(&path, b"first version").unwrap();
        write(&path, b"second").unwrap();
        assert_eq!(fs::read(&path).unwrap(), b"second");
        let names: Vec<String> =
            fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        assert_eq!(names, ["model.safetensors"]);
        // A missing folder is an error that names the file it was writing.
        let err = write(&dir.path().join("missing/model.safetensors"), b"x").unwrap_err();
        assert!(err.to_string().contains("missing"), "{err}");
    }
}

#[test]
fn frames_too_small_or_too_large_are_refused_by_size_before_anything_else() {
    // A strip 320x3: refused for its size, not for the principal point its intrinsics put outside it.
    let dir = temp();
    let frames: Vec<Frame> = (0..2).map(|i| tiny_frame(320, 3, i)).collect();
    let poses: Vec<WorldToCamera> = (0..2).map(tiny_pose).collect();
    write_clip(dir.path(), &frames, &poses, Some(&Intrinsics::new(300.0, 300.0, 159.5, 1.0))).unwrap();
    // The intrinsics of the 320x240 frames the strip was cut from.
    std::fs::write(dir.path().join("CameraIntrinsics.csv"), "300,0,159.5\n0,300,119.5\n0,0,1\n").unwrap();
    let err = open_err(dir.path());
    assert_message(&err, &dir.path().join("rgb/0000.png"), &["320x3", "at least 4x4"]);
    assert!(!err.to_string().contains("principal point"), "{err}");

    // A PNG whose header claims 60000x60000 pixels: refused from the header, nothing decoded.
    let dir = temp();
    write_tiny_clip(dir.path(), 2);
    for i in 0..2 {
        let path = dir.path().join(format!("rgb/{i:04}.png"));
        std::fs::write(&path, png_header_claiming(60_000, 60_000)).unwrap();
    }
    let err = open_err(dir.path());
    assert_message(&err, &dir.path().join("rgb/0000.png"), &["60000x60000", "more than ivp reads"]);
}

/// A PNG whose header (IHDR, with a correct checksum) claims `w` x `h` RGB pixels, followed by
/// an empty image-data chunk and the end: what a reader sees before it allocates the pixels.
fn png_header_claiming(w: u32, h: u32) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| -> Vec<u8> {
        let body = [kind, data].concat();
        [&(data.len() as u32).to_be_bytes()[..], &body, &crc32(&body).to_be_bytes()].concat()
    };
    let ihdr = [&w.to_be_bytes()[..], &h.to_be_bytes(), &[8, 2, 0, 0, 0]].concat();
    [&b"\x89PNG\r\n\x1a\n"[..], &chunk(b"IHDR", &ihdr), &chunk(b"IDAT", &[]), &chunk(b"IEND", &[])].concat()
}

/// PNG's CRC-32 (ISO 3309), bit by bit.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}
