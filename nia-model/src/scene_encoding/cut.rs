//! The chunked backward (`train.ray_chunk`, `nia-infer bench --ray-chunk`): a scene's rays
//! through the field a chunk at a time, each chunk's graph freed by its own backward pass, so
//! the step holds the per-scene graph (encoder, body volume) and one chunk's, not every ray's.
//!
//! The per-scene encoding is cut from the graph that made it: the tensors the renderer reads
//! with gradients (the pixel-feature rows and the body volume's site features) become leaves
//! ([`SceneEncoding::cut`]). Every chunk's backward gives the model's render-side gradients and
//! the gradient at those leaves; the leaves' gradients are summed over the chunks, and one last
//! backward of `sum_k <root_k, g_k>` (the roots are the tensors before the cut) carries them
//! into the encoder and the body volume. By the chain rule this is the gradient of the summed
//! chunk losses, the same as one backward over all rays up to float rounding (a test compares
//! them); no work is done twice. What a chunk cannot see is per chunk: the training loss's
//! colour gain (`colour_matched_target`) is fitted on the chunk's rays, and c0 shuffling draws
//! the borrowed c0 from the chunk's points.

use std::ops::Range;

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;
use burn::tensor::Gradients;
use nia_data::geometry::rays::RayBundle;

use crate::body_volume::ScaleVolume;
use crate::error::ModelError;
use crate::model::NiaModel;
use crate::renderer::quadrature::RenderOutput;
use crate::scene_encoding::SceneEncoding;

/// The tensors of a [`SceneEncoding`] before its cut: the roots the leaves' gradients flow
/// back into.
#[derive(Debug, Clone)]
pub struct CutRoots {
    /// `[N H W + 1, d]` the pixel-feature rows.
    pixel_rows: Tensor<2>,
    /// Per scale `[N, P_s, C_s]`, the body volume's site features (empty without a body).
    sites: Vec<Tensor<3>>,
}

/// The leaves' gradients summed over the chunks so far (inner backend, no graph).
#[derive(Debug, Default)]
pub struct CutGradients {
    pixel_rows: Option<Tensor<2>>,
    sites: Vec<Option<Tensor<3>>>,
}

/// `acc += g`, where an absent `acc` is zero and an absent `g` adds nothing.
fn add<const D: usize>(acc: &mut Option<Tensor<D>>, g: Option<Tensor<D>>) {
    if let Some(g) = g {
        *acc = Some(match acc.take() {
            Some(a) => a + g,
            None => g,
        });
    }
}

impl SceneEncoding {
    /// This encoding cut from the graph that computed it (see the module docs): the
    /// pixel-feature rows and the body volume's site features as leaves requiring gradients,
    /// and the roots they were cut from. On a device without autodiff it is a plain copy.
    pub fn cut(&self) -> (SceneEncoding, CutRoots) {
        let mut cut = self.clone();
        cut.pixel_rows = self.pixel_rows.detached_leaf();
        cut.host_volume = None;
        cut.host_network = None;
        let mut sites = Vec::new();
        if let Some((_, volume)) = cut.volume.as_mut() {
            for scale in &mut volume.scales {
                let features = scale.features().clone();
                sites.push(features.clone());
                // A new scale, whose reads lay their rows out from the leaf.
                *scale = ScaleVolume::new(features.detach().require_grad(), scale.geometry.clone());
            }
        }
        let roots = CutRoots {
            pixel_rows: self.pixel_rows.rows(),
            sites,
        };
        (cut, roots)
    }
}

impl CutRoots {
    /// Adds the gradients that `grads` (a chunk's backward) holds at the leaves of `cut`
    /// (the encoding [`SceneEncoding::cut`] returned with these roots) into `acc`.
    pub fn accumulate(&self, cut: &SceneEncoding, grads: &Gradients, acc: &mut CutGradients) {
        add(&mut acc.pixel_rows, cut.pixel_rows.rows().grad(grads));
        if let Some((_, volume)) = &cut.volume {
            acc.sites.resize_with(volume.scales.len(), || None);
            for (a, scale) in acc.sites.iter_mut().zip(&volume.scales) {
                add(a, scale.features().grad(grads));
            }
        }
    }

