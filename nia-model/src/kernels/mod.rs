//! The tensor operations nia-rs writes itself, beside burn's: host kernels on flex's buffers
//! and GPU kernels in cubecl, each with its hand-written backward, and the helpers they share.
//! Every one keeps a plain-tensor reference it is tested against.
//!
//! Host (flex; inference and CPU training):
//! - [`host_op`]: what the host operations share (burn's backend extension, with and without
//!   autodiff); [`host_buffer`]: their output buffers; [`host_gemm`]: their matrix products;
//! - [`linear_host`]: a linear layer (with its ReLU) as one operation;
//! - [`host_mlp`]: stacks of linear layers fused and in parallel (inference);
//! - [`weighted_rows`]: the bilinear and trilinear reads as weighted row gathers.
//!
//! GPU backends (training):
//! - [`tap_gather`]: the weighted row gathers as one operation ([`tracked_op`]: the autodiff side
//!   it shares with the body volume's `Im2col` product); [`tap_scatter`]: their rows'
//!   gradient as one cubecl kernel; [`row_scatter`], [`blocked_rows`]: scatter-adds of
//!   gradient rows on a backend's primitives, in blocks.
//!
//! Every backend:
//! - [`linear_rows`]: a linear layer on a rank-3 input as one matrix product;
//! - [`readback`]: tensors read back to host memory without copies.

pub mod blocked_rows;
pub mod host_buffer;
pub mod host_gemm;
pub mod host_mlp;
pub mod host_op;
pub mod linear_host;
pub mod linear_rows;
pub mod readback;
pub mod row_scatter;
pub mod tap_gather;
pub mod tap_scatter;
pub mod tracked_op;
pub mod weighted_rows;
