//! Small helpers shared by the per-module tests (fields, renderer).
#![allow(dead_code)]

use burn::prelude::*;

/// The reference CPU backend (deprecated upstream in favour of flex; the project keeps it).
#[allow(deprecated)]
pub fn device() -> Device {
    Device::ndarray()
}

pub fn tensor<const D: usize>(values: Vec<f32>, shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::from_data(TensorData::new(values, shape), device)
}

pub fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

pub fn assert_close(got: &[f32], expected: &[f32], tol: f32, what: &str) {
    assert_eq!(got.len(), expected.len(), "{what}: length");
    for (i, (g, e)) in got.iter().zip(expected).enumerate() {
        assert!(
            (g - e).abs() <= tol * (1.0 + e.abs()),
            "{what}[{i}]: got {g}, expected {e} (tol {tol})"
        );
    }
}
