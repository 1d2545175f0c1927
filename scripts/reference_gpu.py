"""PyTorch CUDA reference of the NIA network, for side-by-side GPU timing only (not part of nia-rs).

The network, dimensions and inputs of ../shared/reference/nia_torch.py (the paper's appendix
and NHP's code), run on a GPU. One difference: spconv's CUDA wheels are too large to carry to
the lent GPU machine, so the sparse body volume is a sparse convolution written in PyTorch:
rulebooks from sorted voxel keys (torch.searchsorted), then per kernel offset a gather, one
matrix product and an index_add scatter. That is spconv's gather-GEMM-scatter algorithm
without its fused kernels, so this reference's body volume is somewhat slower than spconv's
would be; every other stage is the same PyTorch code as nia_torch.py.

    python3 scripts/reference_gpu.py [--device cuda|cpu] [--rays 1024] [--samples 64] [--views 3]
                                     [--size 512] [--reps 5] [--tf32]

Float32 throughout unless --tf32 (cuDNN's default for convolutions is TF32; nia-rs computes in
f32, so the default here is f32 too). Prints per-stage forward times (synchronised), the first
forward and training step (cuDNN/cuBLAS start-up included), the medians of --reps, and the peak
GPU memory PyTorch allocated, as JSON.
"""
import argparse, json, math, time
import torch, torch.nn as nn, torch.nn.functional as F

p = argparse.ArgumentParser()
p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
p.add_argument("--rays", type=int, default=1024)
p.add_argument("--samples", type=int, default=64)
p.add_argument("--views", type=int, default=3)
p.add_argument("--size", type=int, default=512)
p.add_argument("--reps", type=int, default=5)
p.add_argument("--voxel", type=float, default=0.005)
p.add_argument("--threads", type=int, default=0, help="CPU threads (0: PyTorch's default)")
p.add_argument("--tf32", action="store_true", help="allow TF32 in matmul and convolutions")
a = p.parse_args()
if a.threads:
    torch.set_num_threads(a.threads)
torch.backends.cuda.matmul.allow_tf32 = a.tf32
torch.backends.cudnn.allow_tf32 = a.tf32
dev = torch.device(a.device)
torch.manual_seed(0)
N, H, W, R, S, V = a.views, a.size, a.size, a.rays, a.samples, 6890


def sync():
    if dev.type == "cuda":
        torch.cuda.synchronize()


class BasicBlock(nn.Module):
    def __init__(s, cin, cout, stride):
        super().__init__()
        s.c1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False); s.b1 = nn.BatchNorm2d(cout)
        s.c2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False); s.b2 = nn.BatchNorm2d(cout)
        s.down = None if stride == 1 and cin == cout else nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
    def forward(s, x):
        y = F.relu(s.b1(s.c1(x))); y = s.b2(s.c2(y))
        return F.relu(y + (x if s.down is None else s.down(x)))


class Encoder(nn.Module):
    """ResNet-18 trunk; 64@H/2, 64@H/4, 128@H/8, 256@H/16 upsampled to H/2 and concatenated (512)."""
    def __init__(s):
        super().__init__()
        s.conv1 = nn.Conv2d(3, 64, 7, 2, 3, bias=False); s.bn1 = nn.BatchNorm2d(64)
        s.layer1 = nn.Sequential(BasicBlock(64, 64, 1), BasicBlock(64, 64, 1))
        s.layer2 = nn.Sequential(BasicBlock(64, 128, 2), BasicBlock(128, 128, 1))
        s.layer3 = nn.Sequential(BasicBlock(128, 256, 2), BasicBlock(256, 256, 1))
    def forward(s, x):
        f0 = F.relu(s.bn1(s.conv1(x)))
        f1 = s.layer1(F.max_pool2d(f0, 3, 2, 1)); f2 = s.layer2(f1); f3 = s.layer3(f2)
        up = lambda t: F.interpolate(t, size=f0.shape[-2:], mode="bilinear", align_corners=False)
        return torch.cat([f0, up(f1), up(f2), up(f3)], 1)


# --- sparse convolution in PyTorch (spconv's SubMConv3d / SparseConv3d semantics) ------------
OFFSETS = torch.tensor([[dz, dy, dx] for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])


