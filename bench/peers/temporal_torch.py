"""PyTorch CPU peer of `cargo xtask bench temporal` (entry generation_vs_solver).

Times, on the same threads as pbdl's rows (PBDL_THREADS, default 2), the same networks and the
same training update as pbdl-temporal, written here from pbdl's code (f32, random inputs of the
right shapes; no pbdl data needed, the time does not depend on the values):

  * Generator (pbdl_temporal::generator::FrameGenerator, default GeneratorConfig: factor 4, no
    velocity input, 32 channels): 3x3 conv 1 -> 32 (zero padding) + ReLU, ResBlock(32); per 2x
    step (twice) a nearest 2x upsample, 3x3 conv 32 -> 32 + ReLU, ResBlock(32); 3x3 conv 32 -> 1,
    plus the bicubic x4 upsample of the input (align_corners False). ResBlock = pbdl-nets'
    post-activation block without norm: x + relu(conv(relu(conv(x)))). All convs with bias.
    74,593 parameters (checked below).
  * Discriminators (pbdl_nets::discriminator, DiscriminatorConfig::new(c, [16, 32, 64, 64])):
    4 levels of 4x4 conv stride 2 padding 1 (zeros) + LeakyReLU 0.2, no norm; head Linear(64, 1)
    on the spatial mean of the last level. D_s takes 2 channels (nearest-upsampled LR next to an
    HR frame), D_t 3 (frame t-1 advected forward, t, t+1 advected back).
  * Advection (pbdl_temporal::warp::advect): out(x) = field(x - k v(x)), bilinear, borders
    clamped, with v the LR velocity upsampled bilinearly x4 (align_corners False) and times 4:
    grid_sample(padding_mode="border", align_corners=True) at pixel coordinates x - k v.

Rows (case and size equal pbdl's rows, so the report pairs them):
  * temporal_generate_frame, 16->64 and 64->256: the generator forward in eval / no-grad mode on a
    batch of 8 LR frames, seconds per frame (batch time / 8); median of --reps after a warm-up.
  * temporal_train_update_{baseline,per_frame,temporal}, 16->64_b4x3: one update as
    pbdl_temporal::train::finetune does it, on a batch of 4 triplets (12 LR frames 16x16, HR
    64x64, LR velocity): baseline = 5 L1 + backward + Adam step; per_frame = the D_s update on
    real vs detached fake (BCE with logits), then the generator on 5 L1 + BCE(D_s(fake), 1)
    - 1e-5 * feature loss over D_s's levels (real features detached); temporal = the same plus
    D_t in both updates (D_t has no feature term). One Adam (lr 2e-4, betas (0.5, 0.999)) holds
    all networks; each update steps only its player's gradients. pbdl's balance lets D_s train
    while its average is below 0.4, which holds in these few updates, so D trains every update
    here. pbdl's time also includes gathering the 12 frames from its clips (a few narrows and a
    cat), left out here. Median of --reps updates after --warmup updates.

Output: {"rows": [...]} in the shared bench schema (peer: true), stamped by provenance.py; the
stamp's versions also name OMP_WAIT_POLICY (temporal_run.sh sets PASSIVE unless it is set: on
two cores shared with other busy processes, spinning OpenMP threads made this peer 2-3x slower).

Usage: bench/peers/temporal_run.sh [--reps N] [--only CASE]  (installs torch in the shared venv),
or with torch: python3 bench/peers/temporal_torch.py --out target/pbdl/bench/temporal_peers.json
"""

import argparse
import json
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
    print("peers: skipped: torch is not installed", file=sys.stderr)
    sys.exit(0)

FACTOR = 4
CHANNELS = 32
D_WIDTHS = (16, 32, 64, 64)
LOSS_L1, LOSS_SPATIAL, LOSS_TEMPORAL, LOSS_FEATURE = 5.0, 1.0, 1.0, -1e-5
LR_RATE, BETAS = 2e-4, (0.5, 0.999)


def conv3(c_in, c_out):
    return nn.Conv2d(c_in, c_out, 3, padding=1)


