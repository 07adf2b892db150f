//! The per-frame stages of inference at 1920x1080 (`ivp bench frame` times them end to end): the
//! temporal prior, the background depth threshold, the new-region rule, the far blur, the classical infillers,
//! the tile plan of sparse inference, what scaled inference adds around the network (the prior on
//! shrunk frames; shrinking the tiles' inputs and growing their vectors), and one sparse pass of
//! the recipe's network (width 0.25, untrained weights) at factor 2.
//!
//! `cargo bench -p ivp-core --bench frame_stages`.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DMat4, DVec3};
use ivp_core::geometry::{FrameView, NearestKnown, PixelClass};
use ivp_core::inference::{plan_tiles, Coverage, NetworkFrame, NetworkPredictor, TileShape};
use ivp_core::infill::rules::distance_to_known;
use ivp_core::infill::{
    blur_far_pixels, classical_infiller, fill_new_regions, InfillContext, VectorPredictor, FAR_BLUR,
};
use ivp_core::nn::model::{IvpNet, ModelConfig, Variant};
use ivp_core::prior::{background_depth_threshold, scaled_target_prior, target_prior};
use ivp_core::{relative_pose, warp_forward, DepthMap, Image, Intrinsics, RgbImage, VectorField, WorldToCamera};

/// A wall with boxes in front of it, seen from a camera at `x` metres.
fn frame(w: usize, h: usize, x: f64) -> (RgbImage, DepthMap, WorldToCamera) {
    let image = Image::from_fn(w, h, |u, v| [u as f32 / w as f32, v as f32 / h as f32, ((u ^ v) & 255) as f32 / 255.0]);
    let depth = Image::from_fn(w, h, |u, v| [if (u / 160 + v / 120) % 3 == 0 { 1.5 } else { 6.0 + (u as f32) * 1e-3 }]);
    (image, depth, WorldToCamera(DMat4::from_translation(DVec3::new(-x, 0.0, 0.0))))
}

fn bench_stages(c: &mut Criterion) {
    let (w, h) = (1920, 1080);
    let k = Intrinsics::iisc_veed_default();
    // Frames n-2, n and t of a camera sliding 1 cm a frame: holes beside every box.
    let frames = [frame(w, h, 0.0), frame(w, h, 0.02), frame(w, h, 0.03)];
    let view = |i: usize| FrameView { image: &frames[i].0, depth: &frames[i].1, pose: &frames[i].2 };
    let warp = warp_forward(&frames[1].0, &frames[1].1, &k, &relative_pose(&frames[1].2, &frames[2].2));
    let known = warp.holes.known();
    let holes = warp.holes.disocclusions();
    let hole_pixels = known.iter().filter(|&&k| !k).count();
    println!("{hole_pixels} of {} pixels are not known ({:.1}%)", w * h, 100.0 * hole_pixels as f64 / (w * h) as f64);
    let ctx = InfillContext {
        intrinsics: &k,
        last: view(1),
        before_last: Some(view(0)),
        target_pose: &frames[2].2,
        warped: &warp,
        ground_truth: Some(&frames[2].0),
    };
    let mut group = c.benchmark_group("frame_stages_1920x1080");
    group.sample_size(20);
    group.bench_function("target_prior", |b| b.iter(|| target_prior(&view(0), &view(1), &frames[2].2, &k, &known)));
    group.bench_function("nearest_known", |b| b.iter(|| NearestKnown::new(w, h, &known)));
    group.bench_function("background_depth_threshold", |b| b.iter(|| background_depth_threshold(&known, &warp.depth)));
    group.bench_function("fill_new_regions", |b| {
        b.iter(|| {
            let mut image = warp.image.clone();
            fill_new_regions(&mut image, &warp.holes);
            image
        })
    });
    let disocclusions = warp.holes.indices_of(PixelClass::Disocclusion);
    let nearest = NearestKnown::new(w, h, &known);
    let distances: Vec<f32> = disocclusions.iter().map(|&i| distance_to_known(&nearest, (i % w, i / w))).collect();
    group.bench_function("far_blur", |b| {
        b.iter(|| {
            let mut image = warp.image.clone();
            blur_far_pixels(&mut image, &disocclusions, &distances, FAR_BLUR);
            image
        })
    });
    let scaled_prior = || scaled_target_prior(&view(0), &view(1), &frames[2].2, &k, &warp.holes, 2);
    group.bench_function("scaled_target_prior_x2", |b| b.iter(scaled_prior));
    let prior = scaled_prior();
    // One sparse pass at factor 2 without the network: the frame's blocks of holes, the tile
    // plan, every tile's windows and every core's vectors written back.
    group.bench_function("sparse_pass_x2_around_the_network", |b| {
        b.iter(|| {
            let frame = NetworkFrame::new(&prior, &warp.depth, &holes, 2);
            let whole = frame.whole();
            let mut vectors = VectorField::zeros(w, h);
            for tile in plan_tiles(whole.width, whole.height, frame.holes(), TileShape::DEFAULT) {
                let inputs = (frame.window(tile.input), frame.mask(tile.input));
                for core in &tile.cores {
                    frame.write_vectors(*core, |_, _| [1.0, 0.0], &mut vectors);
                }
                std::hint::black_box(inputs);
            }
            vectors
        })
    });
    group.bench_function("network_frame_x2_holes", |b| b.iter(|| NetworkFrame::new(&prior, &warp.depth, &holes, 2)));
    // The network itself: the encoder and depth head over the tiles, the decoder at the holes.
    let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.25), 0).unwrap();
    let net = net.detached();
    let network = NetworkPredictor::new(&net, Coverage::default(), 2);
    let mut vectors = VectorField::zeros(w, h);
    group.bench_function("network_sparse_pass_x2", |b| {
        b.iter(|| network.predict_into(&prior, &warp.depth, &holes, &mut vectors).unwrap())
    });
    group.bench_function("plan_tiles", |b| b.iter(|| plan_tiles(w, h, &holes, TileShape::DEFAULT)));
    for method in ["fill", "telea"] {
        let infiller = classical_infiller(method).unwrap();
        group.bench_function(method, |b| b.iter(|| infiller.infill(&ctx).unwrap()));
    }
    group.finish();
}

criterion_group!(benches, bench_stages);
criterion_main!(benches);
