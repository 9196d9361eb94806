"""Reading a `neuspike dataset` folder (see dataset/src/lib.rs): its .npy shards and samples.csv."""

import csv
import pathlib
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Split:
    spike: torch.Tensor  # [N, 32, S, S] float16
    events: torch.Tensor  # [N, 32, S, S] float16
    truth: torch.Tensor  # [N, 1, S, S] float32, luminance in [0, 1]
    tfp: np.ndarray  # [N, S, S] luminance
    tfi: np.ndarray
    lum_per_rate: torch.Tensor  # [N] float32
    complex: np.ndarray  # [N] bool
    rows: list[dict]

    def __len__(self) -> int:
        return self.spike.shape[0]

    def to(self, device: torch.device) -> "Split":
        """The tensors on `device` (a GPU holds the whole set: no copy per step)."""
        for name in ("spike", "events", "truth", "lum_per_rate"):
            setattr(self, name, getattr(self, name).to(device))
        return self

    def inputs(self, names: list[str], idx) -> list[torch.Tensor]:
        return [getattr(self, n)[idx].float() for n in names]


def load(folder: pathlib.Path) -> Split:
    """Loads every shard, in order; the representations as float16 to halve the memory."""
    folder = pathlib.Path(folder)
    rows = list(csv.DictReader(open(folder / "samples.csv", newline="")))
    shards = sorted(p for p in folder.iterdir() if p.is_dir())
    if not shards:
        raise SystemExit(f"{folder}: no shards (is it a `neuspike dataset` folder?)")

    def cat(name: str, dtype) -> np.ndarray:
        return np.concatenate([np.load(s / f"{name}.npy").astype(dtype) for s in shards])

    spike, events = cat("spike", np.float16), cat("events", np.float16)
    truth, tfp, tfi = cat("truth", np.float32), cat("tfp", np.float32), cat("tfi", np.float32)
    if not (len(rows) == spike.shape[0] == events.shape[0] == truth.shape[0]):
        raise SystemExit(f"{folder}: samples.csv has {len(rows)} rows, the shards {spike.shape[0]}")
    return Split(
        spike=torch.from_numpy(spike),
        events=torch.from_numpy(events),
        truth=torch.from_numpy(truth)[:, None],
        tfp=tfp,
        tfi=tfi,
        lum_per_rate=torch.tensor([float(r["lum_per_rate"]) for r in rows], dtype=torch.float32),
        complex=np.array([r["complex"] == "1" for r in rows]),
        rows=rows,
    )


def load_all(folders: list[pathlib.Path]) -> Split:
    """Every folder's samples, one after another (the sets must share their crop size)."""
    splits = [load(f) for f in folders]
    if len(splits) == 1:
        return splits[0]
    sizes = {s.spike.shape[1:] for s in splits}
    if len(sizes) != 1:
        raise SystemExit(f"{', '.join(map(str, folders))}: samples of different shapes {sorted(sizes)}")
    return Split(
        spike=torch.cat([s.spike for s in splits]),
        events=torch.cat([s.events for s in splits]),
        truth=torch.cat([s.truth for s in splits]),
        tfp=np.concatenate([s.tfp for s in splits]),
        tfi=np.concatenate([s.tfi for s in splits]),
        lum_per_rate=torch.cat([s.lum_per_rate for s in splits]),
        complex=np.concatenate([s.complex for s in splits]),
        rows=[r for s in splits for r in s.rows],
    )


def camera_of(folder: pathlib.Path) -> str:
    """The spike camera a set was made with, from its `dataset.yml`: `random` (made with
    `--randomise-camera`), `profile <name>` for a profile other than the paper's, else `paper`."""
    path = pathlib.Path(folder) / "dataset.yml"
    line = next((l for l in path.read_text().splitlines() if l.startswith("camera:")), "") if path.exists() else ""
    value = line.removeprefix("camera:").strip().strip('"')
    if value.startswith("randomised"):
        return "random"
    if value.startswith("profile ") and not value.startswith("profile paper"):
        return value.split(":")[0]
    return "paper"


def psnr(x: np.ndarray, y: np.ndarray) -> float:
    """docs/definitions.md: data range 1, MSE over the frame; identical frames give +inf."""
    mse = float(np.mean((x.astype(np.float64) - y.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1.0 / mse)


def ssim(x: np.ndarray, y: np.ndarray) -> float:
    """docs/definitions.md: Gaussian 11x11 window, sigma 1.5, population covariance, data range 1 (the
    sink's definition; scikit-image computes it with these settings)."""
    from skimage.metrics import structural_similarity

    return float(
        structural_similarity(
            x.astype(np.float64),
            y.astype(np.float64),
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
            data_range=1.0,
        )
    )
