//! Adam whose whole state (moments and step count) can be saved and restored, so that a resumed
//! training run continues bit-identically (candle-nn's `AdamW` keeps its moments private).

use std::collections::HashMap;

use candle_core::backprop::GradStore;
use candle_core::{bail, Result, Tensor, Var};

/// Adam's hyper-parameters (PyTorch's defaults; the reference trains with a learning rate of 1e-4).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamConfig {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Gradients whose global norm (over every parameter) exceeds this are scaled down to it
    /// before the update; `None` (PyTorch's Adam) never scales.
    pub max_grad_norm: Option<f64>,
}

impl Default for AdamConfig {
    fn default() -> Self {
        Self { lr: 1e-4, beta1: 0.9, beta2: 0.999, eps: 1e-8, max_grad_norm: None }
    }
}

/// Adam over named parameters: `m = b1 m + (1 - b1) g`, `v = b2 v + (1 - b2) g^2`,
/// `p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps)`.
pub struct Adam {
    config: AdamConfig,
    params: Vec<(String, Var)>,
    first_moments: Vec<Tensor>,
    second_moments: Vec<Tensor>,
    steps: u64,
}

impl Adam {
    /// Parameters are kept in name order, so the state's layout does not depend on how they were given.
    pub fn new(params: impl IntoIterator<Item = (String, Var)>, config: AdamConfig) -> Result<Self> {
        let mut params: Vec<(String, Var)> = params.into_iter().collect();
        params.sort_by(|a, b| a.0.cmp(&b.0));
        let zeros = params.iter().map(|(_, p)| p.zeros_like()).collect::<Result<Vec<_>>>()?;
        Ok(Self { config, first_moments: zeros.clone(), second_moments: zeros, params, steps: 0 })
    }

    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The parameters, in name order.
    pub fn parameters(&self) -> &[(String, Var)] {
        &self.params
    }

    pub fn config(&self) -> &AdamConfig {
        &self.config
    }

    pub fn set_lr(&mut self, lr: f64) {
        self.config.lr = lr;
    }

    /// One update from the gradients of a backward pass; parameters without a gradient are left
    /// alone. Returns the gradients' global norm, before any scaling by `max_grad_norm`.
    pub fn step(&mut self, grads: &GradStore) -> Result<f64> {
        self.steps += 1;
        let AdamConfig { lr, beta1, beta2, eps, max_grad_norm } = self.config;
        let t = self.steps as i32;
        let (bias1, bias2) = (1.0 - beta1.powi(t), 1.0 - beta2.powi(t));
        let norm = self.gradient_norm(grads)?;
        let scale = match max_grad_norm {
            Some(max) if norm > max => Some(max / norm),
            _ => None,
        };
        for (i, (_, param)) in self.params.iter().enumerate() {
            let Some(g) = grads.get(param.as_tensor()) else { continue };
            let scaled;
            let g = match scale {
                Some(s) => {
                    scaled = (g * s)?;
                    &scaled
                }
                None => g,
            };
            let m = ((&self.first_moments[i] * beta1)? + (g * (1.0 - beta1))?)?;
            let v = ((&self.second_moments[i] * beta2)? + (g.sqr()? * (1.0 - beta2))?)?;
            let denominator = ((&v / bias2)?.sqrt()? + eps)?;
            let update = ((&m / bias1)? / denominator)?;
            param.set(&param.as_tensor().sub(&(update * lr)?)?)?;
            self.first_moments[i] = m;
            self.second_moments[i] = v;
        }
        Ok(norm)
    }

    /// The Euclidean norm of every parameter's gradient together (in f64).
    pub fn gradient_norm(&self, grads: &GradStore) -> Result<f64> {
        let mut sum = 0.0;
        for (_, param) in &self.params {
            if let Some(g) = grads.get(param.as_tensor()) {
                sum += g.to_dtype(candle_core::DType::F64)?.sqr()?.sum_all()?.to_scalar::<f64>()?;
            }
        }
        Ok(sum.sqrt())
    }

    /// The moments as named tensors (`adam.m.NAME`, `adam.v.NAME`) and the step count, for a checkpoint.
    pub fn state(&self) -> (HashMap<String, Tensor>, u64) {
        let mut tensors = HashMap::new();
        for (i, (name, _)) in self.params.iter().enumerate() {
            tensors.insert(format!("adam.m.{name}"), self.first_moments[i].clone());
            tensors.insert(format!("adam.v.{name}"), self.second_moments[i].clone());
        }
        (tensors, self.steps)
    }

