//! What the host operations share: the operations that burn's backend extension routes to
//! hand-written kernels on flex's buffers, with and without autodiff ([`linear_host`] and the
//! body volume's [`host_conv`]).
//!
//! [`linear_host`]: crate::kernels::linear_host
//! [`host_conv`]: crate::body_volume::host_conv

use burn::backend::tensor::FloatTensor;
use burn::backend::{Flex, TensorMetadata};
use burn::prelude::*;
use burn::tensor::DType;

/// flex's tensor primitive.
pub type FlexTensor = FloatTensor<Flex>;

/// Whether `device` is flex, with or without autodiff: where the host operations run.
pub fn runs_on_host(device: &Device) -> bool {
    use burn_dispatch::DispatchDevice;
    match device.as_dispatch() {
        DispatchDevice::Flex(_) => true,
        DispatchDevice::Autodiff(d) => matches!(d.clone().inner(), DispatchDevice::Flex(_)),
        _ => false,
    }
}

/// `t` as a contiguous f32 tensor (as it is when it already is one, else converted or copied).
pub fn contiguous_f32(t: FlexTensor) -> FlexTensor {
    let t = if t.dtype() == DType::F32 {
        t
    } else {
        FlexTensor::from_data(t.into_data().convert::<f32>())
    };
    if t.is_contiguous() {
        t
    } else {
        t.to_contiguous()
    }
}

/// The f32 values of a tensor from [`contiguous_f32`].
pub fn values(t: &FlexTensor) -> &[f32] {
    t.as_slice::<f32>()
        .expect("contiguous_f32 gives a contiguous f32 tensor")
}

/// The dimensions of a rank-`D` tensor.
pub fn dims<const D: usize>(t: &FlexTensor) -> [usize; D] {
    t.shape().dims::<D>()
}

/// A flex tensor that owns `values` (no copy: a `Vec<f32>` meets the runtime's alignment).
pub fn flex_tensor<const D: usize>(values: Vec<f32>, dims: [usize; D]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, dims))
}
