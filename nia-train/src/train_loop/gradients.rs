//! Whole-model gradient passes: the sum of the devices' gradients, the global L2 norm and the
//! scaling that clips it.

use burn::module::{ModuleVisitor, Param};
use burn::optim::{GradientsParams, MultiGradientsParams};
use burn::prelude::*;
use nia_model::NiaModel;

/// Every parameter's gradient summed over the devices of a [`MultiGradientsParams`], on
/// `device`.
pub(super) struct Merge<'a> {
    pub multi: &'a mut MultiGradientsParams,
    pub out: GradientsParams,
    pub device: &'a Device,
}

impl ModuleVisitor for Merge<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some((g, _)) = self.multi.remove::<D>(param.id) {
            self.out.register(param.id, g.to_device(self.device));
        }
    }
}

/// Sum of squares of every parameter gradient, as one tensor.
struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    total: Option<Tensor<1>>,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.get::<D>(param.id) {
            let s = g.square().sum();
            self.total = Some(match self.total.take() {
                Some(t) => t + s,
                None => s,
            });
        }
    }
}

/// The squared global L2 norm of the gradient, on the gradients' device, unread (NaN or
/// infinite when any entry is); `None` without gradients.
pub(super) fn squared_norm(model: &NiaModel, grads: &GradientsParams) -> Option<Tensor<1>> {
    let mut v = SquaredNorm { grads, total: None };
    model.visit(&mut v);
    v.total
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, g.mul_scalar(self.factor));
        }
    }
}

pub(super) fn scale_gradients(model: &NiaModel, grads: &mut GradientsParams, factor: f32) {
    model.visit(&mut Scale { grads, factor });
}
