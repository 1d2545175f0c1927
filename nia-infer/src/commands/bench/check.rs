//! `nia-infer bench --check-against`: the same forward (and, with the training step, one
//! training forward's gradients) on another backend with the same weights and inputs, and how
//! far the results differ.

use anyhow::Context;
use burn::prelude::*;
use nia_data::geometry::rays::RayBundle;
use nia_data::rng::Rng;
use nia_data::scene::SceneInput;
use nia_model::device::{Backend, DeviceSpec};
use nia_model::loss::render_loss;
use nia_model::renderer::RenderOutput;
use nia_model::{ModelConfig, NiaModel};
use serde::Serialize;

use super::Bench;

/// The forward's colours on two backends with the same weights and inputs.
#[derive(Serialize)]
pub(super) struct BackendCheck {
    against: String,
    /// Largest |a - b| over the colours and opacities (both in [0, 1]).
    max_abs_diff: f32,
    /// ||a - b|| / ||b|| over the colours and opacities.
    rel_l2: f32,
    /// With the training step: per parameter, the largest |difference| of the gradients of
    /// one training forward (the same weights, rays and jitter) over the largest |gradient| on
    /// the other backend. Empty with `--no-train`.
    gradients: Vec<(String, f32)>,
}

/// The forward's colours and opacities as one host vector, refused if any is not finite.
pub(super) fn forward_colours(out: RenderOutput) -> anyhow::Result<Vec<f32>> {
    let read = |t: Tensor<2>, what: &str| -> anyhow::Result<Vec<f32>> {
        t.try_into_data()
            .map_err(|e| anyhow::anyhow!("reading the forward's {what} from the device: {e:?}"))?
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))
    };
    let mut values = read(out.rgb, "colours")?;
    values.extend(read(out.acc.unsqueeze_dim(1), "opacities")?);
    anyhow::ensure!(
        values.iter().all(|x| x.is_finite()),
        "non-finite colours in the benchmark forward"
    );
    Ok(values)
}

/// The gradients of one training forward and backward (render loss against grey, the same
/// weights, rays and jitter) on `device` and on `other`: per parameter, the largest
/// |difference| over the largest |gradient| on `other`.
fn gradient_check(
    config: &ModelConfig,
    input: &SceneInput,
    rays: &RayBundle,
    samples: usize,
    device: &Device,
    other: &Device,
) -> anyhow::Result<Vec<(String, f32)>> {
    let ad = device.clone().autodiff();
    ad.seed(0);
    let model = config.init(&ad);
    let mut rng = Rng::new(5);
    let jitter: Vec<f32> = (0..rays.len() * samples).map(|_| rng.uniform()).collect();
    let gradients = |model: &NiaModel, d: &Device| -> anyhow::Result<Vec<(String, Vec<f32>)>> {
        let scene = model.encode(input, None, d, None)?;
        let out = model.render(&scene, rays, samples, Some(&jitter), None)?;
        let gt = Tensor::<2>::ones([rays.len(), 3], d).mul_scalar(0.5);
        let grads = render_loss(out.rgb, out.rgb0, gt)?.total.backward();
        let read = |name: &str, g: Option<Tensor<1>>| -> anyhow::Result<(String, Vec<f32>)> {
            let g = g.with_context(|| format!("{name} has no gradient"))?;
            let values = g
                .try_into_data()
                .map_err(|e| anyhow::anyhow!("reading the {name} gradient from the device: {e:?}"))?
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?;
            Ok((name.to_string(), values))
        };
        Ok(vec![
            read(
                "encoder.conv1",
                model
                    .encoder
                    .conv1
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 3)),
            )?,
            read(
                "body_volume.full[0]",
                model
                    .body_volume
                    .full
                    .first()
                    .and_then(|b| b.conv.weight.val().grad(&grads))
                    .map(|g| g.flatten(0, 2)),
            )?,
            read(
                "density",
                model.density.layers[0]
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 1)),
            )?,
            read(
                "blender.token_input",
                model
                    .blender
                    .token_input
                    .weight
                    .val()
                    .grad(&grads)
                    .map(|g| g.flatten(0, 1)),
            )?,
        ])
    };
    let other_ad = other.clone().autodiff();
    let ours = gradients(&model, &ad)?;
    let theirs = gradients(&model.clone().fork(&other_ad), &other_ad)?;
    Ok(ours
        .into_iter()
        .zip(theirs)
        .map(|((name, a), (_, b))| {
            let largest = b.iter().fold(0.0f32, |m, x| m.max(x.abs()));
            let diff = a
                .iter()
                .zip(&b)
                .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
            (name, diff / largest.max(f32::MIN_POSITIVE))
        })
        .collect())
}

impl Bench<'_> {
    /// `model`'s forward on `against` compared with `colours`, the forward's on this backend;
    /// with the training step, also the gradients of one training forward on both.
    pub(super) fn backend_check(
        &self,
        config: &ModelConfig,
        model: &NiaModel,
        device: &Device,
        against: Backend,
        colours: &[f32],
    ) -> anyhow::Result<BackendCheck> {
        let args = self.args;
        let other = DeviceSpec {
            backend: against,
            index: None,
        }
        .device()?;
        let reference = model.clone().to_device(&other);
        let scene = reference.encode(self.input, None, &other, None)?;
        let theirs =
            forward_colours(reference.render(&scene, self.rays, args.samples, None, None)?)?;
        let (mut max_abs_diff, mut diff2, mut ref2) = (0.0f32, 0.0f64, 0.0f64);
        for (a, b) in colours.iter().zip(&theirs) {
            max_abs_diff = max_abs_diff.max((a - b).abs());
            diff2 += f64::from(a - b).powi(2);
            ref2 += f64::from(*b).powi(2);
        }
        self.note(format!(
            "{} against {}: max |difference| {max_abs_diff:.2e}, relative L2 {:.2e}",
            args.backend.name(),
            against.name(),
            (diff2 / ref2.max(1e-30)).sqrt()
        ));
        let gradients = if args.no_train {
            Vec::new()
        } else {
            let gradients =
                gradient_check(config, self.input, self.rays, args.samples, device, &other)?;
            for (name, rel) in &gradients {
                self.note(format!(
                    "{name}: gradients {} against {} differ by {rel:.2e} of the largest",
                    args.backend.name(),
                    against.name()
                ));
            }
            gradients
        };
        Ok(BackendCheck {
            against: against.name().to_string(),
            max_abs_diff,
            rel_l2: (diff2 / ref2.max(1e-30)).sqrt() as f32,
            gradients,
        })
    }
}
