//! Tests of the sample pipeline on small generated box scenes (96x72 frames, 32x32 crops), and
//! one on the Blender clips of data/blender-dev.

use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::Arc;
use std::time::Duration;

use glam::{DMat4, DVec3};
use ivp_core::prior::target_prior;
use ivp_core::{relative_pose, warp_forward, Image, Intrinsics, WorldToCamera};

use super::generator::validation_batches;
use super::rng::Rng;
use super::*;
use crate::{Clip, DataError, Frame};

const WIDTH: usize = 96;
const HEIGHT: usize = 72;
const FRAMES: usize = 12;
const CROP: usize = 32;

/// A textured wall at depth 10 with a box at depth 3 in front of it, seen by a camera moving
/// sideways (speed, box and textures drawn from `seed`): every frame pair uncovers wall beside
/// the box. `speed = 0` gives a still camera.
fn box_clip(seed: u64, width: usize, height: usize, speed_scale: f64) -> ClipFrames {
    let mut rng = Rng::from_words(&[seed]);
    let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * (rng.below(1 << 20) as f64 / (1 << 20) as f64);
    let speed = speed_scale * uniform(0.08, 0.16) * if uniform(0.0, 1.0) < 0.5 { -1.0 } else { 1.0 };
    let (box_x, box_y, half) = (uniform(-0.4, 0.4), uniform(-0.3, 0.3), uniform(0.5, 0.8));
    let phase = uniform(0.0, 6.0);
    let f = width as f64 * 0.8;
    let k = Intrinsics::new(f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let (wall_z, box_z) = (10.0, 3.0);
    let mut frames = Vec::new();
    let mut poses = Vec::new();
    for i in 0..FRAMES {
        let camera_x = (i as f64 - FRAMES as f64 / 2.0) * speed;
        poses.push(WorldToCamera(DMat4::from_translation(DVec3::new(-camera_x, 0.0, 0.0))));
        let pixel = |u: usize, v: usize| {
            let (dx, dy) = ((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy);
            let (x, y) = (camera_x + dx * box_z, dy * box_z);
            if (x - box_x).abs() < half && (y - box_y).abs() < half {
                let c = [0.9, 0.5 + 0.3 * (5.0 * x + phase).sin(), 0.3 + 0.2 * (7.0 * y).cos()];
                (c, box_z)
            } else {
                let (x, y) = (camera_x + dx * wall_z, dy * wall_z);
                let c = [0.5 + 0.4 * (3.0 * x + phase).sin(), 0.5 + 0.4 * (2.0 * y + x).sin(), 0.2];
                (c, wall_z)
            }
        };
        let image = Image::from_fn(width, height, |u, v| pixel(u, v).0.map(|c| c as f32));
        let depth = Image::from_fn(width, height, |u, v| [pixel(u, v).1 as f32]);
        frames.push(Frame { image, depth });
    }
    ClipFrames { frames, poses, intrinsics: k }
}

/// Endless box scenes, clip `id` drawn from the seed the sampler hands out.
fn box_source() -> Arc<dyn ClipSource> {
    Arc::new(FnSource::new("box", None, |_id, seed| Ok(box_clip(seed, WIDTH, HEIGHT, 1.0))))
}

fn small_config(seed: u64) -> SampleConfig {
    SampleConfig { seed, crop: CROP, batch_size: 3, pool_size: 2, refresh_every: 2 }
}

fn generator(seed: u64) -> SampleGenerator {
    SampleGenerator::new(box_source(), small_config(seed), Split::Train).unwrap()
}

/// Every value of every tensor, as bits, so that equal means bit-identical.
fn batch_bits(batch: &Batch) -> Vec<Vec<u32>> {
    let tensors =
        [&batch.prior, &batch.warped_depth, &batch.warped, &batch.mask, &batch.truth, &batch.last, &batch.last_warped];
    tensors
        .iter()
        .map(|t| t.flatten_all().unwrap().to_vec1::<f32>().unwrap().iter().map(|x| x.to_bits()).collect())
        .collect()
}

fn stream_bits(seed: u64, first: u64, steps: u64, workers: usize) -> Vec<Vec<Vec<u32>>> {
    let generator = Arc::new(generator(seed));
    let options = StreamOptions { workers, prefetch: 3 };
    let mut stream = SampleStream::start(generator, first, options).unwrap();
    (first..first + steps)
        .map(|step| {
            let batch = stream.next_batch().unwrap();
            assert_eq!(batch.step, step);
            batch_bits(&batch)
        })
        .collect()
}

#[test]
fn crops_lie_inside_the_frame_and_are_centred_on_a_disocclusion() {
    let generator = generator(1);
    let mut shifted = 0;
    for step in 0..12 {
        for sample in generator.samples(step).unwrap() {
            let (window, centre) = (sample.origin.window, sample.origin.centre);
            assert_eq!(window.size, CROP);
            assert!(window.left + CROP <= WIDTH && window.top + CROP <= HEIGHT, "{window:?}");
            let (cu, cv) = window.to_crop(centre).expect("the centre lies in the crop");
            assert_eq!(sample.mask.at(cu, cv), 1.0, "the centre is a disocclusion pixel");
            if (cu, cv) == (CROP / 2, CROP / 2) {
                assert_eq!((window.left + CROP / 2, window.top + CROP / 2), centre);
            } else {
                shifted += 1;
                let at_edge =
                    window.left == 0 || window.top == 0 || window.left + CROP == WIDTH || window.top + CROP == HEIGHT;
                assert!(at_edge, "only a crop against the frame border may be off-centre: {window:?}");
            }
        }
    }
    assert!(shifted < 36, "every crop was shifted: centring is not exercised");
}

#[test]
fn a_sample_matches_the_warps_and_prior_computed_directly() {
    let generator = generator(2);
    for sample in generator.samples(3).unwrap() {
        let clip = box_clip(generator.clip_seed(sample.origin.clip), WIDTH, HEIGHT, 1.0);
        let TargetFrames { before_last, last, target } = sample.origin.frames;
        let k = clip.intrinsics;
        let warped = warp_forward(
            &clip.frames[last].image,
            &clip.frames[last].depth,
            &k,
            &relative_pose(&clip.poses[last], &clip.poses[target]),
        );
        let known_t = warped.holes.known();
        let prior = target_prior(&clip.view(before_last), &clip.view(last), &clip.poses[target], &k, &known_t).prior;
        let last_warped = warp_forward(
            &clip.frames[before_last].image,
            &clip.frames[before_last].depth,
            &k,
            &relative_pose(&clip.poses[before_last], &clip.poses[last]),
        );
        let window = sample.origin.window;
        assert_eq!(sample.prior, window.cut(&prior));
        assert_eq!(sample.warped, window.cut(&warped.image));
        assert_eq!(sample.warped_depth, window.cut(&warped.depth));
        assert_eq!(sample.truth, window.cut(&clip.frames[target].image));
        assert_eq!(sample.last, window.cut(&clip.frames[last].image));
        assert_eq!(sample.last_warped, window.cut(&last_warped.image));
        let disocclusions = window.cut_field(&warped.holes.disocclusions(), WIDTH);
        assert!(sample.mask.pixels().iter().zip(&disocclusions).all(|(&[m], &d)| m == if d { 1.0 } else { 0.0 }));
    }
}

#[test]
fn prior_is_zero_on_the_holes_of_the_target_and_finite_everywhere() {
    let generator = generator(3);
    let mut nonzero = 0;
    for step in 0..8 {
        for sample in generator.samples(step).unwrap() {
            for ((&[a, b], &[depth]), &[mask]) in
                sample.prior.pixels().iter().zip(sample.warped_depth.pixels()).zip(sample.mask.pixels())
            {
                assert!(a.is_finite() && b.is_finite());
                // Holes of t (disocclusions and new regions) are exactly where the warped depth is 0.
                if depth == 0.0 {
                    assert_eq!([a, b], [0.0, 0.0]);
                }
                if mask == 1.0 {
                    assert_eq!(depth, 0.0, "a disocclusion pixel is a hole");
                }
                nonzero += usize::from(a != 0.0 || b != 0.0);
            }
            let all = [&sample.warped, &sample.truth, &sample.last, &sample.last_warped];
            assert!(all.iter().all(|image| image.as_flat().iter().all(|x| x.is_finite())));
        }
    }
    assert!(nonzero > 100, "the prior is almost empty ({nonzero} non-zero vectors)");
}

#[test]
fn reversed_clips_give_valid_samples_of_both_directions() {
    let generator = generator(4);
    let samples: Vec<Sample> = (0..10).flat_map(|step| generator.samples(step).unwrap()).collect();
    for direction in Playback::BOTH {
        let of_direction: Vec<&Sample> = samples.iter().filter(|s| s.origin.direction == direction).collect();
        assert!(of_direction.len() >= 5, "{direction:?}: {} samples", of_direction.len());
        for sample in of_direction {
            let TargetFrames { before_last, last, target } = sample.origin.frames;
            match direction {
                Playback::Forward => assert_eq!((before_last + 2, last + 1), (last, target)),
                Playback::Reversed => assert_eq!((before_last, last), (last + 2, target + 1)),
            }
            assert!(sample.mask.pixels().iter().filter(|&&[m]| m == 1.0).count() >= 1);
        }
    }
}

#[test]
fn batches_have_the_documented_shapes_and_dtype() {
    let batch = generator(5).batch(0).unwrap();
    let b = 3;
    let expected = [
        (&batch.prior, 2),
        (&batch.warped_depth, 1),
        (&batch.warped, 3),
        (&batch.mask, 1),
        (&batch.truth, 3),
        (&batch.last, 3),
        (&batch.last_warped, 3),
    ];
    for (tensor, channels) in expected {
        assert_eq!(tensor.dims(), &[b, channels, CROP, CROP]);
        assert_eq!(tensor.dtype(), candle_core::DType::F32);
        assert!(tensor.device().is_cpu());
    }
    assert_eq!((batch.len(), batch.step), (b, 0));
    // Channel planes: sample 1, channel 2 of `truth` is the blue plane of its crop.
    let samples = generator(5).samples(0).unwrap();
    let plane = batch.truth.get(1).unwrap().get(2).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(plane, samples[1].truth.pixels().iter().map(|p| p[2]).collect::<Vec<_>>());
    let mask = batch.mask.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert!(mask.iter().all(|&m| m == 0.0 || m == 1.0) && mask.contains(&1.0));
}

#[test]
fn batches_depend_only_on_seed_and_step() {
    let reference = stream_bits(7, 0, 9, 1);
    assert_eq!(stream_bits(7, 0, 9, 2), reference, "two workers");
    assert_eq!(stream_bits(7, 0, 9, 0), reference, "no worker");
    assert_eq!(stream_bits(7, 5, 4, 2), reference[5..], "resumed at step 5");
    let direct: Vec<_> = (0..9).map(|s| batch_bits(&generator(7).batch(s).unwrap())).collect();
    assert_eq!(direct, reference, "random access");
    assert_ne!(stream_bits(8, 0, 9, 1), reference, "another seed");
    assert!(reference.windows(2).all(|w| w[0] != w[1]), "consecutive batches differ");
}

#[test]
fn the_pool_rolls_and_the_cache_keeps_only_what_pending_steps_need() {
    let generator = Arc::new(generator(9));
    assert_eq!(generator.pool(0), 0..2);
    assert_eq!(generator.pool(5), 2..4);
    let mut stream = SampleStream::start(generator.clone(), 0, StreamOptions { workers: 2, prefetch: 2 }).unwrap();
    let mut clips = std::collections::BTreeSet::new();
    for _ in 0..12 {
        let batch = stream.next_batch().unwrap();
        clips.extend(batch.origins.iter().map(|o| o.clip));
        for origin in &batch.origins {
            assert!(generator.pool(batch.step).contains(&origin.clip), "step {}: clip {}", batch.step, origin.clip);
        }
    }
    // Pools of steps 12..14 and one clip of lookahead: arrivals 6..9 at most.
    let cached = generator.cached_clip_ids();
    assert!(cached.iter().all(|id| (6..9).contains(id)), "cached {cached:?}");
    assert!(clips.len() >= 6, "clips used: {clips:?}");
}

#[test]
fn validation_is_fixed_and_disjoint_from_training() {
    let config = small_config(11);
    let validation = validation_batches(box_source(), config.clone(), 3).unwrap();
    let again = validation_batches(box_source(), config.clone(), 3).unwrap();
    assert_eq!(validation.iter().map(batch_bits).collect::<Vec<_>>(), again.iter().map(batch_bits).collect::<Vec<_>>());
    let train = SampleGenerator::new(box_source(), config.clone(), Split::Train).unwrap();
    let valid = SampleGenerator::new(box_source(), config, Split::Validation).unwrap();
    let train_seeds: std::collections::HashSet<u64> = (0..10_000).map(|id| train.clip_seed(id)).collect();
    assert!((0..10_000).all(|id| !train_seeds.contains(&valid.clip_seed(id))));
    for (step, batch) in validation.iter().enumerate() {
        assert_ne!(batch_bits(batch), batch_bits(&train.batch(step as u64).unwrap()));
    }
}

#[test]
fn a_crop_larger_than_the_frames_is_a_clear_error() {
    let config = SampleConfig { crop: 128, ..small_config(0) };
    let generator = SampleGenerator::new(box_source(), config, Split::Train).unwrap();
    let error = generator.batch(0).unwrap_err();
    assert!(matches!(error, DataError::Sampling { .. }));
    let message = error.to_string();
    assert!(message.contains("96x72") && message.contains("128x128"), "{message}");
    assert!(message.starts_with("box clip"), "the message names the clip: {message}");
    // The stream reports it too, rather than hanging.
    let mut stream = SampleStream::start(Arc::new(generator), 0, StreamOptions::default()).unwrap();
    assert!(stream.next_batch().is_err());
}

#[test]
fn clips_without_disocclusions_give_an_error_not_a_hang() {
    let still = Arc::new(FnSource::new("still", None, |_id, seed| Ok(box_clip(seed, WIDTH, HEIGHT, 0.0))));
    let generator = SampleGenerator::new(still, small_config(0), Split::Train).unwrap();
    let message = generator.sample(0, 0).unwrap_err().to_string();
    assert!(message.contains("no disocclusion"), "{message}");
    let short = Arc::new(FnSource::new("short", None, |_id, seed| {
        let mut clip = box_clip(seed, WIDTH, HEIGHT, 1.0);
        clip.frames.truncate(3);
        clip.poses.truncate(3);
        Ok(clip)
    }));
    let generator = SampleGenerator::new(short, small_config(0), Split::Train).unwrap();
    assert!(generator.sample(0, 0).unwrap_err().to_string().contains("at least 4 frames"));
}

#[test]
fn bad_configurations_are_refused() {
    for config in [
        SampleConfig { crop: 0, ..small_config(0) },
        SampleConfig { batch_size: 0, ..small_config(0) },
        SampleConfig { pool_size: 0, ..small_config(0) },
        SampleConfig { refresh_every: 0, ..small_config(0) },
    ] {
        assert!(SampleGenerator::new(box_source(), config, Split::Train).is_err());
    }
    let empty = Arc::new(FnSource::new("empty", Some(0), |_, _| unreachable!()));
    assert!(SampleGenerator::new(empty, small_config(0), Split::Train).is_err());
}

#[test]
fn dropping_a_stream_does_not_hang() {
    let (done, finished) = mpsc::channel();
    std::thread::spawn(move || {
        let stream =
            SampleStream::start(Arc::new(generator(12)), 0, StreamOptions { workers: 2, prefetch: 4 }).unwrap();
        drop(stream); // while the workers are busy
        let mut stream =
            SampleStream::start(Arc::new(generator(12)), 3, StreamOptions { workers: 2, prefetch: 4 }).unwrap();
        stream.next_batch().unwrap();
        std::thread::sleep(Duration::from_millis(50)); // workers idle, waiting for the consumer
        drop(stream);
        done.send(()).unwrap();
    });
    finished.recv_timeout(Duration::from_secs(60)).expect("dropping the stream hung");
}

#[test]
fn a_finite_source_visits_every_clip_once_per_pass() {
    let source = Arc::new(FnSource::new("five", Some(5), |_id, seed| Ok(box_clip(seed, WIDTH, HEIGHT, 1.0))));
    let generator = SampleGenerator::new(source, small_config(13), Split::Train).unwrap();
    for pass in 0..3 {
        let mut ids: Vec<u64> = (pass * 5..pass * 5 + 5).map(|a| generator.clip_id(a)).collect();
        ids.sort_unstable();
        assert_eq!(ids, vec![0, 1, 2, 3, 4]);
    }
    let first_two: Vec<Vec<u64>> = (0..2).map(|p| (p * 5..p * 5 + 5).map(|a| generator.clip_id(a)).collect()).collect();
    assert_ne!(first_two[0], first_two[1], "each pass has its own order");
    assert!(generator.batch(0).is_ok());
}

fn blender_dev() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/blender-dev"))
}

#[test]
fn dataset_source_samples_blender_clips_with_their_own_intrinsics() {
    let source = DatasetSource::open(blender_dev()).unwrap();
    assert_eq!(source.clips().len(), 4);
    let clips: Vec<Clip> = source.clips().to_vec();
    let config = SampleConfig { seed: 3, crop: 64, batch_size: 4, pool_size: 2, refresh_every: 1 };
    let generator = SampleGenerator::new(Arc::new(source), config, Split::Train).unwrap();
    for step in 0..2 {
        for sample in generator.samples(step).unwrap() {
            let clip = &clips[sample.origin.clip as usize];
            assert_eq!(sample.origin.clip_name, clip.path());
            assert_eq!(&sample.origin.intrinsics, clip.intrinsics());
            assert_ne!(sample.origin.intrinsics, Intrinsics::scenenet_default());
            let window = sample.origin.window;
            assert_eq!(sample.truth, window.cut(&clip.load_image(sample.origin.frames.target).unwrap()));
            let (cu, cv) = window.to_crop(sample.origin.centre).unwrap();
            assert_eq!(sample.mask.at(cu, cv), 1.0);
            assert!(sample.prior.as_flat().iter().all(|x| x.is_finite()));
        }
    }
}

/// Small generated scenes, so that the test stays fast; at 96x72 a head's motion at 30 fps
/// moves edges by less than a pixel, hence the faster camera.
fn small_synthetic() -> Arc<dyn ClipSource> {
    let params = crate::scene::SceneParams { width: WIDTH, height: HEIGHT, motion_scale: 4.0, ..Default::default() };
    Arc::new(SyntheticSource::new(params))
}

#[test]
fn synthetic_scenes_give_deterministic_samples() {
    let config = SampleConfig { seed: 21, crop: CROP, batch_size: 2, pool_size: 3, refresh_every: 1 };
    let run = |workers: usize, first: u64| {
        let generator = Arc::new(SampleGenerator::new(small_synthetic(), config.clone(), Split::Train).unwrap());
        let mut stream = SampleStream::start(generator, first, StreamOptions { workers, prefetch: 2 }).unwrap();
        (first..4).map(|_| batch_bits(&stream.next_batch().unwrap())).collect::<Vec<_>>()
    };
    let reference = run(1, 0);
    assert_eq!(run(2, 2), reference[2..]);
    let generator = SampleGenerator::new(small_synthetic(), config, Split::Train).unwrap();
    // Here the warps and renders run on the global pool (two threads), in the workers on one.
    assert_eq!(batch_bits(&generator.batch(1).unwrap()), reference[1], "random access on the calling thread");
    for sample in generator.samples(0).unwrap() {
        assert!(sample.origin.clip_name.to_string_lossy().starts_with("synthetic clip"));
        let (cu, cv) = sample.origin.window.to_crop(sample.origin.centre).unwrap();
        assert_eq!(sample.mask.at(cu, cv), 1.0);
    }
}

#[test]
fn clips_at_several_scales_are_drawn_per_clip_from_the_seed() {
    let params = crate::scene::SceneParams { width: 32, height: 24, frames: 2, ..Default::default() };
    let source = SyntheticSource::new(params).with_scales(&[1, 3]);
    let sizes: Vec<(usize, usize)> = (0..16u64)
        .map(|seed| {
            let p = source.params_for(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15));
            (p.width, p.height)
        })
        .collect();
    assert!(sizes.iter().all(|s| [(32, 24), (96, 72)].contains(s)), "{sizes:?}");
    assert!(sizes.contains(&(32, 24)) && sizes.contains(&(96, 72)), "both scales are drawn: {sizes:?}");
    // The clip of a seed is rendered at its scale, the same every time, and its name says so.
    let seed = (0..64u64).find(|&s| source.params_for(s).width == 96).unwrap();
    let clip = source.load(0, seed).unwrap();
    assert_eq!(clip.size(), (96, 72));
    assert_eq!(clip.frames, source.load(0, seed).unwrap().frames);
    assert!(source.origin(0, seed).to_string_lossy().contains("96x72"));
    // Without scales, the frames are the parameters' size.
    assert_eq!(SyntheticSource::new(source.params().clone()).params_for(seed).width, 32);
}

