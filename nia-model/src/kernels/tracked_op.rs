//! The autodiff side of the training operations with a hand-written backward on two float
//! inputs ([`crate::kernels::tap_gather`], [`crate::body_volume::im2col_op`]): under burn's
//! autodiff the forward runs on the inner backend's primitives and, where the graph tracks an
//! input, the operation's inputs are kept; the backward registers the gradients of the inputs
//! that take one.

use std::fmt;
use std::marker::PhantomData;

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Autodiff, Backend};

/// An operation on two float inputs with a hand-written backward.
pub trait TwoFloatOp<B: Backend>: Send + Sync + 'static {
    /// The operation's inputs on the inner backend (its two float tensors and the rest), which
    /// the backward keeps.
    type Inputs: Clone + Send + fmt::Debug + 'static;

    /// The forward.
    fn forward(inputs: &Self::Inputs) -> FloatTensor<B>;

    /// The gradients of the two float inputs from the output's `grad`: at least those `wants`
    /// asks for (the inputs the graph tracks).
    fn backward(
        grad: FloatTensor<B>,
        inputs: Self::Inputs,
        wants: [bool; 2],
    ) -> [Option<FloatTensor<B>>; 2];
}

/// The backward node of `Op`.
pub struct OpBackward<Op>(PhantomData<Op>);

impl<Op> fmt::Debug for OpBackward<Op> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(std::any::type_name::<Op>())
    }
}

impl<B: Backend, Op: TwoFloatOp<B>> Backward<B, 2> for OpBackward<Op> {
    type State = Op::Inputs;

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let grad = grads.consume::<B>(&ops.node);
        let wants = [ops.parents[0].is_some(), ops.parents[1].is_some()];
        let got = Op::backward(grad, ops.state, wants);
        for (node, g) in ops.parents.into_iter().zip(got) {
            if let (Some(node), Some(g)) = (node, g) {
                grads.register::<B>(node.id, g);
            }
        }
    }
}

/// `Op` under autodiff on the float inputs `floats` (either may be tracked), which `inputs`
/// places among the operation's other inputs.
pub fn run<B, C, Op>(
    floats: [FloatTensor<Autodiff<B, C>>; 2],
    inputs: impl FnOnce([FloatTensor<B>; 2]) -> Op::Inputs,
) -> FloatTensor<Autodiff<B, C>>
where
    B: Backend,
    C: CheckpointStrategy,
    Op: TwoFloatOp<B>,
{
    let [(a, a_node), (b, b_node)] = floats.map(|t| t.into_parts());
    match OpBackward::<Op>(PhantomData)
        .prepare::<C>([a_node, b_node])
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let inputs = inputs([a, b]);
            let out = Op::forward(&inputs);
            prep.finish(inputs, out)
        }
        OpsKind::UnTracked(prep) => prep.finish(Op::forward(&inputs([a, b]))),
    }
}
