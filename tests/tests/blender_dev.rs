//! Acceptance checks on real Blender renders (data/blender-dev).

use ivp_core::infill::classical_infiller;
use ivp_data::{find_clips, Clip};
use ivp_tests::blender_dev;
use ivp_train::eval::{evaluate, Method, DEFAULT_TARGETS};

/// Warping frame n to n+1 explains the next frame: mean absolute error on known pixels <= 4.
#[test]
fn warping_to_the_next_frame_matches_it_on_known_pixels() {
    for dir in find_clips(blender_dev()).unwrap() {
        let clip = Clip::open(&dir).unwrap();
        for n in 0..clip.len() - 1 {
            let (src, dst) = (clip.load_frame(n).unwrap(), clip.load_frame(n + 1).unwrap());
            let t = ivp_core::relative_pose(clip.pose(n), clip.pose(n + 1));
            let warp = ivp_core::warp_forward(&src.image, &src.depth, clip.intrinsics(), &t);
            let known = warp.holes.known();
            let (mut sum, mut count) = (0.0f64, 0usize);
            for ((p, q), k) in warp.image.pixels().iter().zip(dst.image.pixels()).zip(&known) {
                if *k {
                    sum += p.iter().zip(q).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / 3.0;
                    count += 1;
                }
            }
            let mae = 255.0 * sum / count as f64;
            assert!(count > known.len() * 9 / 10, "{}: {n} -> {}: only {count} known pixels", dir.display(), n + 1);
            assert!(mae <= 4.0, "{}: {n} -> {}: mean absolute error {mae:.2} > 4", dir.display(), n + 1);
        }
    }
}

/// The scores of the classical methods agree with an independent implementation of the metrics of
/// ALGORITHMS.md §7 (data/README.md; `telea` is OpenCV's Telea inpainting, radius 5) within 2%, and
/// `fill` beats `warp` and `copy` on disocclusions.
#[test]
fn classical_methods_score_as_the_independent_implementation() {
    // method, MSE, D-MSE, SSIM, D-SSIM, TC from data/README.md.
    let reference = [
        ("copy", 169.6, 1956.0, 0.808, 0.414, 385.7),
        ("warp", 51.9, 7852.2, 0.952, 0.195, 2175.3),
        ("fill", 23.1, 581.8, 0.965, 0.742, 184.8),
        ("oracle", 22.7, 585.2, 0.965, 0.748, 156.5),
        ("telea", 23.0, 652.3, 0.965, 0.750, 169.8),
    ];
    check_against_reference(&blender_dev(), &reference, (12, 11), 9286);
}

/// The same for the eight clips of data/blender-dev-extra.
#[test]
fn classical_methods_score_as_the_independent_implementation_on_the_extra_clips() {
    let reference = [
        ("copy", 251.5, 2976.8, 0.794, 0.323, 583.9),
        ("warp", 85.5, 8807.8, 0.936, 0.178, 1859.3),
        ("fill", 36.4, 1021.9, 0.954, 0.679, 273.5),
        ("oracle", 35.0, 739.0, 0.954, 0.718, 199.7),
        ("telea", 36.5, 942.8, 0.954, 0.685, 244.8),
    ];
    let extra = blender_dev().parent().unwrap().join("blender-dev-extra");
    check_against_reference(&extra, &reference, (24, 24), 19379);
}

type Reference = (&'static str, f64, f64, f64, f64, f64);

fn check_against_reference(data: &std::path::Path, reference: &[Reference], frames: (usize, usize), tracks: usize) {
    let methods: Vec<Method> = reference.iter().map(|r| Method::Internal(classical_infiller(r.0).unwrap())).collect();
    let report = evaluate(data, &DEFAULT_TARGETS, &methods, false).unwrap();
    let close = |got: f64, want: f64| (got - want).abs() <= 0.02 * want.abs();
    for (m, &(name, mse, d_mse, ssim, d_ssim, tc)) in report.methods.iter().zip(reference) {
        assert_eq!(m.name, name);
        assert_eq!((m.frames, m.d_frames), frames, "{name}: frames counted");
        let got = [m.mse, m.d_mse.unwrap(), m.ssim, m.d_ssim.unwrap(), m.tc.unwrap()];
        for (g, w) in got.iter().zip([mse, d_mse, ssim, d_ssim, tc]) {
            assert!(close(*g, w), "{name}: {got:?} vs reference {:?}", [mse, d_mse, ssim, d_ssim, tc]);
        }
        let expected = tracks as f64;
        assert!((m.tc_tracks as f64 - expected).abs() <= 0.02 * expected, "{name}: {} TC tracks", m.tc_tracks);
    }
    let d_mse = |i: usize| report.methods[i].d_mse.unwrap();
    assert!(d_mse(2) < d_mse(1) && d_mse(2) < d_mse(0), "fill must beat warp and copy in D-MSE");
    assert!(report.methods[3].uses_ground_truth);
}
