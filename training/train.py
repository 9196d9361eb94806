"""Trains NeuSpike-Net on a `neuspike dataset` training set (CPU, or CUDA when present).

    python training/train.py --train data/train --base 8 --mode fused --steps 6000 \
        --out runs/fused-8.pt

Loss: the prediction is a firing rate; it is compared as luminance (`rate * lum_per_rate`, the
sample's calibration) with the ground truth, by L2 plus an auxiliary term standing in for the
paper's VGG perceptual loss (no pretrained weights can be downloaded here): `ssim` (1 - SSIM,
REFERENCE.md's window), `grad` (L1 between image gradients) or `none`. Augmentation: the 8 flips
and quarter turns, the same for every input and the target. Everything is seeded; the step count,
not the wall clock, ends training, so a run repeats (on a CPU; CUDA kernels are not bit-exact).

`--init FILE` starts from the weights of a checkpoint (`.pt`) or an exported network (`.onnx`, its
initializers by parameter name) of the same architecture, to fine-tune it (e.g. on larger crops).
With `--init-partial` the architecture may differ: every tensor of the same name and shape is
taken, the others keep their initial values and are named (a `--features half` network started
from a `full` one's deeper layers).

`--fresh 'size=64 seed=5 per_cell=4000'` trains on samples made on demand instead of `--train`
sets: `neuspike.Samples` with those `neuspike dataset` options (the camera drawn per sample), in
`--workers` DataLoader workers, each step's batch new until the set's 25 x per_cell samples are
used up. It pays where a GPU trains and the CPU cores would wait; on 2 CPU cores, which the
network's steps need, reading a written set is faster (docs/python.md).

`--val DIR` (a set made like the training set with another `--seed`, never the held-out set)
scores the model every `--val-every` steps and keeps the weights of the best mean PSNR: the
checkpoint is chosen without looking at the held-out set.
"""

import argparse
import json
import pathlib
import time

import numpy as np
import torch
import torch.nn.functional as F

import data
from neuspike_net import NeuSpikeNet, parameters


