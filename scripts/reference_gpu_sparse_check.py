"""Checks scripts/reference_gpu.py's PyTorch sparse convolution against spconv's CPU one.

    python3 scripts/reference_gpu_sparse_check.py     # needs torch and spconv (pip install spconv)

Same weights, random active sites in two batches: SubMConv3d(3) and SparseConv3d(3, stride 2,
padding 1). Prints the largest difference of the dense outputs (ReLU applied to spconv's, as the
reference's layer ends in BN + ReLU and BN is replaced by the identity here).
"""
import os, sys, torch
sys.argv = ["x", "--device", "cpu"]
here = os.path.dirname(os.path.abspath(__file__))
src = open(os.path.join(here, "reference_gpu.py")).read().split("model = NIA()")[0]
g = {}; exec(compile(src, "ref", "exec"), g)
import spconv.pytorch as spconv
import spconv.pytorch.ops as _spops, spconv.pytorch.cppcore as _spcore
_spops.get_current_stream = _spcore.get_current_stream = lambda: 0
torch.manual_seed(1)
D = [20, 24, 16]; M = 300
coords = torch.unique(torch.stack([torch.randint(0, 2, (M,)), torch.randint(0, D[0], (M,)), torch.randint(0, D[1], (M,)), torch.randint(0, D[2], (M,))], 1), dim=0).int()
feats = torch.randn(coords.shape[0], 4)
for stride in (1, 2):
    ref = (spconv.SubMConv3d(4, 5, 3, bias=False) if stride == 1 else spconv.SparseConv3d(4, 5, 3, 2, padding=1, bias=False))
    print("spconv weight", tuple(ref.weight.shape))
    ours = g["SparseConv"](4, 5, stride); ours.eval()
    w = ref.weight.detach()  # [out, kz, ky, kx, in]
    ours.weight.data = w.permute(1, 2, 3, 4, 0).reshape(27, 4, 5).clone()
    ours.bn = torch.nn.Identity()
    x = spconv.SparseConvTensor(feats, coords, D, 2)
    y = ref(x).dense()
    out = ours(g["Sparse"](feats, coords, D, 2), {})
    # undo our relu for comparison: compare relu(y)
    yo = out.dense()
    diff = float((torch.relu(y) - yo).abs().max().detach())
    print(f"stride {stride}: output {tuple(yo.shape)}, max |spconv - ours| {diff:.2e} (values up to {float(y.abs().max().detach()):.2f})")
    assert yo.shape == y.shape and diff < 1e-5, "the PyTorch sparse convolution differs from spconv"