class Sparse:
    """Active voxels: features [M, C], coords [M, 4] (batch, z, y, x), spatial (D, H, W)."""
    def __init__(s, feats, coords, spatial, batch):
        s.feats, s.coords, s.spatial, s.batch = feats, coords, list(spatial), batch
    def keys(s, coords=None):
        c = (s.coords if coords is None else coords).long()
        D, Hh, Ww = s.spatial
        return ((c[:, 0] * D + c[:, 1]) * Hh + c[:, 2]) * Ww + c[:, 3]
    def dense(s):
        D, Hh, Ww = s.spatial
        out = s.feats.new_zeros(s.batch, D * Hh * Ww, s.feats.shape[1])
        c = s.coords.long()
        out[c[:, 0], (c[:, 1] * Hh + c[:, 2]) * Ww + c[:, 3]] = s.feats
        return out.view(s.batch, D, Hh, Ww, -1).permute(0, 4, 1, 2, 3)


def lookup(sorted_keys, order, keys, valid):
    """Index into the unsorted site list of each key, and whether it exists."""
    pos = torch.searchsorted(sorted_keys, keys).clamp(max=sorted_keys.numel() - 1)
    found = valid & (sorted_keys[pos] == keys)
    return order[pos], found


def rulebook(x, out_coords, out_spatial, stride):
    """Per offset k: (input rows, output rows) with in = stride * out + offset_k (padding 1)."""
    keys = x.keys(); sorted_keys, order = keys.sort()
    book = []
    for off in OFFSETS.to(x.coords.device):
        c = out_coords.clone()
        c[:, 1:] = c[:, 1:] * stride + off
        valid = ((c[:, 1:] >= 0) & (c[:, 1:] < torch.tensor(x.spatial, device=c.device))).all(1)
        rows, found = lookup(sorted_keys, order, x.keys(c.clamp(min=0)), valid)
        out_rows = torch.nonzero(found)[:, 0]
        book.append((rows[out_rows], out_rows))
    return book