class ResBlock(nn.Module):
    """pbdl-nets' post-activation block without norm: x + relu(conv(relu(conv(x))))."""

    def __init__(self, c):
        super().__init__()
        self.unit1, self.unit2 = conv3(c, c), conv3(c, c)

    def forward(self, x):
        return x + F.relu(self.unit2(F.relu(self.unit1(x))))


class FrameGenerator(nn.Module):
    def __init__(self, c=CHANNELS, factor=FACTOR):
        super().__init__()
        levels = factor.bit_length() - 1
        self.factor = factor
        self.input = conv3(1, c)
        self.blocks = nn.ModuleList(ResBlock(c) for _ in range(levels + 1))
        self.ups = nn.ModuleList(conv3(c, c) for _ in range(levels))
        self.output = conv3(c, 1)

    def forward(self, density):
        h = self.blocks[0](F.relu(self.input(density)))
        for up, blk in zip(self.ups, self.blocks[1:]):
            h = blk(F.relu(up(F.interpolate(h, scale_factor=2, mode="nearest"))))
        base = F.interpolate(density, scale_factor=self.factor, mode="bicubic", align_corners=False)
        return self.output(h) + base


class Discriminator(nn.Module):
    def __init__(self, c_in, widths=D_WIDTHS):
        super().__init__()
        cs = (c_in,) + tuple(widths)
        self.levels = nn.ModuleList(nn.Conv2d(a, b, 4, stride=2, padding=1) for a, b in zip(cs[:-1], cs[1:]))
        self.head = nn.Linear(cs[-1], 1)

    def forward(self, x):
        feats = []
        for conv in self.levels:
            x = F.leaky_relu(conv(x), 0.2)
            feats.append(x)
        return self.head(x.mean(dim=(2, 3))).squeeze(1), feats


def bce(logits, target):
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, target))


def spatial_input(lr, hr):
    return torch.cat([F.interpolate(lr, scale_factor=FACTOR, mode="nearest"), hr], 1)


def advect(field, v, k):
    """out(x) = field(x - k v(x)) in pixel units, bilinear, borders clamped (pbdl's warp)."""
    b, _, h, w = field.shape
    ys, xs = torch.meshgrid(torch.arange(h, dtype=field.dtype), torch.arange(w, dtype=field.dtype), indexing="ij")
    px = xs - k * v[:, 0]
    py = ys - k * v[:, 1]
    grid = torch.stack([2.0 * px / (w - 1) - 1.0, 2.0 * py / (h - 1) - 1.0], dim=-1)
    return F.grid_sample(field, grid, mode="bilinear", padding_mode="border", align_corners=True)


def temporal_input(hr, lr_vel):
    """[B, 3, Y, X] from hr [3B, 1, Y, X] (triplets t-1, t, t+1) and the LR velocity [3B, 2, y, x]."""
    n, _, h, w = hr.shape
    b = n // 3
    v = F.interpolate(lr_vel, scale_factor=FACTOR, mode="bilinear", align_corners=False) * FACTOR
    frames = hr.reshape(b, 3, h, w)
    vel = v.reshape(b, 3, 2, h, w)
    fwd = advect(frames[:, 0:1], vel[:, 0], 1.0)
    bwd = advect(frames[:, 2:3], vel[:, 2], -1.0)
    return torch.cat([fwd, frames[:, 1:2], bwd], 1)


def feature_loss(real, fake):
    return sum((r - f).abs().mean() for r, f in zip(real, fake))


