//! Experiment: the temporal prior spread into the holes, as the vectors of the iterative infilling
//! (a network-free baseline for what the network adds to its prior).
use ivp_core::infill::{classical_infiller, infill_iteratively, InfillContext, InfillError, Infilled, Infiller};
use ivp_core::infill::{InfillRules, VectorPredictor, DEFAULT_ITERATIONS};
use ivp_core::prior::{mean_of_nonzero_vectors, ScaledPrior};
use ivp_core::{DepthMap, VectorField};
use ivp_train::eval::{evaluate, format_table, Method, DEFAULT_TARGETS};

/// Predicts, for every hole, the mean of the non-zero prior vectors within `radius`.
struct PriorSpread {
    name: String,
    radius: usize,
}

impl VectorPredictor for PriorSpread {
    fn predict(&self, prior: &VectorField, _depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        let spread = mean_of_nonzero_vectors(prior, self.radius);
        let mut out = VectorField::zeros(prior.width(), prior.height());
        for (i, h) in holes.iter().enumerate() {
            if *h {
                out.pixels_mut()[i] = spread.pixels()[i];
            }
        }
        Ok(out)
    }
}

impl Infiller for PriorSpread {
    fn name(&self) -> &str {
        &self.name
    }

    fn infill(&self, ctx: &InfillContext<'_>) -> Result<Infilled, InfillError> {
        let w = ctx.warped;
        let (width, height) = (w.image.width(), w.image.height());
        let prior = ctx.temporal_prior().map_or_else(|| VectorField::zeros(width, height), |p| p.prior);
        let prior = ScaledPrior::full_size(prior);
        let out =
            infill_iteratively(self, &w.image, &w.depth, &w.holes, &prior, DEFAULT_ITERATIONS, InfillRules::default())?;
        let stages = vec![("infill", out.predict_time + out.other_time)];
        Ok(Infilled { image: out.image, stages, vectors: Some(out.vectors) })
    }
}

fn main() {
    let data = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or("data/blender-dev".into()));
    let mut methods = vec![Method::Internal(classical_infiller("fill").unwrap())];
    for radius in [2, 5, 10] {
        methods.push(Method::Internal(Box::new(PriorSpread { name: format!("prior-r{radius}"), radius })));
    }
    let report = evaluate(&data, &DEFAULT_TARGETS, &methods, false).unwrap();
    print!("{}", format_table(&report));
}
