// TEMPORARY probe, to be deleted.
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;
use candle_core::{Device, Tensor, Var};
use std::time::Instant;
fn cpu() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap();
    let f: Vec<&str> = s.rsplit(')').next().unwrap().split_whitespace().collect();
    (f[11].parse::<f64>().unwrap() + f[12].parse::<f64>().unwrap()) / 100.0
}
fn main() { api() }
fn measure(mut f: impl FnMut()) -> (f64, f64) {
    f();
    let (c0, t0) = (cpu(), Instant::now());
    let mut runs = 0;
    while cpu() - c0 < 1.0 || runs < 2 { f(); runs += 1; }
    (t0.elapsed().as_secs_f64() / runs as f64, (cpu() - c0) / runs as f64 / 2.0)
}
fn api() {
    let layers: &[(&str, usize, usize, usize, usize, usize)] = &[
        ("e1", 3, 64, 7, 1, 256), ("e2", 64, 128, 5, 2, 256), ("e3", 128, 256, 3, 2, 128),
        ("e4", 256, 256, 3, 2, 64), ("e5", 256, 256, 3, 2, 32), ("d6", 512, 256, 3, 1, 32),
        ("d7", 512, 128, 3, 1, 64), ("d8", 256, 64, 3, 1, 128), ("d9", 128, 2, 3, 1, 256),
        ("c1", 1, 16, 7, 2, 256), ("c2", 16, 32, 7, 2, 128), ("c3", 32, 16, 7, 1, 128), ("c4", 16, 1, 7, 1, 256),
    ];
    let only: Vec<String> = std::env::args().skip(1).collect();
    let b = 4;
    let mut tot = [0.0; 4];
    let mut totfl = 0.0;
    for &(name, cin, cout, k, s, hw) in layers {
        if !only.is_empty() && !only.iter().any(|o| o == name) { continue; }
        let x = Var::from_tensor(&Tensor::randn(0f32, 1., (b, cin, hw, hw), &Device::Cpu).unwrap()).unwrap();
        let w = Var::from_tensor(&Tensor::randn(0f32, 0.05, (cout, cin, k, k), &Device::Cpu).unwrap()).unwrap();
        let bias = Var::from_tensor(&Tensor::randn(0f32, 1., cout, &Device::Cpu).unwrap()).unwrap();
        let ho = (hw + 2 * (k / 2) - k) / s + 1;
        let fl = 2.0 * (cout * cin * k * k * ho * ho * b) as f64 / 1e9;
        let (xd, wd, bd) = (x.as_detached_tensor(), w.as_detached_tensor(), bias.as_detached_tensor());
        let (fw, fc) = measure(|| { ivp_core::ops::conv2d(&xd, &wd, Some(&bd), s, k / 2).unwrap(); });
        let (bw, bc) = measure(|| { ivp_core::ops::conv2d(&x, &w, Some(&bias), s, k / 2).unwrap().sum_all().unwrap().backward().unwrap(); });
        for (t, v) in tot.iter_mut().zip([fw, fc, bw, bc]) { *t += v; }
        totfl += fl;
        println!("{name}: {fl:5.1} GFLOP  fwd {:6.1} ms wall {:4.0} GF/s, cpu {:4.0} GF/s | fwd+bwd {:7.1} ms wall {:4.0} GF/s, cpu {:4.0} GF/s",
            fw * 1e3, fl / fw, fl / fc, bw * 1e3, 3.0 * fl / bw, 3.0 * fl / bc);
    }
    println!("total: fwd wall {:.0} ms ({:.0} GF/s) cpu {:.0} GF/s | fwd+bwd wall {:.0} ms ({:.0} GF/s) cpu {:.0} GF/s",
        tot[0] * 1e3, totfl / tot[0], totfl / tot[1], tot[2] * 1e3, 3.0 * totfl / tot[2], 3.0 * totfl / tot[3]);
}