def make_update(kind, lr, hr, vel):
    """One pbdl finetune update of `kind` (fresh networks and Adam); returns the closure."""
    gen = FrameGenerator()
    d_s = Discriminator(2) if kind != "baseline" else None
    d_t = Discriminator(3) if kind == "temporal" else None
    disc = [m for m in (d_s, d_t) if m is not None]
    params = list(gen.parameters()) + [p for d in disc for p in d.parameters()]
    opt = torch.optim.Adam(params, lr=LR_RATE, betas=BETAS)
    d_params = [p for d in disc for p in d.parameters()]

    def update():
        fake = gen(lr)
        l1 = (fake - hr).abs().mean()
        if d_s is not None:
            # Discriminators: real vs generated (detached).
            real_s, _ = d_s(spatial_input(lr, hr))
            fake_s, _ = d_s(spatial_input(lr, fake.detach()))
            d_loss = bce(real_s, 1.0) + bce(fake_s, 0.0)
            _log_d_real = -bce(real_s, 1.0).item()
            if d_t is not None:
                real_t, _ = d_t(temporal_input(hr, vel))
                fake_t, _ = d_t(temporal_input(fake.detach(), vel))
                d_loss = d_loss + bce(real_t, 1.0) + bce(fake_t, 0.0)
            _d_value = d_loss.item()
            opt.zero_grad(set_to_none=True)
            d_loss.backward()
            opt.step()
        # Generator.
        g_loss = l1 * LOSS_L1
        if d_s is not None:
            _, real_feats = d_s(spatial_input(lr, hr))
            fake_logits, fake_feats = d_s(spatial_input(lr, fake))
            adv = bce(fake_logits, 1.0)
            _adversarial = adv.item()
            g_loss = g_loss + adv * LOSS_SPATIAL
            g_loss = g_loss + feature_loss([r.detach() for r in real_feats], fake_feats) * LOSS_FEATURE
            if d_t is not None:
                logits_t, _ = d_t(temporal_input(fake, vel))
                g_loss = g_loss + bce(logits_t, 1.0) * LOSS_TEMPORAL
        opt.zero_grad(set_to_none=True)
        g_loss.backward()
        for p in d_params:
            p.grad = None
        opt.step()
        return g_loss.item(), l1.item()

    return update


def median_seconds(fn, warmup, reps):
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), ts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--reps", type=int, default=11, help="timed runs per case (pbdl's bench uses 11)")
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--only", default="", help="run only cases whose name contains this")
    args = ap.parse_args()
    torch.set_num_threads(THREADS)
    torch.manual_seed(0)

    n_params = sum(p.numel() for p in FrameGenerator().parameters())
    assert n_params == 74593, f"generator has {n_params} parameters, pbdl's default has 74593"
    n_d = [sum(p.numel() for p in Discriminator(c).parameters()) for c in (2, 3)]
    print(f"peers: generator {n_params} parameters, D_s {n_d[0]}, D_t {n_d[1]}; {THREADS} threads", file=sys.stderr)

    cases = []  # (case, size, unit, per_unit_divisor, fn)
    gen = FrameGenerator().eval()
    batch = 8
    for n in (16, 64):
        x = torch.rand(batch, 1, n, n)

        def generate(x=x):
            with torch.inference_mode():
                return gen(x)

        cases.append(("temporal_generate_frame", f"{n}->{FACTOR * n}", "frame", batch, generate))

    trip = 4 * 3
    lr = torch.rand(trip, 1, 16, 16)
    hr = torch.rand(trip, 1, 16 * FACTOR, 16 * FACTOR)
    vel = 0.5 * torch.randn(trip, 2, 16, 16)  # LR cells per frame
    for kind in ("baseline", "per_frame", "temporal"):
        cases.append((f"temporal_train_update_{kind}", "16->64_b4x3", "update", 1,
                      lambda kind=kind: make_update(kind, lr, hr, vel)))

    rows = []
    for case, size, unit, div, fn in cases:
        if args.only and args.only not in case:
            continue
        if unit == "update":
            fn = fn()  # build the networks and the optimiser outside the timing
        s, ts = median_seconds(fn, args.warmup, args.reps)
        s /= div
        print(f"{case} {size}: {s * 1e3:.3f} ms / {unit} (min {min(ts) / div * 1e3:.3f}, "
              f"max {max(ts) / div * 1e3:.3f})", file=sys.stderr)
        rows.append({"case": case, "method": f"pytorch_{torch.__version__}_cpu", "size": size, "seconds": s,
                     "unit": unit, "error": None, "error_kind": "", "peer": True, "threads": THREADS})
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        versions = f"{versions_of(torch)}, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}"
        json.dump({"rows": stamp(rows, __file__, versions)}, f, indent=2)
    print(f"peers: wrote {len(rows)} rows to {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