    /// `sum_k <root_k, g_k>` over the roots and their summed leaf gradients `acc`: its
    /// backward is the encoder's and body volume's share of the gradient. `None` when no leaf
    /// received a gradient.
    pub fn surrogate(&self, acc: CutGradients) -> Option<Tensor<1>> {
        let mut total: Option<Tensor<1>> = None;
        if let Some(g) = acc.pixel_rows {
            add(
                &mut total,
                Some((self.pixel_rows.clone() * constant_like(&self.pixel_rows, g)).sum()),
            );
        }
        for (root, g) in self.sites.iter().zip(acc.sites) {
            add(
                &mut total,
                g.map(|g| (root.clone() * constant_like(root, g)).sum()),
            );
        }
        total
    }
}

/// `g` (a gradient, read without autodiff) as a constant of `root`'s graph: an autodiff
/// tensor with `root`'s gradient-checkpointing strategy, as autodiff requires of the two
/// operands of one operation (`Device::gradient_checkpointing`, `train.gradient_checkpointing`).
fn constant_like<const D: usize>(root: &Tensor<D>, g: Tensor<D>) -> Tensor<D> {
    let g = Tensor::from_inner(g);
    match root.gradient_checkpointing_strategy() {
        Some(strategy) => g.with_gradient_checkpointing_strategy(strategy),
        None => g,
    }
}

/// Adds every parameter's gradient in `other` into `into`.
struct AddInto<'a> {
    into: &'a mut GradientsParams,
    other: GradientsParams,
}

impl ModuleVisitor for AddInto<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = self.other.remove::<D>(param.id) {
            let sum = match self.into.remove::<D>(param.id) {
                Some(a) => a + g,
                None => g,
            };
            self.into.register(param.id, sum);
        }
    }
}

/// `into += other`, parameter by parameter of `model`.
pub fn add_gradients(model: &NiaModel, into: &mut GradientsParams, other: GradientsParams) {
    model.visit(&mut AddInto { into, other });
}

/// The model's gradient of a scene's loss with the rays rendered `chunk` at a time on an
/// autodiff device (see the module docs). For each chunk, `loss_of` gets the chunk's render
/// and its ray range in `rays` and returns the chunk's share of the loss (a mean over the
/// scene's rays is the chunk's mean times its share of the rays); an error from it ends the
/// pass. `jitter` is `[R * samples]`, ray-major, as [`NiaModel::render`] takes it. With
/// `chunk >= R` (or 0) this is one render and one backward, without a cut.
pub fn chunked_gradients<E, F>(
    model: &NiaModel,
    scene: &SceneEncoding,
    rays: &RayBundle,
    samples: usize,
    jitter: Option<&[f32]>,
    chunk: usize,
    mut loss_of: F,
) -> Result<GradientsParams, E>
where
    E: From<ModelError>,
    F: FnMut(RenderOutput, Range<usize>) -> Result<Tensor<1>, E>,
{
    let r = rays.len();
    if chunk == 0 || chunk >= r {
        let out = model.render(scene, rays, samples, jitter, None)?;
        let loss = loss_of(out, 0..r)?;
        return Ok(GradientsParams::from_grads(loss.backward(), model));
    }
    if let Some(j) = jitter {
        if j.len() != r * samples {
            return Err(ModelError::Input(format!(
                "chunked backward: {} jitter values for {r} rays x {samples} samples",
                j.len()
            ))
            .into());
        }
    }
    let (cut, roots) = scene.cut();
    let mut leaves = CutGradients::default();
    let mut grads = GradientsParams::new();
    for start in (0..r).step_by(chunk) {
        let range = start..(start + chunk).min(r);
        let sub = rays.slice(range.clone());
        let sub_jitter = jitter.map(|j| &j[range.start * samples..range.end * samples]);
        let out = model.render(&cut, &sub, samples, sub_jitter, None)?;
        let loss = loss_of(out, range)?;
        let g = loss.backward();
        roots.accumulate(&cut, &g, &mut leaves);
        add_gradients(model, &mut grads, GradientsParams::from_grads(g, model));
    }
    if let Some(surrogate) = roots.surrogate(leaves) {
        let g = surrogate.backward();
        add_gradients(model, &mut grads, GradientsParams::from_grads(g, model));
    }
    Ok(grads)
}
