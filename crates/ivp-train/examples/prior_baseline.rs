//! Experiment: the temporal prior spread into the holes, as the vectors of the iterative infilling.
use ivp_core::infill::{classical_infiller, InfillError};
use ivp_core::iterative::{IterativeInfiller, VectorPredictor};
use ivp_core::prior::mean_of_nonzero_vectors;
use ivp_core::{DepthMap, VectorField};
use ivp_train::eval::{evaluate, format_table, Method, DEFAULT_TARGETS};

struct PriorSpread(usize);

impl VectorPredictor for PriorSpread {
    fn predict(&self, prior: &VectorField, _depth: &DepthMap, holes: &[bool]) -> Result<VectorField, InfillError> {
        let spread = mean_of_nonzero_vectors(prior, self.0);
        let mut out = VectorField::zeros(prior.width(), prior.height());
        for (i, h) in holes.iter().enumerate() {
            if *h {
                out.pixels_mut()[i] = spread.pixels()[i];
            }
        }
        Ok(out)
    }
}

fn main() {
    let data = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or("../shared/data/blender-dev".into()));
    let mut methods = vec![Method::Internal(classical_infiller("fill").unwrap())];
    for r in [2, 5, 10] {
        methods.push(Method::Internal(Box::new(IterativeInfiller::new(format!("prior-r{r}"), PriorSpread(r), 3))));
    }
    let report = evaluate(&data, &DEFAULT_TARGETS, &methods, false).unwrap();
    print!("{}", format_table(&report));
}
