//! Sparse inference against dense on real clips, for every tile shape of a list: how many vectors
//! agree within 0.5 px, D-MSE and time per frame (the table "Choosing the tile shape" of
//! PERFORMANCE.md).
//!
//! `cargo run --release -p ivp-train --example tile_study -- MODEL DATA TARGETS [SCALE]`, e.g.
//! `... -- model.safetensors data/blender-dev 6,8,10` from the repository's root (PERFORMANCE.md
//! also ran it on a 1920x1080 Blender clip that is not in the repository, with targets 3,4,5).
//! SCALE is that of `ivp eval --scale` (default `auto`); tiles are planned on the shrunk frame.

use std::path::Path;
use std::time::Instant;

use ivp_core::geometry::FrameView;
use ivp_core::inference::{Coverage, ModelInfiller, Scale, TileShape};
use ivp_core::infill::InfillContext;
use ivp_core::metrics::score_frame;
use ivp_core::{relative_pose, warp_forward};

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

const SHAPES: [(usize, usize); 8] = [(16, 16), (32, 16), (64, 16), (16, 32), (32, 32), (64, 32), (16, 48), (32, 48)];
const AGREEMENT_PX: f32 = 0.5;

/// Sums over the frames of one coverage.
#[derive(Default)]
struct Tally {
    d_mse: f64,
    frames: usize,
    ms: f64,
    agreeing: usize,
    /// Within [`AGREEMENT_PX`] pixels of the shrunk frame the network saw.
    agreeing_shrunk: usize,
    holes: usize,
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(
        (3..=5).contains(&args.len()),
        "usage: tile_study MODEL DATA TARGETS [SCALE [SHAPES]] (e.g. 6,8,10 auto 16x32,32x32)"
    );
    let scale: Scale = args.get(3).map_or("auto", String::as_str).parse().map_err(anyhow::Error::msg)?;
    let (net, _) = ivp_train::checkpoint::load_model(Path::new(&args[0]))?;
    let targets: Vec<usize> = args[2].split(',').map(str::parse).collect::<Result<_, _>>()?;
    let mut coverages = vec![Coverage::Dense];
    let shapes: Vec<(usize, usize)> = match args.get(4) {
        Some(list) => list
            .split(',')
            .map(|shape| {
                let (core, margin) =
                    shape.split_once('x').ok_or_else(|| anyhow::anyhow!("shape `{shape}`: CORExMARGIN"))?;
                Ok((core.parse()?, margin.parse()?))
            })
            .collect::<anyhow::Result<_>>()?,
        None => SHAPES.to_vec(),
    };
    for (core, margin) in shapes {
        coverages.push(Coverage::Sparse(TileShape::new(core, margin).map_err(anyhow::Error::msg)?));
    }
    let mut tallies: Vec<Tally> = coverages.iter().map(|_| Tally::default()).collect();
    for dir in ivp_data::find_clips(Path::new(&args[1]))? {
        let clip = ivp_data::Clip::open(&dir)?;
        for &t in &targets {
            let frames = (t - 3..=t).map(|i| clip.load_frame(i)).collect::<Result<Vec<_>, _>>()?;
            let view =
                |j: usize| FrameView { image: &frames[j].image, depth: &frames[j].depth, pose: clip.pose(t - 3 + j) };
            let to_target = relative_pose(clip.pose(t - 1), clip.pose(t));
            let warp = warp_forward(&frames[2].image, &frames[2].depth, clip.intrinsics(), &to_target);
            let holes = warp.holes.disocclusions();
            if !holes.contains(&true) {
                continue;
            }
            let ctx = InfillContext {
                intrinsics: clip.intrinsics(),
                last: view(2),
                before_last: Some(view(0)),
                target_pose: clip.pose(t),
                warped: &warp,
                ground_truth: None,
            };
            let factor = scale.factor(warp.image.height());
            let mut dense_vectors = None;
            for (coverage, tally) in coverages.iter().zip(&mut tallies) {
                let model = ModelInfiller::new("ivp", net.clone(), 3).with_coverage(*coverage).with_scale(scale);
                model.predict(&ctx)?; // warm-up
                                      // The faster of two timed runs: the machine is shared.
                let mut fastest = f64::INFINITY;
                let mut prediction = None;
                for _ in 0..2 {
                    let started = Instant::now();
                    prediction = Some(model.predict(&ctx)?);
                    fastest = fastest.min(started.elapsed().as_secs_f64() * 1e3);
                }
                let prediction = prediction.expect("two runs");
                tally.ms += fastest;
                tally.d_mse +=
                    score_frame(&prediction.image.quantized_to_8bit(), &frames[3].image, &holes).d_mse.unwrap();
                tally.frames += 1;
                let vectors = prediction.vectors.expect("a vector variant");
                let dense = dense_vectors.get_or_insert_with(|| vectors.clone());
                for ((a, b), _) in dense.pixels().iter().zip(vectors.pixels()).zip(&holes).filter(|(_, &h)| h) {
                    tally.holes += 1;
                    let difference = (a[0] - b[0]).abs().max((a[1] - b[1]).abs());
                    tally.agreeing += usize::from(difference <= AGREEMENT_PX);
                    tally.agreeing_shrunk += usize::from(difference <= AGREEMENT_PX * factor as f32);
                }
            }
        }
    }
    println!(
        "| coverage | D-MSE | vectors within {AGREEMENT_PX} px of dense | within {AGREEMENT_PX} px of the shrunk frame | ms/frame |"
    );
    println!("|---|---|---|---|---|");
    for (coverage, t) in coverages.iter().zip(&tallies) {
        let name = match coverage {
            Coverage::Dense => "dense".to_string(),
            Coverage::Sparse(s) => format!("core {} margin {}", s.core, s.margin),
        };
        let share = |agreeing: usize| 100.0 * agreeing as f64 / t.holes.max(1) as f64;
        let n = t.frames.max(1) as f64;
        println!(
            "| {name} | {:.1} | {:.2}% | {:.2}% | {:.0} |",
            t.d_mse / n,
            share(t.agreeing),
            share(t.agreeing_shrunk),
            t.ms / n
        );
    }
    Ok(())
}
