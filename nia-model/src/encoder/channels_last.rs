//! The maps' channels-last rows for the bilinear read ([`super::bilinear::ViewRows`]) as one
//! host operation with a hand-written backward (burn's backend extension): on flex, with and
//! without autodiff.
//!
//! `rows[(n H + y) W + x][c] = maps[n][c][y][x]`, then one zero row. The tensor form is a
//! permute, a reshape (a copy into the new layout) and a concatenation with the zero row (a
//! second copy), and under autodiff the concatenation's backward hands a slice to the
//! reshape's, whose gradient the permute's backward then passes on as a transposed view: every
//! reshape behind it (the pyramid's upsampling and reduction) copies that view back into
//! `[N, C, H, W]` order, a transposing copy per view and level. Here the forward is one pass
//! and the backward writes the maps' gradient in their own layout at once (the zero row's
//! gradient is dropped: it reads nothing). Pure data movement: the same values as the tensor
//! form to the bit (`nia-model/tests/bilinear.rs`).

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{unary, Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Autodiff, Backend, Dispatch, Flex, TensorMetadata};
use burn::prelude::*;
use rayon::prelude::*;

use crate::kernels::host_buffer::zeroed;
use crate::kernels::host_op::{contiguous_f32, dims, flex_tensor, values, FlexTensor};

/// The layout change as a backend operation: flex, and autodiff over flex with this module's
/// backward.
#[backend_extension(Autodiff, Flex)]
pub trait ChannelsLastBackend: Backend {
    /// `maps` `[N, C, H, W]` -> `[N H W + 1, C]`, the last row zero.
    fn channels_last_rows(maps: FloatTensor<Self>) -> FloatTensor<Self>;
}

/// The host kernels on a concrete backend's buffers.
pub trait ChannelsLastKernels: Backend {
    /// The forward: `[N, C, H, W]` -> `[N H W + 1, C]`.
    fn channels_last_forward(maps: FloatTensor<Self>) -> FloatTensor<Self>;
    /// The maps' gradient `[N, C, H, W]` (= `dims`) from the rows' `[N H W + 1, C]`.
    fn channels_last_backward(grad: FloatTensor<Self>, dims: [usize; 4]) -> FloatTensor<Self>;
}

/// The forward on host slices: `maps` `[N, C, H, W]` row-major -> `[N H W + 1, C]` row-major.
/// Every task is one image row of one view (W C values), read plane by plane.
pub fn forward(maps: &[f32], [n, c, h, w]: [usize; 4]) -> Vec<f32> {
    let mut out = zeroed((n * h * w + 1) * c);
    if n * c * h * w == 0 {
        return out;
    }
    out[..n * h * w * c]
        .par_chunks_mut(w * c)
        .enumerate()
        .for_each(|(row, out)| {
            let (view, y) = (row / h, row % h);
            for ch in 0..c {
                let plane = &maps[((view * c + ch) * h + y) * w..][..w];
                for (x, &v) in plane.iter().enumerate() {
                    out[x * c + ch] = v;
                }
            }
        });
    out
}

/// The backward on host slices: the rows' gradient `[N H W + 1, C]` -> the maps' `[N, C, H, W]`.
/// Every task is one image row of one channel of one view (W values).
pub fn backward(grad: &[f32], [n, c, h, w]: [usize; 4]) -> Vec<f32> {
    let mut out = zeroed(n * c * h * w);
    if out.is_empty() {
        return out;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
        let (plane, y) = (row / h, row % h);
        let (view, ch) = (plane / c, plane % c);
        let first = (view * h + y) * w;
        for (x, o) in out.iter_mut().enumerate() {
            *o = grad[(first + x) * c + ch];
        }
    });
    out
}

impl ChannelsLastKernels for Flex {
    fn channels_last_forward(maps: FlexTensor) -> FlexTensor {
        let maps = contiguous_f32(maps);
        let [n, c, h, w] = dims::<4>(&maps);
        flex_tensor(forward(values(&maps), [n, c, h, w]), [n * h * w + 1, c])
    }

    fn channels_last_backward(grad: FlexTensor, dims4: [usize; 4]) -> FlexTensor {
        let grad = contiguous_f32(grad);
        let [n, c, h, w] = dims4;
        assert_eq!(
            dims::<2>(&grad),
            [n * h * w + 1, c],
            "channels-last rows: gradient shape for maps {dims4:?}"
        );
        flex_tensor(backward(values(&grad), dims4), dims4)
    }
}

impl ChannelsLastBackend for Flex {
    fn channels_last_rows(maps: FlexTensor) -> FlexTensor {
        <Flex as ChannelsLastKernels>::channels_last_forward(maps)
    }
}

/// The backward of [`ChannelsLastBackend::channels_last_rows`] under autodiff.
#[derive(Debug)]
struct ChannelsLastBackward;

impl<B: Backend + ChannelsLastKernels> Backward<B, 1> for ChannelsLastBackward {
    /// The maps' dimensions.
    type State = [usize; 4];

    fn backward(
        self,
        ops: Ops<Self::State, 1>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let dims = ops.state;
        unary::<B, _>(ops.parents, ops.node, grads, |grad| {
            B::channels_last_backward(grad, dims)
        });
    }
}

impl<B: Backend + ChannelsLastKernels, C: CheckpointStrategy> ChannelsLastBackend
    for Autodiff<B, C>
{
    fn channels_last_rows(maps: FloatTensor<Self>) -> FloatTensor<Self> {
        match ChannelsLastBackward
            .prepare::<C>([maps.node()])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let maps = maps.into_primitive();
                let dims = maps.shape().dims::<4>();
                prep.finish(dims, B::channels_last_forward(maps))
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(B::channels_last_forward(maps.into_primitive()))
            }
        }
    }
}

/// `[N, C, H, W]` maps -> their `[N H W + 1, C]` channels-last rows and a zero row, by the host
/// operation (the device must be flex, with or without autodiff:
/// [`crate::kernels::host_op::runs_on_host`]).
pub fn channels_last_rows(maps: Tensor<4>) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as ChannelsLastBackend>::channels_last_rows(
        maps.into_dispatch(),
    ))
}
