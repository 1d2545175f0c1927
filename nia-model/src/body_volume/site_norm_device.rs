//! [`super::site_norm_op`]'s operation on the device backends (ndarray and, with the `wgpu`
//! feature, the cubecl ones) from the backend's own tensor primitives, for training on a GPU
//! (and on ndarray, where the tests compare it with the tensor form).
//!
//! The tensor form's backward runs every element-wise operation's and reduction's backward on
//! its own: about twenty kernel launches a layer on wgpu, two of them buffers of ones or zeros
//! for the means. Here the backward is the closed form of [`super::site_norm_op`]'s module
//! docs, per view n and channel c over the P sites, with `dy'` the output gradient where the
//! ReLU passed (0 where the output is 0 or less):
//! - `d beta_c = sum_{n,p} dy'`, `d gamma_c = sum_{n,p} dy' x_hat`;
//! - `dx = gamma inv_std (dy' - mean_p dy' - x_hat mean_p(dy' x_hat))`.
//!
//! Sums in f32 on the device, in the backend's reduction order (the host operation's are f64
//! in fixed blocks).
// ndarray: the reference CPU backend of the tests, deprecated in burn 0.22.
#![allow(deprecated)]

use burn::backend::tensor::FloatTensor;
#[cfg(feature = "wgpu")]
use burn::backend::Cube;
use burn::backend::{Backend, NdArray, TensorMetadata};

use super::site_norm_op::{Saved, SiteNormBackend, SiteNormInputs, SiteNormKernels};

/// The forward: `ReLU(gamma x_hat + beta)` and what the backward keeps.
///
/// # Shapes
/// - `x`: `[N, P, C]`; `gamma`, `beta`: `[C]`; `y`, `x_hat`: `[N, P, C]`; `inv_std`: `[N, C]`
pub fn forward<B: Backend>(inputs: SiteNormInputs<B>) -> Saved<FloatTensor<B>> {
    let SiteNormInputs {
        x,
        gamma,
        beta,
        epsilon,
    } = inputs;
    let [n, _, c] = x.shape().dims::<3>();
    let mean = B::float_mean_dim(x.clone(), 1); // [N, 1, C]
    let centred = B::float_sub(x, mean);
    let var = B::float_mean_dim(B::float_mul(centred.clone(), centred.clone()), 1);
    let inv_std = B::float_recip(B::float_sqrt(B::float_add_scalar(var, epsilon.into())));
    let x_hat = B::float_mul(centred, inv_std.clone());
    let affine = B::float_add(
        B::float_mul(
            x_hat.clone(),
            B::float_reshape(gamma.clone(), [1, 1, c].into()),
        ),
        B::float_reshape(beta, [1, 1, c].into()),
    );
    Saved {
        y: B::relu(affine),
        x_hat,
        inv_std: B::float_reshape(inv_std, [n, c].into()),
        gamma,
    }
}

/// The backward (module docs): `[dx, d gamma, d beta]` from the output's `grad` `[N, P, C]`.
pub fn backward<B: Backend>(
    grad: FloatTensor<B>,
    saved: Saved<FloatTensor<B>>,
) -> [FloatTensor<B>; 3] {
    let Saved {
        x_hat,
        inv_std,
        y,
        gamma,
    } = saved;
    let [n, p, c] = x_hat.shape().dims::<3>();
    let passed = B::relu_backward(y, grad); // dy'
    let s1 = B::float_sum_dim(passed.clone(), 1); // [N, 1, C]
    let s2 = B::float_sum_dim(B::float_mul(passed.clone(), x_hat.clone()), 1);
    let d_beta = B::float_reshape(B::float_sum_dim(s1.clone(), 0), [c].into());
    let d_gamma = B::float_reshape(B::float_sum_dim(s2.clone(), 0), [c].into());
    let per_site = 1.0 / p.max(1) as f64;
    let scale = B::float_mul(
        B::float_reshape(inv_std, [n, 1, c].into()),
        B::float_reshape(gamma, [1, 1, c].into()),
    );
    let centred = B::float_sub(
        B::float_sub(passed, B::float_mul_scalar(s1, per_site.into())),
        B::float_mul(x_hat, B::float_mul_scalar(s2, per_site.into())),
    );
    [B::float_mul(centred, scale), d_gamma, d_beta]
}

/// The operation on a device backend: [`forward`] and [`backward`].
macro_rules! on_device_backend {
    ($backend:ty) => {
        impl SiteNormKernels for $backend {
            fn site_norm_forward(inputs: SiteNormInputs<Self>) -> Saved<FloatTensor<Self>> {
                forward::<Self>(inputs)
            }

            fn site_norm_backward(
                grad: FloatTensor<Self>,
                saved: Saved<FloatTensor<Self>>,
            ) -> [FloatTensor<Self>; 3] {
                backward::<Self>(grad, saved)
            }
        }

        impl SiteNormBackend for $backend {
            fn site_norm_relu(inputs: SiteNormInputs<Self>) -> FloatTensor<Self> {
                forward::<Self>(inputs).y
            }
        }
    };
}

on_device_backend!(NdArray);
#[cfg(feature = "wgpu")]
on_device_backend!(Cube);
