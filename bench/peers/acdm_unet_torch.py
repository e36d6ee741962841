"""PyTorch CPU peer of `cargo xtask bench diffusion` entry `acdm_unet` (pbdl-diffusion/src/unet).

Times the same work as pbdl's `UnetFixture` (pbdl-diffusion/src/unet/workload.rs):
  * acdm_unet_train_step_f32: forward of the ACDM U-Net, mean smooth-L1 loss against a fixed
    target, backward, Adam update (lr 1e-4);
  * acdm_unet_sample_step_f32: forward only (under torch.no_grad()).
Sizes: dim 16 and 32 at 64x32, batch 16, 12 channels; with --full also dim 128 at 128x64, batch 4.

The network is written here from the architecture description in pbdl-diffusion/src/unet/acdm.rs
(ConvNeXt blocks with depthwise 7x7 conv and step bias, one-group GroupNorms, exact GELU, residual
linear attention 4 x 32 on every level, full attention in the middle, 4x4 stride-2 down conv,
4x4 transposed up conv, sinusoidal step embedding -> Linear(4 dim) -> GELU -> Linear(4 dim),
unused top-level skip). Its parameter count is checked against pbdl's (6,981,300 for dim 128 and
12 channels) before timing.

Usage (2 threads, as pbdl's rows): bench/peers/diffusion_run.sh [--full] installs torch in its own
venv and runs this script; or, with torch already installed,
    python3 bench/peers/acdm_unet_torch.py --out target/pbdl/bench/diffusion_peers.json [--full]
Output: {"rows": [{case, method, size, seconds, unit, error, error_kind, peer: true, threads}]}.
"""

import argparse
import json
import math
import os
import statistics
import sys
import time

from provenance import stamp, versions_of  # bench/peers/provenance.py, beside this script

THREADS = int(os.environ.get("PBDL_THREADS", "2"))

try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError:
    print("peers: skipped: torch is not installed (pip install torch --index-url "
          "https://download.pytorch.org/whl/cpu)", file=sys.stderr)
    sys.exit(0)


def step_embedding(t, dim):
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) / (half - 1) * torch.arange(half, dtype=torch.float32))
    args = t.float()[:, None] * freqs[None, :]
    return torch.cat([args.sin(), args.cos()], dim=1)


class ConvNext(nn.Module):
    def __init__(self, c_in, c_out, time_dim=None):
        super().__init__()
        self.time = nn.Linear(time_dim, c_in) if time_dim else None
        self.dw = nn.Conv2d(c_in, c_in, 7, padding=3, groups=c_in)
        self.n1 = nn.GroupNorm(1, c_in)
        self.c1 = nn.Conv2d(c_in, c_out, 3, padding=1)
        self.n2 = nn.GroupNorm(1, c_out)
        self.c2 = nn.Conv2d(c_out, c_out, 3, padding=1)
        self.res = nn.Conv2d(c_in, c_out, 1) if c_in != c_out else None

    def forward(self, x, temb=None):
        h = self.dw(x)
        if self.time is not None and temb is not None:
            h = h + self.time(F.gelu(temb))[:, :, None, None]
        h = self.c2(self.n2(F.gelu(self.c1(self.n1(h)))))
        return h + (self.res(x) if self.res is not None else x)


class PixelAttention(nn.Module):
    """Residual, pre-normed multi-head attention over pixels (linear or full)."""

    def __init__(self, c, linear, heads=4, dim_head=32):
        super().__init__()
        self.linear, self.heads, self.d = linear, heads, dim_head
        self.pre = nn.GroupNorm(1, c)
        self.qkv = nn.Conv2d(c, 3 * heads * dim_head, 1, bias=False)
        self.out = nn.Conv2d(heads * dim_head, c, 1)
        self.post = nn.GroupNorm(1, c) if linear else None

    def forward(self, x):
        b, _, h, w = x.shape
        q, k, v = self.qkv(self.pre(x)).reshape(b, 3, self.heads, self.d, h * w).unbind(1)
        scale = self.d ** -0.5
        if self.linear:
            q = q.softmax(dim=2) * scale
            k = k.softmax(dim=3)
            o = (k @ v.transpose(2, 3)).transpose(2, 3) @ q
        else:
            attn = ((q * scale).transpose(2, 3) @ k).softmax(dim=3)
            o = v @ attn.transpose(2, 3)
        o = self.out(o.reshape(b, self.heads * self.d, h, w))
        if self.post is not None:
            o = self.post(o)
        return o + x


