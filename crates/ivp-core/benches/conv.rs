//! The convolutions of the IVP network (ALGORITHMS.md §6.1) at batch 4 on a 256x256 crop, through
//! `ivp_core::nn::ops::conv2d`: forward, and forward + backward (input, weight and bias gradients).
//!
//! `cargo bench -p ivp-core --bench conv [-- FILTER]`. Criterion's throughput is in floating-point
//! operations: its "Gelem/s" reads as GFLOP/s. A forward pass counts 2 Cout Cin k k Ho Wo B, and
//! forward and backward together 3 times that (each of the two gradients costs one forward).
//! `conv_candle_builtin` times candle's own `Tensor::conv2d` on one layer for comparison.

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

use std::time::Duration;

use candle_core::{Device, Tensor, Var};
use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use ivp_core::nn::ops::conv2d;

/// A layer: name, Cin, Cout, kernel, stride, input size (square).
type Layer = (&'static str, usize, usize, usize, usize, usize);

/// The network at width 1 on a 256x256 crop: encoder, decoder and depth head.
const LAYERS: [Layer; 13] = [
    ("e1_3to64_k7_256", 3, 64, 7, 1, 256),
    ("e2_64to128_k5s2_256", 64, 128, 5, 2, 256),
    ("e3_128to256_k3s2_128", 128, 256, 3, 2, 128),
    ("e4_256to256_k3s2_64", 256, 256, 3, 2, 64),
    ("e5_256to256_k3s2_32", 256, 256, 3, 2, 32),
    ("d6_512to256_k3_32", 512, 256, 3, 1, 32),
    ("d7_512to128_k3_64", 512, 128, 3, 1, 64),
    ("d8_256to64_k3_128", 256, 64, 3, 1, 128),
    ("d9_128to2_k3_256", 128, 2, 3, 1, 256),
    ("c1_1to16_k7s2_256", 1, 16, 7, 2, 256),
    ("c2_16to32_k7s2_128", 16, 32, 7, 2, 128),
    ("c3_32to16_k7_128", 32, 16, 7, 1, 128),
    ("c4_16to1_k7_256", 16, 1, 7, 1, 256),
];

const BATCH: usize = 4;

struct Case {
    x: Var,
    w: Var,
    b: Var,
    stride: usize,
    padding: usize,
    flops: u64,
}

fn case(&(_, cin, cout, k, stride, size): &Layer) -> Case {
    let dev = &Device::Cpu;
    let bound = 1.0 / ((cin * k * k) as f32).sqrt();
    let x = Var::from_tensor(&Tensor::rand(0f32, 1.0, (BATCH, cin, size, size), dev).unwrap()).unwrap();
    let w = Var::from_tensor(&Tensor::rand(-bound, bound, (cout, cin, k, k), dev).unwrap()).unwrap();
    let b = Var::from_tensor(&Tensor::zeros(cout, x.dtype(), dev).unwrap()).unwrap();
    let out = (size + 2 * (k / 2) - k) / stride + 1;
    let flops = (2 * cout * cin * k * k * out * out * BATCH) as u64;
    Case { x, w, b, stride, padding: k / 2, flops }
}

fn bench_forward(c: &mut Criterion) {
    let mut group = c.benchmark_group("conv_fwd");
    for layer in &LAYERS {
        let t = case(layer);
        group.throughput(Throughput::Elements(t.flops));
        // Constants, as in inference: no graph is recorded.
        let (x, w, b) = (t.x.as_detached_tensor(), t.w.as_detached_tensor(), t.b.as_detached_tensor());
        group.bench_function(layer.0, |bench| bench.iter(|| conv2d(&x, &w, Some(&b), t.stride, t.padding).unwrap()));
    }
    group.finish();
}

fn bench_forward_backward(c: &mut Criterion) {
    let mut group = c.benchmark_group("conv_fwd_bwd");
    for layer in &LAYERS {
        let t = case(layer);
        group.throughput(Throughput::Elements(3 * t.flops));
        // All three gradients, as in training (e1's input comes from the depth head).
        group.bench_function(layer.0, |bench| {
            bench.iter(|| {
                let y = conv2d(&t.x, &t.w, Some(&t.b), t.stride, t.padding).unwrap();
                y.sum_all().unwrap().backward().unwrap()
            })
        });
    }
    group.finish();
}

fn bench_candle_builtin(c: &mut Criterion) {
    let mut group = c.benchmark_group("conv_candle_builtin");
    let layer = &LAYERS[2];
    let t = case(layer);
    group.throughput(Throughput::Elements(t.flops));
    let (x, w) = (t.x.as_detached_tensor(), t.w.as_detached_tensor());
    group.bench_function(layer.0, |bench| bench.iter(|| x.conv2d(&w, t.padding, t.stride, 1, 1).unwrap()));
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(3));
    targets = bench_forward, bench_forward_backward, bench_candle_builtin
}
criterion_main!(benches);