def gaussian_taps(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """REFERENCE.md's SSIM window is the outer product of these normalised 1-D taps."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


class GaussianBlur:
    """The 'valid' 2-D filtering by REFERENCE.md's 11x11 Gaussian window as two banded matrix
    products, `A_rows @ X @ A_cols^T` with `A[r, r + i] = g_i`: the same sums as `conv2d` with the
    outer-product window (to rounding). On 2 CPU cores oneDNN differentiated the single-channel
    convolution with a generic GEMM: with its forward pass, 52 ms of a 0.39 s base-16 step; the
    products take a few ms. The band matrices are built once per image size."""

    def __init__(self, device: torch.device, size: int = 11, sigma: float = 1.5):
        self.taps, self.device, self.bands = gaussian_taps(size, sigma), device, {}

    def band(self, n: int) -> torch.Tensor:
        if n not in self.bands:
            k = len(self.taps)
            a = torch.zeros(n - k + 1, n, dtype=torch.float64)
            for r in range(n - k + 1):
                a[r, r : r + k] = self.taps
            self.bands[n] = a.float().to(self.device)
        return self.bands[n]

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """`[..., H, W]` -> `[..., H - 10, W - 10]`."""
        return self.band(x.shape[-2]) @ x @ self.band(x.shape[-1]).T


def ssim_loss(x: torch.Tensor, y: torch.Tensor, blur: GaussianBlur) -> torch.Tensor:
    """1 - mean SSIM over the valid windows (REFERENCE.md: Gaussian 11x11, sigma 1.5, L = 1)."""
    c1, c2 = 0.01**2, 0.03**2
    mu_x, mu_y, xx, yy, xy = blur(torch.stack([x, y, x * x, y * y, x * y]))
    sxx = xx - mu_x**2
    syy = yy - mu_y**2
    sxy = xy - mu_x * mu_y
    s = ((2 * mu_x * mu_y + c1) * (2 * sxy + c2)) / ((mu_x**2 + mu_y**2 + c1) * (sxx + syy + c2))
    return 1 - s.mean()


def grad_loss(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    dx = lambda t: t[..., :, 1:] - t[..., :, :-1]  # noqa: E731
    dy = lambda t: t[..., 1:, :] - t[..., :-1, :]  # noqa: E731
    return (dx(x) - dx(y)).abs().mean() + (dy(x) - dy(y)).abs().mean()


def augment(tensors: list[torch.Tensor], k: int) -> list[torch.Tensor]:
    """One of the 8 symmetries of the square, the same for all."""
    out = [torch.rot90(t, k % 4, dims=(-2, -1)) for t in tensors]
    return [t.flip(-1) for t in out] if k >= 4 else out


def l2_loss(lum: torch.Tensor, truth: torch.Tensor, how: str) -> torch.Tensor:
    """L2 between prediction and truth. `mean`: over every pixel of the batch. `psnr`: each
    sample's MSE weighted by 1 / (its MSE + 1e-6), the weights (not differentiated) normalised to
    sum 1. Its gradient is that of the mean of the samples' log MSE, i.e. of the mean PSNR we score
    by, scaled to plain L2's size, so the auxiliary term keeps its weight. Without it, the
    darkest, noisiest samples dominate the batch's MSE and a bright sample's small gain error
    (a large PSNR loss) barely counts. The 1e-6 (60 dB) bounds the weight of a perfect sample."""
    if how == "mean":
        return F.mse_loss(lum, truth)
    mse = ((lum - truth) ** 2).mean(dim=(1, 2, 3))
    w = 1.0 / (mse.detach() + 1e-6)
    return (w * mse).sum() / w.sum()


@torch.no_grad()
def validation_psnr(model: NeuSpikeNet, val: data.Split, batch: int = 50) -> float:
    """Mean per-sample PSNR on `val` (luminance clipped to [0, 1], REFERENCE.md's definition; a
    perfect frame counts 120 dB instead of +inf, so one cannot swamp the mean)."""
    model.eval()
    total = 0.0
    for i in range(0, len(val), batch):
        idx = torch.arange(i, min(i + batch, len(val)), device=val.truth.device)
        lum = (model(*val.inputs(model.inputs(), idx)) * model.gain(val.lum_per_rate[idx])).clamp(0, 1)
        mse = ((lum - val.truth[idx]) ** 2).mean(dim=(1, 2, 3)).double()
        total += float((10 * torch.log10(1.0 / mse.clamp_min(1e-12))).sum())
    model.train()
    return total / len(val)


def initial_weights(path: pathlib.Path, model: NeuSpikeNet, partial: bool = False) -> dict[str, torch.Tensor]:
    """The weights of `path` (`.pt` checkpoint or `.onnx` export) for every tensor of `model`'s
    state; a shape that differs, or a missing tensor, is an error naming it. An export holds only
    what its forward pass reads (the deepest fusion's spatial attention is never used): a tensor
    missing from an `.onnx` keeps its initial value, and is named, unless none matched at all.
    `partial`: a missing tensor or one of another shape keeps its initial value too (named)."""
    if path.suffix == ".onnx":
        import onnx
        from onnx import numpy_helper

        graph = onnx.load(str(path)).graph
        found = {i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in graph.initializer}
    else:
        found = torch.load(path, map_location="cpu", weights_only=True)["state"]
    state, kept = {}, []
    for name, want in model.state_dict().items():
        got = found.get(name)
        if (got is None and (partial or path.suffix == ".onnx")) or (
            partial and got is not None and tuple(got.shape) != tuple(want.shape)
        ):
            kept.append(name)
            state[name] = want
            continue
        if got is None:
            raise SystemExit(f"--init {path}: no tensor `{name}` (another architecture?)")
        if tuple(got.shape) != tuple(want.shape):
            raise SystemExit(f"--init {path}: `{name}` is {tuple(got.shape)}, the model's {tuple(want.shape)}")
        state[name] = got.to(want.dtype)
    if len(kept) == len(state):
        raise SystemExit(f"--init {path}: none of the model's tensors is there (another architecture?)")
    if kept:
        why = "not there or of another shape" if partial else "not in the export (unused by the forward pass)"
        print(f"--init {path}: {why}, kept as initialised: {', '.join(kept)}")
    return state


class FreshBatches:
    """Batches of samples made on demand (`--fresh`): neuspike.Samples through a DataLoader's
    workers, one epoch after another, each epoch in a new order."""

    def __init__(self, samples, batch: int, seed: int, workers: int):
        from torch.utils.data import DataLoader

        from neuspike.data import SampleStream

        self.samples = samples
        self.channels = samples.channels
        self.camera = "random" if samples.randomise_camera else "paper"
        self.stream = SampleStream(samples, batch_size=batch, seed=seed, drop_last=True)
        self.loader = DataLoader(self.stream, batch_size=None, num_workers=workers,
                                 persistent_workers=workers > 0)
        self.epoch, self.it = 0, iter(self.loader)

    def next(self) -> dict:
        try:
            return next(self.it)
        except StopIteration:
            self.epoch += 1
            self.stream.set_epoch(self.epoch)
            self.it = iter(self.loader)
            return next(self.it)


def fresh_batches(args) -> FreshBatches:
    import neuspike

    if not getattr(neuspike, "NATIVE", False):
        raise SystemExit("--fresh needs neuspike's Python package with its native module: pip install ./python")
    options = {}
    for word in args.fresh.split():
        key, sep, value = word.partition("=")
        if not sep:
            raise SystemExit(f"--fresh: {word!r} is not key=value")
        options[key] = int(value) if value.lstrip("-").isdigit() else value
    try:
        samples = neuspike.Samples(**options)
    except neuspike.Error as e:
        raise SystemExit(f"--fresh: {e}")
    return FreshBatches(samples, args.batch, args.seed, args.workers)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    source = ap.add_mutually_exclusive_group(required=True)
    source.add_argument("--train", type=pathlib.Path, nargs="+", help="one or more sets, mixed")
    source.add_argument(
        "--fresh",
        metavar="OPTIONS",
        help="samples made on demand by neuspike.Samples: neuspike dataset's options as key=value "
        "words, e.g. 'size=64 seed=5 per_cell=4000'",
    )
    ap.add_argument("--workers", type=int, default=2, help="DataLoader workers making --fresh samples")
    ap.add_argument("--base", type=int, default=16)
    ap.add_argument("--mode", default="fused", choices=["fused", "spike", "event"])
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument(
        "--l2",
        default="mean",
        choices=["mean", "psnr"],
        help="mean: plain L2 over the batch; psnr: each sample's L2 weighted by 1 / its MSE (the "
        "gradient of the batch's mean PSNR, at plain L2's scale)",
    )
    ap.add_argument("--aux", default="ssim", choices=["ssim", "grad", "none"])
    ap.add_argument("--aux-weight", type=float, default=0.1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--gated",
        action="store_true",
        help="fused: the motion path enters each fusion through a per-channel weight that starts at 0",
    )
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: all cores)")
    ap.add_argument(
        "--val", type=pathlib.Path, nargs="+", help="validation sets: keep the best checkpoint on their mean PSNR"
    )
    ap.add_argument("--val-every", type=int, default=500)
    ap.add_argument("--init", type=pathlib.Path, help="start from these weights (.pt or .onnx)")
    ap.add_argument(
        "--init-partial",
        action="store_true",
        help="--init from another architecture: take the tensors of the same name and shape",
    )
    ap.add_argument(
        "--features",
        default="full",
        choices=["full", "half"],
        help="the finest scale computed: full resolution (the paper's) or half (the -lite networks)",
    )
    ap.add_argument("--out", type=pathlib.Path, required=True)
    args = ap.parse_args()
    if args.gated and args.mode != "fused":
        ap.error(f"--gated weighs the motion path of a fused network; mode {args.mode} has one path")

    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if args.fresh:
        train, batches = None, fresh_batches(args)
        channels = batches.channels
    else:
        train, batches = data.load_all(args.train).to(device), None
        channels = train.spike.shape[1]
    model = NeuSpikeNet(
        base=args.base, channels=channels, mode=args.mode, gated=args.gated, features=args.features
    ).to(device)
    if args.init:
        model.load_state_dict(initial_weights(args.init, model, args.init_partial))
    names = model.inputs()
    opt = torch.optim.Adam(model.parameters(), lr=args.lr)
    # The warm-up is 5% of the steps, and at least 2 (OneCycleLR divides by its phases' lengths).
    if args.steps < 4:
        ap.error(f"--steps {args.steps}: at least 4")
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=args.lr, total_steps=args.steps, pct_start=max(0.05, 2 / args.steps)
    )
    blur = GaussianBlur(device)
    n_train = len(batches.samples) if batches else len(train)
    print(
        f"{args.mode} base {args.base}: {parameters(model):,} parameters, {n_train} samples, "
        f"{args.steps} steps of {args.batch} on {device} ({torch.get_num_threads()} threads)"
    )
    val = data.load_all(args.val).to(device) if args.val else None
    best = (-float("inf"), 0, None)  # (mean PSNR, step, weights)
    start, log_every, running = time.monotonic(), max(args.steps // 40, 1), 0.0
    model.train()
    for step in range(args.steps):
        if batches:
            b = batches.next()
            gain = model.gain(b["lum_per_rate"].float().to(device))
            got = [b[n].to(device) for n in names] + [b["truth"][:, None].to(device)]
        else:
            idx = torch.from_numpy(rng.integers(0, len(train), args.batch)).to(device)
            gain = model.gain(train.lum_per_rate[idx])
            got = [*(getattr(train, n)[idx] for n in names), train.truth[idx]]
        # Turned while still float16 (half the bytes to move), then converted once.
        *xs, truth = augment(got, int(rng.integers(0, 8)))
        xs = [x.float() for x in xs]
        lum = model(*xs) * gain
        loss = l2_loss(lum, truth, args.l2)
        if args.aux == "ssim":
            loss = loss + args.aux_weight * ssim_loss(lum.clamp(0, 1), truth, blur)
        elif args.aux == "grad":
            loss = loss + args.aux_weight * grad_loss(lum, truth)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        running += loss.item()
        if (step + 1) % log_every == 0:
            print(f"step {step + 1:6d}  loss {running / log_every:.5f}  {time.monotonic() - start:7.1f} s", flush=True)
            running = 0.0
        if val is not None and ((step + 1) % args.val_every == 0 or step + 1 == args.steps):
            score = validation_psnr(model, val)
            if score > best[0]:
                best = (score, step + 1, {k: v.detach().clone() for k, v in model.state_dict().items()})
            print(f"step {step + 1:6d}  validation PSNR {score:.2f} dB (best {best[0]:.2f} at {best[1]})", flush=True)
    seconds = time.monotonic() - start
    if best[2] is not None:
        model.load_state_dict(best[2])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    config = {
        "base": args.base,
        "mode": args.mode,
        "gated": args.gated,
        "features": args.features,
        "channels": int(channels),
        "steps": args.steps,
        "batch": args.batch,
        "lr": args.lr,
        "l2": args.l2,
        "aux": args.aux,
        "aux_weight": args.aux_weight,
        "seed": args.seed,
        "train": f"fresh: {args.fresh}" if args.fresh else " ".join(map(str, args.train)),
        "train_samples": n_train,
        **({"init": str(args.init)} if args.init else {}),
        "camera": batches.camera if batches else " ".join(sorted({data.camera_of(t) for t in args.train})),
        "parameters": parameters(model),
        "train_seconds": round(seconds, 1),
        # CPU time of every thread: on a machine shared with builds, the wall clock overstates.
        "cpu_seconds": round(time.process_time(), 1),
        "device": str(device) if device.type == "cuda" else f"cpu x{torch.get_num_threads()}",
        **({"val": " ".join(map(str, args.val)), "val_samples": len(val), "best_step": best[1],
            "best_val_psnr": round(best[0], 3)} if val is not None else {}),
        "torch": str(torch.__version__),
    }
    torch.save({"config": config, "state": model.state_dict()}, args.out)
    print(json.dumps(config))


if __name__ == "__main__":
    main()
