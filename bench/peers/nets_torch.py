"""PyTorch CPU peer of `cargo xtask bench nets` (issue 17: the NN layer the coming methods train).

Times, on the same threads as pbdl's rows (PBDL_THREADS, default 2), the same networks written
here from their published descriptions (shared/methods/weather.md, temporal.md), f32:
  * weather_resnet_train_step: Rasp & Thuerey's WeatherBench ResNet - periodic-in-longitude
    7x7 conv 117 -> 128, 19 residual blocks of two (3x3 periodic conv 128 -> LeakyReLU 0.3 ->
    BatchNorm in training mode) + identity, 3x3 periodic conv 128 -> 3; 32x64 grid; MSE against
    a fixed target, backward, Adam (lr 1e-4). Dropout 0 (the paper's best model uses none).
  * tecogan_generator_fwd_bwd: TecoGAN's generator - input 51 channels (LR frame 3 + warped
    previous HR output space-to-depth 48) at 32x32, 3x3 conv -> 64 + ReLU, 16 residual blocks
    (conv-ReLU-conv + skip), two 3x3 transposed convs stride 2 (64, ReLU), 3x3 conv -> 3, plus
    the bicubic x4 upsampling of the LR frame; MSE against a 128x128 target, backward (no
    optimiser step).
  * lstm_fwd_bwd: one LSTM layer over 6 steps of latent vectors (input = hidden = size,
    batch_first), MSE of all hidden states against a fixed target, backward.
Output: {"rows": [{case, method, size, seconds, unit, error, error_kind, peer: true, threads,
torch}]} in the shared bench schema; median of --reps runs after one warm-up.

Usage: bench/peers/nets_run.sh [--reps N]  (installs torch in its own venv), or with torch:
    python3 bench/peers/nets_torch.py --out target/pbdl/bench/nets_peers.json
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


class PeriodicConv(nn.Module):
    """Circular padding in x (longitude), zeros in y (latitude), then a valid conv."""

    def __init__(self, c_in, c_out, k):
        super().__init__()
        self.p = k // 2
        self.conv = nn.Conv2d(c_in, c_out, k)

    def forward(self, x):
        x = F.pad(x, (self.p, self.p, 0, 0), mode="circular")
        x = F.pad(x, (0, 0, self.p, self.p))
        return self.conv(x)


class ConvBlock(nn.Module):
    def __init__(self, c_in, c_out, k):
        super().__init__()
        self.conv = PeriodicConv(c_in, c_out, k)
        self.bn = nn.BatchNorm2d(c_out)

    def forward(self, x):
        return self.bn(F.leaky_relu(self.conv(x), 0.3))


class WeatherResNet(nn.Module):
    def __init__(self, c_in=117, width=128, blocks=19, c_out=3):
        super().__init__()
        self.inp = ConvBlock(c_in, width, 7)
        self.blocks = nn.ModuleList(nn.Sequential(ConvBlock(width, width, 3), ConvBlock(width, width, 3))
                                    for _ in range(blocks))
        self.out = PeriodicConv(width, c_out, 3)

    def forward(self, x):
        x = self.inp(x)
        for b in self.blocks:
            x = x + b(x)
        return self.out(x)


class TecoGenerator(nn.Module):
    def __init__(self, c_in=51, width=64, blocks=16):
        super().__init__()
        self.inp = nn.Conv2d(c_in, width, 3, padding=1)
        self.blocks = nn.ModuleList(nn.Sequential(nn.Conv2d(width, width, 3, padding=1), nn.ReLU(),
                                                  nn.Conv2d(width, width, 3, padding=1)) for _ in range(blocks))
        self.up1 = nn.ConvTranspose2d(width, width, 3, stride=2, padding=1, output_padding=1)
        self.up2 = nn.ConvTranspose2d(width, width, 3, stride=2, padding=1, output_padding=1)
        self.out = nn.Conv2d(width, 3, 3, padding=1)

    def forward(self, x):
        lr = x[:, :3]
        h = F.relu(self.inp(x))
        for b in self.blocks:
            h = h + b(h)
        h = F.relu(self.up1(h))
        h = F.relu(self.up2(h))
        return self.out(h) + F.interpolate(lr, scale_factor=4, mode="bicubic", align_corners=False)


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
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--only", default="", help="run only cases whose name contains this")
    args = ap.parse_args()
    torch.set_num_threads(THREADS)
    torch.manual_seed(0)
    cases = []

    # WeatherBench ResNet, batch 4 (the paper trains at 32; 4 keeps a step near a second here).
    net = WeatherResNet()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    xw, yw = torch.randn(4, 117, 32, 64), torch.randn(4, 3, 32, 64)

    def weather():
        opt.zero_grad(set_to_none=True)
        F.mse_loss(net(xw), yw).backward()
        opt.step()

    cases.append(("weather_resnet_train_step", "b4_c117_w128_blocks19_32x64", weather))

    # pbdl-weather's CPU-sized forecaster (stand-in experiment): 10 inputs, width 32, 4 blocks, batch 32.
    small = WeatherResNet(c_in=10, width=32, blocks=4, c_out=2)
    opt_small = torch.optim.Adam(small.parameters(), lr=1e-3)
    xs_, ys_ = torch.randn(32, 10, 32, 64), torch.randn(32, 2, 32, 64)

    def weather_cpu():
        opt_small.zero_grad(set_to_none=True)
        F.mse_loss(small(xs_), ys_).backward()
        opt_small.step()

    cases.append(("weather_cpu_resnet_train_step", "b32_c10_w32_blocks4_32x64", weather_cpu))

    gen = TecoGenerator()
    xg, yg = torch.randn(4, 51, 32, 32), torch.randn(4, 3, 128, 128)

    def teco():
        gen.zero_grad(set_to_none=True)
        F.mse_loss(gen(xg), yg).backward()

    cases.append(("tecogan_generator_fwd_bwd", "b4_c51_w64_blocks16_32to128", teco))

    for size in (256, 1024):
        lstm = nn.LSTM(size, size, batch_first=True)
        xs, ys = torch.randn(16, 6, size), torch.randn(16, 6, size)

        def run_lstm(lstm=lstm, xs=xs, ys=ys):
            lstm.zero_grad(set_to_none=True)
            out, _ = lstm(xs)
            F.mse_loss(out, ys).backward()

        cases.append(("lstm_fwd_bwd", f"b16_t6_h{size}", run_lstm))

    rows = []
    for case, label, fn in cases:
        if args.only and args.only not in case:
            continue
        s = median_seconds(fn, reps=args.reps)
        print(f"{case} {label}: {s:.4f} s", file=sys.stderr)
        rows.append({"case": case, "method": f"pytorch_{torch.__version__}_cpu", "size": label, "seconds": s,
                     "unit": "step", "error": None, "error_kind": "", "peer": True, "threads": THREADS})
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump({"rows": stamp(rows, __file__, versions_of(torch))}, f, indent=2)


if __name__ == "__main__":
    main()