class AcdmUnet(nn.Module):
    def __init__(self, dim, channels, levels=3):
        super().__init__()
        init = dim // 3 * 2
        td = 4 * dim
        self.dim = dim
        self.init = nn.Conv2d(channels, init, 7, padding=3)
        self.t1, self.t2 = nn.Linear(dim, td), nn.Linear(td, td)
        self.downs = nn.ModuleList()
        for i in range(levels):
            c_in = init if i == 0 else dim
            self.downs.append(nn.ModuleList([
                ConvNext(c_in, dim, td), ConvNext(dim, dim, td), PixelAttention(dim, True),
                nn.Conv2d(dim, dim, 4, 2, 1) if i < levels - 1 else nn.Identity()]))
        self.mid1, self.mid_attn, self.mid2 = ConvNext(dim, dim, td), PixelAttention(dim, False), ConvNext(dim, dim, td)
        self.ups = nn.ModuleList([nn.ModuleList([
            ConvNext(2 * dim, dim, td), ConvNext(dim, dim, td), PixelAttention(dim, True),
            nn.ConvTranspose2d(dim, dim, 4, 2, 1)]) for _ in range(levels - 1)])
        self.head = ConvNext(dim, dim)
        self.final = nn.Conv2d(dim, channels, 1)

    def forward(self, x, t):
        temb = self.t2(F.gelu(self.t1(step_embedding(t, self.dim))))
        h = self.init(x)
        skips = []
        for b1, b2, attn, down in self.downs:
            h = attn(b2(b1(h, temb), temb))
            skips.append(h)
            h = down(h)
        h = self.mid2(self.mid_attn(self.mid1(h, temb)), temb)
        for b1, b2, attn, up in self.ups:  # the first skip is never used, as in ACDM
            h = up(attn(b2(b1(torch.cat([h, skips.pop()], dim=1), temb), temb)))
        return self.final(self.head(h))


def median_seconds(fn, warmup=1, reps=5):
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--full", action="store_true", help="also dim 128, 128x64, batch 4")
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(THREADS)
    torch.manual_seed(0)
    n = sum(p.numel() for p in AcdmUnet(128, 12).parameters())
    if n != 6_981_300:
        sys.exit(f"peer network has {n} parameters, pbdl's AcdmUnet has 6,981,300: fix the peer first")
    sizes = [(16, 16, 64, 32), (32, 16, 64, 32)] + ([(128, 4, 128, 64)] if args.full else [])
    rows = []
    for dim, batch, hgt, wid in sizes:
        net = AcdmUnet(dim, 12)
        opt = torch.optim.Adam(net.parameters(), lr=1e-4)
        x = torch.randn(batch, 12, hgt, wid)
        target = torch.randn(batch, 12, hgt, wid)
        t = torch.arange(batch) % 20

        def train():
            opt.zero_grad(set_to_none=True)
            F.smooth_l1_loss(net(x, t), target).backward()
            opt.step()

        def sample():
            with torch.no_grad():
                net(x, t)

        reps = min(args.reps, 3) if dim >= 128 else args.reps
        label = f"dim{dim}_b{batch}_c12_{hgt}x{wid}"
        for case, fn in [("acdm_unet_train_step_f32", train), ("acdm_unet_sample_step_f32", sample)]:
            s = median_seconds(fn, reps=reps)
            print(f"{case} {label}: {s:.4f} s", file=sys.stderr)
            rows.append({"case": case, "method": "pytorch_cpu", "size": label, "seconds": s, "unit": "step",
                         "error": None, "error_kind": "", "peer": True, "threads": THREADS})
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump({"rows": stamp(rows, __file__, versions_of(torch))}, f, indent=2)


if __name__ == "__main__":
    main()
