#!/usr/bin/env bash
# Soak: the live spike graph for 10 minutes of a 20 kHz camera on its own clock (200 TFP frames/s,
# one PNG in 10 written, every frame counted; `--fps 1000` for the graph at its 2-core limit). Samples each process's resident memory every second
# (out/soak/rss.csv) and fails unless memory stays flat (the last minute within 5% of the second
# second), no frame is lost, and latency p99 does not grow (the last minute within 1.25x the
# minutes' median + 1 ms). Extra arguments go to `neuspike bench-live` (e.g. --seconds 60).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --workspace --bins
exec target/release/neuspike bench-live --no-build --soak --seconds 600 --rate-hz 20000 --fps 200 \
  --out out/soak "$@"
