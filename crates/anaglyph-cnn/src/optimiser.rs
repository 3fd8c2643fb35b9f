//! AdamW (Loshchilov & Hutter, ICLR 2019) whose state can be saved and restored.
//!
//! candle's `AdamW` keeps its moment estimates private, so a run that stops could not
//! continue where it was: this one holds the same state in the open, keyed by variable
//! name, and computes each update with the same operations in the same order as candle's
//! (`same_updates_as_candles_adamw` checks the weights agree bit for bit), so the shipped
//! weights' recipes still reproduce.

use crate::Result;
use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};
use candle_nn::{ParamsAdamW, VarMap};

/// One variable with its first and second moment estimates.
#[derive(Debug)]
struct Moments {
    name: String,
    var: Var,
    first: Var,
    second: Var,
}

/// AdamW over the variables of a `VarMap`, in name order.
#[derive(Debug)]
pub struct AdamW {
    vars: Vec<Moments>,
    /// Updates taken so far (the bias corrections' exponent).
    step: usize,
    params: ParamsAdamW,
}

/// Prefixes of the moments' tensor names in a saved state.
const FIRST: &str = "adamw.first_moment/";
const SECOND: &str = "adamw.second_moment/";

impl AdamW {
    /// Zero moments for every floating-point variable of `varmap`.
    pub fn new(varmap: &VarMap, params: ParamsAdamW) -> Result<Self> {
        let data = varmap
            .data()
            .lock()
            .map_err(|_| crate::Error::Serialise("the variable map lock is poisoned".into()))?;
        let mut vars = data
            .iter()
            .filter(|(_, var)| var.dtype().is_float())
            .map(|(name, var)| {
                Ok(Moments {
                    name: name.clone(),
                    var: var.clone(),
                    first: Var::zeros(var.shape(), var.dtype(), var.device())?,
                    second: Var::zeros(var.shape(), var.dtype(), var.device())?,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        vars.sort_by(|a, b| a.name.cmp(&b.name));
        Ok(AdamW {
            vars,
            step: 0,
            params,
        })
    }

    /// Updates taken so far.
    pub fn steps_taken(&self) -> usize {
        self.step
    }

    /// The moments as named tensors (`adamw.first_moment/NAME`, `adamw.second_moment/NAME`).
    pub fn state(&self) -> Vec<(String, Tensor)> {
        self.vars
            .iter()
            .flat_map(|m| {
                [
                    (format!("{FIRST}{}", m.name), m.first.as_tensor().clone()),
                    (format!("{SECOND}{}", m.name), m.second.as_tensor().clone()),
                ]
            })
            .collect()
    }

    /// Restores the moments from `tensors` (as [`AdamW::state`] names them) and the update
    /// count; `context` names the source in errors.
    pub fn restore(
        &mut self,
        tensors: &std::collections::HashMap<String, Tensor>,
        steps_taken: usize,
        context: &str,
    ) -> Result<()> {
        for m in &self.vars {
            for (prefix, var) in [(FIRST, &m.first), (SECOND, &m.second)] {
                let key = format!("{prefix}{}", m.name);
                let saved = tensors.get(&key).ok_or_else(|| {
                    crate::Error::Checkpoint(format!("{context}: the optimiser state lacks {key}"))
                })?;
                if saved.dims() != var.dims() {
                    return Err(crate::Error::Checkpoint(format!(
                        "{context}: {key} has shape {:?} (expected {:?})",
                        saved.dims(),
                        var.dims()
                    )));
                }
                var.set(saved)?;
            }
        }
        self.step = steps_taken;
        Ok(())
    }

    pub fn set_learning_rate(&mut self, lr: f64) {
        self.params.lr = lr;
    }

    /// One update from the gradients of `loss`.
    pub fn backward_step(&mut self, loss: &Tensor) -> Result<()> {
        let grads = loss.backward()?;
        self.step_with(&grads)
    }

    fn step_with(&mut self, grads: &GradStore) -> Result<()> {
        self.step += 1;
        let p = &self.params;
        let (lr, beta1, beta2) = (p.lr, p.beta1, p.beta2);
        let scale_m = 1.0 / (1.0 - beta1.powi(self.step as i32));
        let scale_v = 1.0 / (1.0 - beta2.powi(self.step as i32));
        for m in &self.vars {
            let theta = &m.var;
            let Some(g) = grads.get(theta) else {
                continue;
            };
            let next_m = ((m.first.as_tensor() * beta1)? + (g * (1.0 - beta1))?)?;
            let next_v = ((m.second.as_tensor() * beta2)? + (g.sqr()? * (1.0 - beta2))?)?;
            let m_hat = (&next_m * scale_m)?;
            let v_hat = (&next_v * scale_v)?;
            let decayed = (theta.as_tensor() * (1.0 - lr * p.weight_decay))?;
            let adjusted = (m_hat / (v_hat.sqrt()? + p.eps)?)?;
            let next_theta = (decayed - (adjusted * lr)?)?;
            m.first.set(&next_m)?;
            m.second.set(&next_v)?;
            theta.set(&next_theta)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device};
    use candle_nn::{Linear, Module, Optimizer, VarBuilder};

    /// A tiny regression: the same loss through candle's AdamW and this one, step by step.
    fn losses(varmap: &VarMap, x: &Tensor, y: &Tensor) -> Tensor {
        let vb = VarBuilder::from_varmap(varmap, DType::F32, &Device::Cpu);
        let layer: Linear = candle_nn::linear(3, 2, vb.pp("l")).unwrap();
        (layer.forward(x).unwrap() - y)
            .unwrap()
            .sqr()
            .unwrap()
            .mean_all()
            .unwrap()
    }

    fn weights(varmap: &VarMap) -> Vec<Vec<f32>> {
        let data = varmap.data().lock().unwrap();
        let mut names: Vec<_> = data.keys().cloned().collect();
        names.sort();
        names
            .iter()
            .map(|n| {
                data[n]
                    .as_tensor()
                    .flatten_all()
                    .unwrap()
                    .to_vec1()
                    .unwrap()
            })
            .collect()
    }

    #[test]
    fn same_updates_as_candles_adamw() {
        let x = Tensor::new(&[[0.3f32, -1.2, 2.0], [1.5, 0.1, -0.7]], &Device::Cpu).unwrap();
        let y = Tensor::new(&[[1.0f32, -2.0], [0.5, 0.25]], &Device::Cpu).unwrap();
        let params = ParamsAdamW {
            lr: 3e-2,
            weight_decay: 1e-2,
            ..ParamsAdamW::default()
        };
        let (ours, mut theirs) = (VarMap::new(), VarMap::new());
        // Build the variables, then give both the same start.
        losses(&ours, &x, &y);
        losses(&theirs, &x, &y);
        for name in ["l.weight", "l.bias"] {
            let start = ours.data().lock().unwrap()[name].as_tensor().clone();
            theirs.set_one(name, &start).unwrap();
        }
        let mut a = AdamW::new(&ours, params.clone()).unwrap();
        let mut b = candle_nn::AdamW::new(theirs.all_vars(), params).unwrap();
        for step in 0..20 {
            let lr = 3e-2 * (1.0 - step as f64 / 40.0);
            a.set_learning_rate(lr);
            b.set_learning_rate(lr);
            a.backward_step(&losses(&ours, &x, &y)).unwrap();
            b.backward_step(&losses(&theirs, &x, &y)).unwrap();
        }
        assert_eq!(weights(&ours), weights(&theirs));
        assert_eq!(a.steps_taken(), 20);
    }
}