    /// Restores what [`Adam::state`] gave; every parameter's moments must be there with its shape.
    pub fn load_state(&mut self, tensors: &HashMap<String, Tensor>, steps: u64) -> Result<()> {
        for (i, (name, param)) in self.params.iter().enumerate() {
            for (kind, slot) in [("m", &mut self.first_moments[i]), ("v", &mut self.second_moments[i])] {
                let key = format!("adam.{kind}.{name}");
                let Some(t) = tensors.get(&key) else { bail!("optimizer state has no `{key}`") };
                if t.dims() != param.dims() {
                    bail!("optimizer state `{key}` has shape {:?}, the parameter {:?}", t.dims(), param.dims());
                }
                *slot = t.clone();
            }
        }
        self.steps = steps;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn var(values: &[f32]) -> Var {
        Var::from_tensor(&Tensor::new(values, &Device::Cpu).unwrap()).unwrap()
    }

    fn loss_grads(p: &Var) -> GradStore {
        // Loss sum((p - 3)^2): gradient 2 (p - 3).
        (p.as_tensor() - 3.0).unwrap().sqr().unwrap().sum_all().unwrap().backward().unwrap()
    }

    #[test]
    fn first_step_moves_each_parameter_by_the_learning_rate() {
        let p = var(&[0.0, 5.0, 3.0]);
        let mut adam = Adam::new([("p".to_string(), p.clone())], AdamConfig { lr: 0.1, ..Default::default() }).unwrap();
        adam.step(&loss_grads(&p)).unwrap();
        let got: Vec<f32> = p.as_tensor().to_vec1().unwrap();
        // Bias-corrected m / sqrt(v) = sign(g) on the first step (0 where g = 0).
        assert!((got[0] - 0.1).abs() < 1e-6 && (got[1] - 4.9).abs() < 1e-6 && got[2] == 3.0, "{got:?}");
    }

    #[test]
    fn gradients_above_the_largest_norm_are_scaled_down_to_it() {
        let max = 1.0;
        let start = [0.0, 5.0, 3.0, -1.0];
        let adam = |p: &Var, max_grad_norm| {
            let config = AdamConfig { lr: 0.5, max_grad_norm, ..Default::default() };
            Adam::new([("p".to_string(), p.clone())], config).unwrap()
        };
        let (clipped, by_hand, unclipped) = (var(&start), var(&start), var(&start));
        let (mut a, mut b, mut c) = (adam(&clipped, Some(max)), adam(&by_hand, None), adam(&unclipped, None));
        for _ in 0..4 {
            // By hand: the loss scaled so that its gradient has norm `max` when it had more.
            let grads = loss_grads(&by_hand);
            let norm = b.gradient_norm(&grads).unwrap();
            let want: f64 =
                by_hand.as_tensor().to_vec1::<f32>().unwrap().iter().map(|x| (2.0 * (*x as f64 - 3.0)).powi(2)).sum();
            assert!((norm - want.sqrt()).abs() < 1e-6 * want.sqrt(), "{norm} vs {}", want.sqrt());
            let grads = match norm > max {
                true => ((by_hand.as_tensor() - 3.0).unwrap().sqr().unwrap().sum_all().unwrap() * (max / norm))
                    .unwrap()
                    .backward()
                    .unwrap(),
                false => grads,
            };
            b.step(&grads).unwrap();
            assert_eq!(a.step(&loss_grads(&clipped)).unwrap(), norm, "the norm before scaling");
            c.step(&loss_grads(&unclipped)).unwrap();
        }
        let values = |p: &Var| p.as_tensor().to_vec1::<f32>().unwrap();
        let (got, want) = (values(&clipped), values(&by_hand));
        assert!(got.iter().zip(&want).all(|(x, y)| (x - y).abs() < 1e-6), "{got:?} vs {want:?}");
        let free = values(&unclipped);
        assert!(got.iter().zip(&free).any(|(x, y)| (x - y).abs() > 1e-3), "clipping changed nothing: {got:?}");
    }

    #[test]
    fn saved_state_resumes_bit_identically() {
        let run = |split: Option<usize>| {
            let p = var(&[0.5, -2.0, 7.0, 1.25]);
            let mut adam =
                Adam::new([("p".to_string(), p.clone())], AdamConfig { lr: 0.05, ..Default::default() }).unwrap();
            for step in 0..10 {
                if split == Some(step) {
                    let (state, steps) = adam.state();
                    let copy = var(&p.as_tensor().to_vec1::<f32>().unwrap());
                    adam = Adam::new([("p".to_string(), copy.clone())], *adam.config()).unwrap();
                    adam.load_state(&state, steps).unwrap();
                    return (copy, adam, step);
                }
                adam.step(&loss_grads(&p)).unwrap();
            }
            (p, adam, 10)
        };
        let (p_full, _, _) = run(None);
        let (p_resumed, mut adam, from) = run(Some(4));
        for _ in from..10 {
            adam.step(&loss_grads(&p_resumed)).unwrap();
        }
        let (a, b): (Vec<f32>, Vec<f32>) =
            (p_full.as_tensor().to_vec1().unwrap(), p_resumed.as_tensor().to_vec1().unwrap());
        assert_eq!(a, b);
        assert_eq!(adam.steps(), 10);
    }

    #[test]
    fn load_state_names_missing_or_misshapen_moments() {
        let p = var(&[1.0, 2.0]);
        let mut adam = Adam::new([("w".to_string(), p)], AdamConfig::default()).unwrap();
        let err = adam.load_state(&HashMap::new(), 3).unwrap_err().to_string();
        assert!(err.contains("adam.m.w"), "{err}");
        let wrong = Tensor::zeros(3, candle_core::DType::F32, &Device::Cpu).unwrap();
        let state = HashMap::from([("adam.m.w".to_string(), wrong.clone()), ("adam.v.w".to_string(), wrong)]);
        let err = adam.load_state(&state, 3).unwrap_err().to_string();
        assert!(err.contains("shape"), "{err}");
    }

    #[test]
    fn zero_gradient_leaves_a_parameter_finite() {
        let p = var(&[3.0]);
        let mut adam = Adam::new([("p".to_string(), p.clone())], AdamConfig::default()).unwrap();
        for _ in 0..3 {
            adam.step(&loss_grads(&p)).unwrap();
        }
        assert_eq!(p.as_tensor().to_vec1::<f32>().unwrap(), vec![3.0]);
    }
}
