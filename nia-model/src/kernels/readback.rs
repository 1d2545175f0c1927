//! Reading tensors back to host memory (sigma for early termination, the host copies of the
//! inference reads, rendered images).
//!
//! On flex a tensor already lives in host memory, and burn's `into_data` copies it up to three
//! times on the way to a `Vec<f32>` (a shared or narrowed buffer is copied out, the copy is
//! copied again to burn's allocation alignment, and that again into a `Vec<f32>`, whose
//! alignment differs). A contiguous f32 flex tensor is therefore read here straight from its
//! storage: [`HostValues`] borrows it without a copy, [`host_values`] copies it once.
//! Every other tensor (wgpu, ndarray, autodiff, strided views, other dtypes) goes through
//! `into_data`.
//!
//! Every read is counted ([`readbacks`]): on a GPU each one is a wait for the device, so the
//! count per training step or per image is what a device run pays in synchronisations
//! (docs/speed.md, "Readbacks"). A read of a flex tensor counts too, as the same read of a GPU
//! tensor would. The training step and the renderers read through this module only.

use burn::backend::tensor::FloatTensor;
use burn::backend::Flex;
use burn::prelude::*;
use burn::tensor::DType;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::shape::ShapeError;

/// Reads made through this module since the process started.
static READBACKS: AtomicU64 = AtomicU64::new(0);

/// How many tensor reads this process has made through this module ([`HostValues::read`] and
/// the functions built on it), on every thread.
pub fn readbacks() -> u64 {
    READBACKS.load(Ordering::Relaxed)
}

/// The values of `tensor` as f32, row-major. The error is burn's, as text, for the caller to
/// wrap with what it was reading.
pub fn host_values<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, String> {
    HostValues::read(tensor).map(HostValues::into_vec)
}

/// [`host_values`] with the error as a [`ShapeError`] naming `what` was read.
pub fn host_values_of<const D: usize>(
    what: &str,
    tensor: Tensor<D>,
) -> Result<Vec<f32>, ShapeError> {
    host_values(tensor).map_err(|e| ShapeError::value(what, format!("f32 values ({e})")))
}

/// [`HostValues::read`] with the error as a [`ShapeError`] naming `what` was read.
pub fn host_view_of<const D: usize>(
    what: &str,
    tensor: Tensor<D>,
) -> Result<HostValues, ShapeError> {
    HostValues::read(tensor).map_err(|e| ShapeError::value(what, format!("f32 values ({e})")))
}

/// A tensor's f32 values in host memory, row-major, read-only: a contiguous f32 flex tensor's
/// own storage (no copy; the tensor's buffer is shared, not moved), or a copy read back with
/// `into_data`.
pub struct HostValues(Storage);

enum Storage {
    /// A flex tensor and the element range of its storage that holds its values in order.
    Flex(FloatTensor<Flex>, std::ops::Range<usize>),
    Owned(Vec<f32>),
}

impl HostValues {
    /// The values of `tensor`. The error is burn's, as text.
    pub fn read<const D: usize>(tensor: Tensor<D>) -> Result<Self, String> {
        READBACKS.fetch_add(1, Ordering::Relaxed);
        if let Some(values) = Self::borrow(&tensor) {
            return Ok(values);
        }
        let values = tensor
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_err(|e| format!("{e:?}"))?;
        Ok(Self(Storage::Owned(values)))
    }

    /// The values of `tensor` where they are a contiguous f32 flex tensor's storage (no copy),
    /// else `None`.
    pub fn borrow<const D: usize>(tensor: &Tensor<D>) -> Option<Self> {
        let flex = tensor.clone().try_into_primitive::<Flex>().ok()?;
        if flex.dtype() != DType::F32 {
            return None;
        }
        let (start, end) = flex.layout().contiguous_offsets()?;
        Some(Self(Storage::Flex(flex, start..end)))
    }

    /// The values as a vector (one copy where they are a flex tensor's storage).
    pub fn into_vec(self) -> Vec<f32> {
        match self.0 {
            Storage::Owned(values) => values,
            Storage::Flex(..) => self.to_vec(),
        }
    }
}

impl std::ops::Deref for HostValues {
    type Target = [f32];

    fn deref(&self) -> &[f32] {
        match &self.0 {
            Storage::Flex(flex, range) => &flex.storage::<f32>()[range.clone()],
            Storage::Owned(values) => values,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(deprecated)]
    fn flex() -> Device {
        Device::flex()
    }

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    fn values(n: usize) -> Vec<f32> {
        (0..n).map(|i| i as f32 * 0.5 - 3.0).collect()
    }

    #[test]
    fn a_flex_tensor_reads_back_its_values_in_row_major_order() {
        let t = Tensor::<2>::from_data(TensorData::new(values(12), [3, 4]), &flex());
        assert_eq!(host_values(t).unwrap(), values(12));
    }

    #[test]
    fn views_read_back_the_viewed_values_on_flex_and_ndarray() {
        for device in [flex(), ndarray()] {
            let t = Tensor::<2>::from_data(TensorData::new(values(12), [3, 4]), &device);
            // A narrowed view (contiguous at an offset), a strided one and a transpose.
            let rows = host_values(t.clone().slice([1..3, 0..4])).unwrap();
            assert_eq!(rows, values(12)[4..12]);
            let cols = host_values(t.clone().slice([0..3, 1..3])).unwrap();
            assert_eq!(cols, vec![-2.5, -2.0, -0.5, 0.0, 1.5, 2.0]);
            let tr = host_values(t.clone().swap_dims(0, 1)).unwrap();
            let want: Vec<f32> = (0..4)
                .flat_map(|c| (0..3).map(move |r| values(12)[r * 4 + c]))
                .collect();
            assert_eq!(tr, want);
            // A shared tensor reads back the same and stays usable.
            let shared = t.clone();
            assert_eq!(host_values(shared).unwrap(), values(12));
            assert_eq!(HostValues::read(t).unwrap().iter().sum::<f32>(), -3.0);
        }
    }

    #[test]
    fn every_read_is_counted() {
        let before = readbacks();
        let t = Tensor::<1>::from_data(TensorData::new(values(4), [4]), &flex());
        host_values(t.clone()).unwrap();
        host_values_of("t", t.clone() * 2.0).unwrap();
        host_view_of("t", t).unwrap();
        // Other tests of this binary read on other threads at the same time: at least ours.
        assert!(readbacks() >= before + 3);
    }

    #[test]
    fn an_autodiff_tensor_reads_back_through_into_data() {
        let device = flex().autodiff();
        let t = Tensor::<1>::from_data(TensorData::new(values(5), [5]), &device).require_grad();
        assert_eq!(
            host_values(t * 2.0).unwrap(),
            vec![-6.0, -5.0, -4.0, -3.0, -2.0]
        );
    }
}
