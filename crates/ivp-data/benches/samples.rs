//! Training samples per second from generated scenes, rendering included: batches of 4 crops of
//! 256x256 cut from 512x384 clips, with the default rolling pool (4 clips, a new one every 16
//! steps, so rendering and the per-target warps and prior are amortised over 64 samples a clip).
//!
//! `cargo bench -p ivp-data --bench samples`; samples/s is printed by criterion as throughput.
//! - `stream_1_worker`: what training sees, a background stream on one core.
//! - `generator_2_cores`: batches computed on the calling thread, warps on both cores.
//! - `render_clip`: one 12-frame 512x384 clip, for scale.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::sync::Arc;
use std::time::{Duration, Instant};

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use ivp_data::samples::{SampleConfig, SampleGenerator, SampleStream, Split, StreamOptions, SyntheticSource};
use ivp_data::scene::render_clip;

const BATCH: usize = 4;

fn config() -> SampleConfig {
    SampleConfig { seed: 1, crop: 256, batch_size: BATCH, pool_size: 4, refresh_every: 16 }
}

fn generator() -> Arc<SampleGenerator> {
    Arc::new(SampleGenerator::new(Arc::new(SyntheticSource::for_crops_of_256()), config(), Split::Train).unwrap())
}

fn bench_samples(c: &mut Criterion) {
    let mut group = c.benchmark_group("samples_synthetic_512x384_crop_256");
    group.sample_size(10).measurement_time(Duration::from_secs(120)).warm_up_time(Duration::from_secs(20));
    group.throughput(Throughput::Elements(BATCH as u64));

    // One stream for the whole benchmark: every measured batch comes after the previous ones, so
    // the measurement spans many clip arrivals (and their rendering).
    let mut stream = SampleStream::start(generator(), 0, StreamOptions { workers: 1, prefetch: 4 }).unwrap();
    group.bench_function("stream_1_worker", |b| {
        b.iter_custom(|batches| {
            let start = Instant::now();
            for _ in 0..batches {
                stream.next_batch().unwrap();
            }
            start.elapsed()
        })
    });
    drop(stream);

    let generator = generator();
    let mut step = 0;
    group.bench_function("generator_2_cores", |b| {
        b.iter_custom(|batches| {
            let start = Instant::now();
            for _ in 0..batches {
                generator.batch(step).unwrap();
                step += 1;
                generator.keep_only(generator.arrivals_for(step..step + 1, 0));
            }
            start.elapsed()
        })
    });
    group.finish();

    let params = SyntheticSource::for_crops_of_256().params().clone();
    let mut group = c.benchmark_group("render_clip_512x384");
    group.sample_size(10);
    let mut seed = 0;
    group.bench_function("12_frames", |b| {
        b.iter(|| {
            seed += 1;
            render_clip(seed, &params)
        })
    });
    group.finish();
}

criterion_group!(benches, bench_samples);
criterion_main!(benches);
