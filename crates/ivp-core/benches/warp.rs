//! Forward warping of one 1920x1080 frame (image + depth), the per-frame cost of every method.
//!
//! `cargo bench -p ivp-core --bench warp`; Mpixel/s is printed by criterion as throughput.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use glam::{DMat4, DVec3};
use ivp_core::{warp_forward, Image, Intrinsics};

fn scene(w: usize, h: usize) -> (ivp_core::RgbImage, ivp_core::DepthMap) {
    let image = Image::from_fn(w, h, |u, v| [u as f32 / w as f32, v as f32 / h as f32, ((u ^ v) & 255) as f32 / 255.0]);
    // A wall with boxes in front of it: depth edges everywhere, as in a real frame.
    let depth = Image::from_fn(w, h, |u, v| [if (u / 160 + v / 120) % 3 == 0 { 1.5 } else { 6.0 + (u as f32) * 1e-3 }]);
    (image, depth)
}

fn bench_warp(c: &mut Criterion) {
    let (w, h) = (1920, 1080);
    let (image, depth) = scene(w, h);
    let k = Intrinsics::iisc_veed_default();
    // One frame of head motion at 30 fps: 2 cm sideways, 0.3 degrees of yaw.
    let t = DMat4::from_rotation_y(0.3f64.to_radians()) * DMat4::from_translation(DVec3::new(-0.02, 0.003, 0.005));
    let mut group = c.benchmark_group("warp_forward");
    group.throughput(Throughput::Elements((w * h) as u64));
    group.sample_size(30);
    group.bench_function("1920x1080", |b| b.iter(|| warp_forward(&image, &depth, &k, &t)));
    // A 10 degree roll and a bigger step: each row of the source crosses many rows of the target,
    // so that the warp projects more of the frame twice, to reach two bands of target rows.
    let roll = DMat4::from_rotation_z(10f64.to_radians()) * DMat4::from_translation(DVec3::new(-0.05, 0.02, 0.01));
    group.bench_function("1920x1080 roll", |b| b.iter(|| warp_forward(&image, &depth, &k, &roll)));
    group.finish();
}

criterion_group!(benches, bench_warp);
criterion_main!(benches);
