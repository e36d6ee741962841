#!/usr/bin/env bash
# The stand-in WeatherBench experiment (issue 18's acceptance): generate the truth (4 years:
# 2 train, 1 valid, 1 test) and a biased climate-model run (10 years), then train the CPU-sized
# ResNet four ways and score everything on the test year:
#   pretrain   on the climate run                         (the paper's CMIP pretraining)
#   finetune   from pretrain, on the last half year of truth training data, lr / 10
#   short      from scratch on the same half year          (fine-tune-only baseline)
#   full       from scratch on both truth training years   (compared with linear regression)
# plus the same comparison at an equal fine-tuning budget and with a 0.1-year record.
# Usage: bench/weather_experiment.sh [SEED]   (outputs under target/pbdl/weather/seed<SEED>/)
set -euo pipefail
cd "$(dirname "$0")/.."
seed="${1:-0}"
out="target/pbdl/weather/seed$seed"
x=target/release/xtask
cargo build --release -p xtask --quiet
[ -f "$out/data/climate_t.nc" ] || $x weather generate --out "$out/data" --truth-years 4 --climate-years 10 --seed "$seed"
common=(--data "$out/data" --seed "$seed" --width 32 --blocks 4)
$x weather train "${common[@]}" --out "$out/pretrain" --source climate --epochs 6 --steps-per-epoch 100 --lr 1e-3
$x weather train "${common[@]}" --out "$out/finetune" --source truth --truth-train-years 0.5 --init "$out/pretrain" --epochs 6 --steps-per-epoch 50 --lr 1e-4
$x weather train "${common[@]}" --out "$out/short" --source truth --truth-train-years 0.5 --epochs 10 --steps-per-epoch 50 --lr 1e-3
# Equal fine-tuning budget: the pretrained weights under the scratch run's recipe (lr 1e-3, 10 x 50 updates).
$x weather train "${common[@]}" --out "$out/finetune_equal" --source truth --truth-train-years 0.5 --init "$out/pretrain" --epochs 10 --steps-per-epoch 50 --lr 1e-3
# A shorter record (0.1 year, about 36 days): scratch and pretrained, same recipe.
$x weather train "${common[@]}" --out "$out/short_0.1y" --source truth --truth-train-years 0.1 --epochs 10 --steps-per-epoch 50 --lr 1e-3
$x weather train "${common[@]}" --out "$out/finetune_0.1y" --source truth --truth-train-years 0.1 --init "$out/pretrain" --epochs 10 --steps-per-epoch 50 --lr 1e-3
# Both truth training years until early stopping or 20 epochs.
$x weather train "${common[@]}" --out "$out/full" --source truth --epochs 20 --steps-per-epoch 100 --lr 1e-3
runs=()
for r in pretrain finetune short finetune_equal short_0.1y finetune_0.1y full; do runs+=(--run "$out/$r"); done
$x weather eval --data "$out/data" --out "$out/eval" "${runs[@]}"
