"""Photographic textures for `neuspike dataset --textures`, from the photos scikit-image ships in
its wheel (public domain or CC0; see skimage/data/README). Each photo is turned to grey (ITU-R
601 luma) and cut into `--crops` random crops of random scale, written as 8-bit PNGs named
`<photo>-<k>.png`. Train and test use different photos, so they never share a texture.

    python training/prepare_textures.py --out data/textures
writes data/textures/train/*.png and data/textures/test/*.png.
"""

import argparse
import pathlib

import numpy as np
import skimage.data
import skimage.io
import skimage.transform

# `cat` is the same photograph as `chelsea`, so it is left out.
TRAIN = [
    "astronaut", "brick", "camera", "cell", "clock", "coffee", "grass", "hubble_deep_field",
    "immunohistochemistry", "moon", "page", "retina", "text",
]
TEST = ["chelsea", "coins", "gravel", "rocket"]


def grey(img: np.ndarray) -> np.ndarray:
    """Luma in [0, 1]."""
    img = img.astype(np.float64)
    if img.ndim == 3:
        img = img[..., :3] @ np.array([0.299, 0.587, 0.114])
    return img / 255.0


def crops(img: np.ndarray, n: int, side: int, rng: np.random.Generator):
    """`n` crops of `side` pixels, each after a random rescale in [0.5, 1.5]."""
    for _ in range(n):
        s = rng.uniform(0.5, 1.5)
        s = max(s, (side + 1) / min(img.shape))
        scaled = skimage.transform.rescale(img, s, anti_aliasing=s < 1, preserve_range=True)
        y = rng.integers(0, scaled.shape[0] - side + 1)
        x = rng.integers(0, scaled.shape[1] - side + 1)
        yield scaled[y : y + side, x : x + side]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=pathlib.Path, required=True)
    ap.add_argument("--crops", type=int, default=12)
    ap.add_argument("--side", type=int, default=160)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    for split, names in (("train", TRAIN), ("test", TEST)):
        folder = args.out / split
        folder.mkdir(parents=True, exist_ok=True)
        for name in names:
            img = grey(getattr(skimage.data, name)())
            for k, c in enumerate(crops(img, args.crops, args.side, rng)):
                png = np.clip(np.round(c * 255), 0, 255).astype(np.uint8)
                skimage.io.imsave(folder / f"{name}-{k:02}.png", png, check_contrast=False)
        print(f"{folder}: {len(names)} photos x {args.crops} crops")


if __name__ == "__main__":
    main()
