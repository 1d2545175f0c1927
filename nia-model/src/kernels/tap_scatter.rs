//! The taps' weighted scatter-add, `rows[index[j, l]] += weight[j, l] * grad[l]` for K taps and
//! L outputs: the rows' gradient of [`crate::kernels::tap_gather`], as one GPU kernel of our own where
//! the device adds floats atomically ([`crate::device::cube_adds_floats_atomically`]).
//!
//! Without it (ndarray, devices without float atomics) the tensor form runs
//! ([`crate::kernels::row_scatter::weighted_scatter_tensor_form`], or [`crate::kernels::tap_gather`]'s blocks of
//! it): the output gradient weighted by every tap into a `[K L, C]` buffer, then a scatter-add
//! ([`crate::kernels::row_scatter::RowScatter::scatter_add_rows`]). On a GPU that was a copy of the
//! block's taps, a product and a scatter-add per block of at most 64 MiB of values, 16 blocks
//! for a body-volume read at the paper's size. The kernel runs one thread per (tap, output,
//! channel), reads the weight, the index and the gradient where they are and adds atomically:
//! one launch, no buffer. Atomic adds land in no fixed order, so the sums may differ in the
//! last bits from run to run, as burn's atomic scatter-add's do.
//!
//! Under burn's fusion the kernel is a custom operation in the fusion stream, ordered with the
//! operations around it and not fused into them.

/// The kernel on burn's cubecl backend, and its place in the fusion stream.
#[cfg(feature = "wgpu")]
pub mod cube {
    use burn::backend::cubecl::dtype_to_storage_type;
    use burn_cubecl::kernel::into_contiguous;
    use burn_cubecl::tensor::CubeTensor;
    use burn_cubecl::CubeBackend;
    use burn_fusion::custom::{
        CustomOpIr, HandleContainer, OperationFn, OperationIr, StreamId, TensorIr,
    };
    use burn_fusion::{FusionBackend, FusionRuntime, FusionTensor};
    use cubecl::prelude::*;
    use cubecl::{calculate_cube_count_elemwise, CubeDim};

    /// One thread per (tap j, output l, channel c), in that order from the slowest:
    /// `rows[index[j, l], c] += weight[j, l] * grad[l, c]`. All tensors contiguous; an index
    /// past the rows adds nothing.
    #[cube(launch_unchecked, address_type = "dynamic")]
    fn weighted_tap_scatter_kernel<F: Float, I: Int>(
        rows: &mut Tensor<Atomic<F>>,
        grad: &Tensor<F>,
        index: &Tensor<I>,
        weight: &Tensor<F>,
        #[define(F, I)] _dtypes: [ElemType; 2],
    ) {
        let columns = grad.shape(1);
        let outputs = grad.shape(0);
        if ABSOLUTE_POS >= index.shape(0) * outputs * columns {
            terminate!();
        }
        let channel = ABSOLUTE_POS % columns;
        let tap_output = ABSOLUTE_POS / columns;
        let row = usize::cast_from(index[tap_output]);
        if row >= rows.shape(0) {
            terminate!();
        }
        let output = tap_output % outputs;
        rows[row * columns + channel]
            .fetch_add(weight[tap_output] * grad[output * columns + channel]);
    }

    /// Launches the kernel (module docs) on `rows`, in place where `rows` is its buffer's only
    /// owner.
    ///
    /// # Shapes
    /// - `rows`: `[R, C]`; `grad`: `[L, C]`; `index`: `[K, L]` Int; `weight`: `[K, L]`;
    ///   output `[R, C]`
    pub fn weighted_tap_scatter(
        rows: CubeTensor,
        grad: CubeTensor,
        index: CubeTensor,
        weight: CubeTensor,
    ) -> CubeTensor {
        let rows = if !rows.is_contiguous() {
            into_contiguous(rows)
        } else if !rows.can_mut() {
            into_contiguous(rows.copy())
        } else {
            rows
        };
        let (grad, index, weight) = (
            into_contiguous(grad),
            into_contiguous(index),
            into_contiguous(weight),
        );
        // What the launch below relies on, checked: a caller's wrong shape must fail here, not
        // read or write past a buffer on the device.
        let (r, g, i, w) = (
            rows.meta.shape().to_vec(),
            grad.meta.shape().to_vec(),
            index.meta.shape().to_vec(),
            weight.meta.shape().to_vec(),
        );
        assert!(
            r.len() == 2 && g.len() == 2 && i.len() == 2,
            "tap scatter: rows {r:?}, grad {g:?} and index {i:?} must be matrices"
        );
        assert_eq!(i, w, "tap scatter: index and weight shapes [K, L]");
        assert_eq!(i[1], g[0], "tap scatter: index [K, L] against grad [L, C]");
        assert_eq!(r[1], g[1], "tap scatter: rows [R, C] against grad [L, C]");
        let units = index.meta.num_elements() * grad.meta.shape()[1];
        if units == 0 {
            return rows;
        }
        let client = rows.client.clone();
        let cube_dim = CubeDim::new(&client, units);
        let cube_count = calculate_cube_count_elemwise(&client, units, cube_dim);
        let address_type = [&rows, &grad, &index, &weight]
            .iter()
            .map(|t| t.required_address_type())
            .max()
            .unwrap_or_default();
        let dtypes = [
            dtype_to_storage_type(rows.dtype),
            dtype_to_storage_type(index.dtype),
        ];
        // Safety: the kernel indexes `index` and `weight` below K L, `grad` below L C and
        // `rows` below R C (it skips indices past R), on contiguous tensors whose shapes the
        // asserts above tie together.
        unsafe {
            weighted_tap_scatter_kernel::launch_unchecked(
                &client,
                cube_count,
                cube_dim,
                address_type,
                rows.clone().into_tensor_arg(),
                grad.into_tensor_arg(),
                index.into_tensor_arg(),
                weight.into_tensor_arg(),
                dtypes,
            )
        };
        rows
    }

    type Runtime = <CubeBackend as FusionBackend>::FusionRuntime;
    type Handles = HandleContainer<<Runtime as FusionRuntime>::FusionHandle>;

    /// [`weighted_tap_scatter`] as a custom operation of burn's fusion stream: `[R, C]`, of
    /// `rows`' shape and type.
    pub fn fused(
        rows: FusionTensor<Runtime>,
        grad: FusionTensor<Runtime>,
        index: FusionTensor<Runtime>,
        weight: FusionTensor<Runtime>,
    ) -> FusionTensor<Runtime> {
        let client = rows.client.clone();
        let out = TensorIr::uninit(client.create_empty_handle(), rows.shape.clone(), rows.dtype);
        let inputs = [
            rows.into_ir(),
            grad.into_ir(),
            index.into_ir(),
            weight.into_ir(),
        ];
        let description = CustomOpIr {
            id: "nia_weighted_tap_scatter".into(),
            inputs: inputs.to_vec(),
            outputs: vec![out.clone()],
            scalars: Vec::new(),
        };
        let operation = OperationFn(move |handles: &mut Handles| {
            let [rows, grad, index, weight] = &inputs;
            let result = weighted_tap_scatter(
                handles.get_float_tensor::<CubeBackend>(rows),
                handles.get_float_tensor::<CubeBackend>(grad),
                handles.get_int_tensor::<CubeBackend>(index),
                handles.get_float_tensor::<CubeBackend>(weight),
            );
            handles.register_float_tensor::<CubeBackend>(&out.id, result);
            Ok(())
        });
        client
            .register(
                StreamId::current(),
                OperationIr::Custom(description),
                operation,
            )
            .pop()
            .expect("the operation's one output")
    }
}