#[test]
fn motion_scales_are_drawn_per_clip_independently_of_frame_scales() {
    let params =
        crate::scene::SceneParams { width: 32, height: 24, frames: 3, motion_scale: 0.5, ..Default::default() };
    let source = SyntheticSource::new(params.clone()).with_scales(&[1, 3]).with_motion_scales(&[1.0, 4.0]);
    // Clip seeds are hashes (of the sampler's seed, split and id), uniform in all their bits.
    let seeds: Vec<u64> = (0..64u64).map(|i| i.wrapping_mul(0x9E37_79B9_7F4A_7C15)).collect();
    let drawn: Vec<(usize, f64)> = seeds
        .iter()
        .map(|&seed| {
            let p = source.params_for(seed);
            (p.width, p.motion_scale)
        })
        .collect();
    // The clip's motion multiplies the parameters' own; every pairing of the two draws occurs.
    for pair in [(32, 0.5), (32, 2.0), (96, 0.5), (96, 2.0)] {
        assert!(drawn.contains(&pair), "{pair:?} never drawn: {drawn:?}");
    }
    assert!(drawn.iter().all(|(_, m)| [0.5, 2.0].contains(m)), "{drawn:?}");
    // A seed's clip moves the camera by its motion scale: the same scene, a path four times as
    // long, so a clip drawn at 2.0 differs from the same seed at 0.5.
    let seed = *seeds
        .iter()
        .find(|&&s| source.params_for(s) == crate::scene::SceneParams { motion_scale: 2.0, ..params.clone() })
        .unwrap();
    let fast = source.load(0, seed).unwrap();
    let slow = SyntheticSource::new(params.clone()).load(0, seed).unwrap();
    let position = |pose: &WorldToCamera| pose.camera_to_world().w_axis.truncate();
    let travelled = |clip: &ClipFrames| {
        let first = position(&clip.poses[0]);
        clip.poses.iter().map(|pose| position(pose).distance(first)).fold(0.0, f64::max)
    };
    assert!(travelled(&fast) > 2.0 * travelled(&slow), "{} vs {}", travelled(&fast), travelled(&slow));
    // Without motion scales, every clip keeps the parameters' motion (the scenes of earlier versions).
    let plain = SyntheticSource::new(params.clone());
    assert!((0..16u64).all(|s| plain.params_for(s) == params));
}