def downsampled_sites(x):
    """Output sites of a 3x3x3 stride-2 padding-1 convolution: every o with 2o - 1 + k = i."""
    D, Hh, Ww = x.spatial
    out_spatial = [(d + 2 - 3) // 2 + 1 for d in (D, Hh, Ww)]
    cands = []
    for off in OFFSETS.to(x.coords.device):
        c = x.coords.clone()
        num = c[:, 1:] - off  # = 2o  (i = 2o + off)
        ok = (num % 2 == 0).all(1)
        c[:, 1:] = torch.div(num, 2, rounding_mode="floor")
        ok &= ((c[:, 1:] >= 0) & (c[:, 1:] < torch.tensor(out_spatial, device=c.device))).all(1)
        cands.append(c[ok])
    out = torch.unique(torch.cat(cands), dim=0)
    return out, out_spatial


class SparseConv(nn.Module):
    def __init__(s, cin, cout, stride):
        super().__init__()
        s.stride = stride
        s.weight = nn.Parameter(torch.randn(27, cin, cout) * math.sqrt(2.0 / (27 * cin)))
        s.bn = nn.BatchNorm1d(cout, eps=1e-3, momentum=0.01)
    def forward(s, x, cache):
        key = (s.stride, id(x.coords))
        if key not in cache:
            if s.stride == 1:
                cache[key] = (x.coords, x.spatial, rulebook(x, x.coords, x.spatial, 1))
            else:
                oc, osp = downsampled_sites(x)
                cache[key] = (oc, osp, rulebook(x, oc, osp, 2))
        coords, spatial, book = cache[key]
        out = x.feats.new_zeros(coords.shape[0], s.weight.shape[2])
        for k, (rows_in, rows_out) in enumerate(book):
            if rows_in.numel():
                out = out.index_add(0, rows_out, x.feats[rows_in] @ s.weight[k])
        return Sparse(F.relu(s.bn(out)), coords, spatial, x.batch)


class SparseNet(nn.Module):
    """NHP's sparse conv net: four scales sampled, 64+64+128+128 = 384 channels."""
    def __init__(s):
        super().__init__()
        L = lambda *cs: nn.ModuleList(cs)
        s.c0 = L(SparseConv(64, 64, 1), SparseConv(64, 64, 1))
        s.d0 = SparseConv(64, 64, 2); s.c1 = L(SparseConv(64, 64, 1), SparseConv(64, 64, 1))
        s.d1 = SparseConv(64, 64, 2); s.c2 = L(*[SparseConv(64, 64, 1) for _ in range(3)])
        s.d2 = SparseConv(64, 128, 2); s.c3 = L(SparseConv(128, 128, 1), *[SparseConv(128, 128, 1) for _ in range(2)])
        s.d3 = SparseConv(128, 128, 2); s.c4 = L(*[SparseConv(128, 128, 1) for _ in range(3)])
    def forward(s, x, grid):  # grid: [B, 1, 1, P, 3] in [-1, 1]
        cache = {}
        def seq(layers, x):
            for layer in layers:
                x = layer(x, cache)
            return x
        x = seq(s.c0, x); x = seq(s.c1, s.d0(x, cache)); n1 = x
        x = seq(s.c2, s.d1(x, cache)); n2 = x
        x = seq(s.c3, s.d2(x, cache)); n3 = x
        x = seq(s.c4, s.d3(x, cache)); n4 = x
        feats = [F.grid_sample(n.dense(), grid, padding_mode="zeros", align_corners=True) for n in (n1, n2, n3, n4)]
        return torch.cat(feats, 1).view(grid.shape[0], -1, grid.shape[3])  # [B, 384, P]


def mlp(dims, last_act=False):
    layers = []
    for i in range(len(dims) - 1):
        layers.append(nn.Linear(dims[i], dims[i + 1]))
        if i < len(dims) - 2 or last_act: layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def posenc(d, L=4):
    out = [d]
    for i in range(L):
        out += [torch.sin(2 ** i * d), torch.cos(2 ** i * d)]
    return torch.cat(out, -1)  # 3 + 6L = 27


class NIA(nn.Module):
    def __init__(s):
        super().__init__()
        s.encoder = Encoder()
        s.reduce = nn.Conv1d(512, 64, 1)
        s.sparse = SparseNet()
        s.fc_body = nn.Linear(384, 256)
        s.fc_pix = nn.Linear(512, 256)
        s.phi_k = nn.Linear(256, 128); s.phi_v = nn.Linear(256, 256)
        s.f_sigma = mlp([256, 256, 256, 256, 1])
        s.f_c0_a = mlp([256 + 27, 256, 256, 128], last_act=True); s.f_c0_b = nn.Linear(128, 4)
        s.f_b = mlp([N * (256 + 4 + 1) + 128 + 1] + [256] * 7 + [N + 1])

    def forward(s, imgs, proj_vert, coords, spatial, grid3d, proj_pts, vis_pts, dirs, src_dirs, timed):
        st = {}
        tic = time.perf_counter()
        def mark(name):
            nonlocal tic
            if timed:
                sync(); st[name] = time.perf_counter() - tic; tic = time.perf_counter()
        feat = s.encoder(imgs)                                                       # [N, 512, H/2, W/2]
        mark("encoder")
        vf = F.grid_sample(feat, proj_vert, align_corners=False)[:, :, 0]            # [N, 512, V]
        vf = s.reduce(vf).permute(0, 2, 1).reshape(-1, 64)                           # [N*V, 64]
        # spconv sums features of vertices in one voxel (its SparseConvTensor keeps duplicates
        # only through the first conv's gather); here they are summed into unique sites first.
        keys = ((coords[:, 0].long() * spatial[0] + coords[:, 1]) * spatial[1] + coords[:, 2]) * spatial[2] + coords[:, 3]
        uniq, inv = torch.unique(keys, return_inverse=True)
        site_feats = vf.new_zeros(uniq.numel(), 64).index_add(0, inv, vf)
        site_coords = coords.new_zeros(uniq.numel(), 4); site_coords[inv] = coords
        body = s.sparse(Sparse(site_feats, site_coords, spatial, N), grid3d).permute(0, 2, 1)  # [N, P, 384]
        body = s.fc_body(body)                                                        # [N, P, 256]
        mark("body_volume")
        pix = F.grid_sample(feat, proj_pts, align_corners=False)[:, :, 0].permute(0, 2, 1)  # [N, P, 512]
        cols = F.grid_sample(imgs, proj_pts, align_corners=False)[:, :, 0].permute(0, 2, 1)  # [N, P, 3]
        pix = s.fc_pix(pix)
        mark("sampling")
        Sv, Lv = body.permute(1, 0, 2), pix.permute(1, 0, 2)                          # [P, N, 256]
        att = torch.softmax(s.phi_k(Sv) @ s.phi_k(Lv).transpose(1, 2) / math.sqrt(128), -1)
        Z = att @ s.phi_v(Lv) + Sv                                                    # [P, N, 256]
        sigma = F.relu(s.f_sigma(Z.mean(1)))[:, 0]
        zd = torch.cat([Z, posenc(dirs)[:, None].expand(-1, N, -1)], -1).mean(1)
        h = s.f_c0_a(zd); o = s.f_c0_b(h)
        c0, psi = torch.sigmoid(o[:, :3]), torch.sigmoid(o[:, 3:])
        mark("nerf_mlps")
        dot = (src_dirs * dirs[None]).sum(-1, keepdim=True)
        dh = torch.cat([src_dirs - dirs[None], dot], -1)                              # [N, P, 4]
        bin_ = torch.cat([pix, dh, vis_pts[..., None]], -1).permute(1, 0, 2).reshape(pix.shape[1], -1)
        w = s.f_b(torch.cat([bin_, h, psi], -1))                                      # [P, N+1]
        allc = torch.cat([c0[None], cols], 0).permute(1, 0, 2)                        # [P, N+1, 3]
        c = (torch.softmax(w, -1)[..., None] * allc).sum(1)
        mark("blending")
        sig = sigma.view(R, S); delta = torch.full_like(sig, 2.0 / S)
        tau = torch.cumsum(sig * delta, -1); trans = torch.exp(-(tau - sig * delta))
        wts = trans * (1 - torch.exp(-sig * delta))
        rgb = (wts[..., None] * c.view(R, S, 3)).sum(1); rgb0 = (wts[..., None] * c0.view(R, S, 3)).sum(1)
        mark("compositing")
        return rgb, rgb0, st


def make_inputs():
    imgs = torch.rand(N, 3, H, W)
    # vertices on an ellipsoid shell of a 0.8 x 1.8 x 0.4 m body box, voxelised at a.voxel
    u = torch.rand(V) * 2 * math.pi; v = torch.rand(V) * math.pi
    verts = torch.stack([0.4 * torch.sin(v) * torch.cos(u), 0.9 * torch.cos(v), 0.2 * torch.sin(v) * torch.sin(u)], -1)
    lo = verts.min(0).values - 0.05; hi = verts.max(0).values + 0.05
    shape = ((hi - lo) / a.voxel).ceil().int()
    shape = ((shape + 31) // 32 * 32).tolist()
    idx = ((verts - lo) / a.voxel).floor().int()
    coords = torch.cat([torch.arange(N).repeat_interleave(V)[:, None].int(), idx[:, [2, 1, 0]].repeat(N, 1)], 1)
    proj_vert = torch.rand(N, 1, V, 2) * 2 - 1
    P = R * S
    pts = lo + torch.rand(P, 3) * (hi - lo)
    g = (pts - lo) / (torch.tensor(shape, dtype=torch.float32) * a.voxel) * 2 - 1
    grid3d = g[None, None, None].expand(N, 1, 1, P, 3).contiguous()
    proj_pts = torch.rand(N, 1, P, 2) * 2 - 1
    vis_pts = torch.rand(N, P)
    dirs = F.normalize(torch.randn(P, 3), dim=-1); src_dirs = F.normalize(torch.randn(N, P, 3), dim=-1)
    target = torch.rand(R, 3)
    to = lambda t: t.to(dev) if torch.is_tensor(t) else t
    inputs = [imgs, proj_vert, coords, shape[::-1], grid3d, proj_pts, vis_pts, dirs, src_dirs]
    return [to(t) for t in inputs], to(target)


model = NIA().to(dev)
inputs, target = make_inputs()
opt = torch.optim.Adam(model.parameters(), lr=5e-4)
if dev.type == "cuda":
    torch.cuda.reset_peak_memory_stats()


def timed(fn):
    sync(); t0 = time.perf_counter(); out = fn(); sync()
    return time.perf_counter() - t0, out


# forward (inference mode): the first call, then reps timed without per-stage syncs, then
# reps with them for the stage shares
model.eval()
fw, stages = [], {}
with torch.no_grad():
    first_forward, _ = timed(lambda: model(*inputs, False))
    for _ in range(a.reps):
        fw.append(timed(lambda: model(*inputs, False))[0])
    for _ in range(a.reps):
        _, (_, _, st) = timed(lambda: model(*inputs, True))
        for k, v in st.items(): stages.setdefault(k, []).append(v)


def train_step():
    rgb, rgb0, _ = model(*inputs, False)
    loss = F.mse_loss(rgb, target) + F.mse_loss(rgb0, target)
    opt.zero_grad(); loss.backward(); opt.step()
    return loss


model.train()
first_train, _ = timed(train_step)
tr = [timed(train_step)[0] for _ in range(a.reps)]
med = lambda xs: sorted(xs)[len(xs) // 2]
print(json.dumps({
    "torch": torch.__version__, "device": torch.cuda.get_device_name() if dev.type == "cuda" else "cpu",
    "precision": "tf32" if a.tf32 else "f32", "sparse_conv": "PyTorch gather-GEMM-scatter (not spconv)",
    "rays": R, "samples": S, "views": N, "size": H,
    "first_forward_s": first_forward, "first_train_step_s": first_train,
    "forward_s": med(fw), "forward_rays_per_s": R / med(fw),
    "train_step_s": med(tr), "train_rays_per_s": R / med(tr),
    "stages_s": {k: med(v) for k, v in stages.items()},
    "peak_gpu_mib": torch.cuda.max_memory_allocated() / 2**20 if dev.type == "cuda" else None,
    "params": sum(p.numel() for p in model.parameters()),
}))
