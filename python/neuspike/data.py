"""Simulated training data for PyTorch: :class:`neuspike.Samples` as a map-style ``Dataset`` and
as an ``IterableDataset``.

Both work without torch too (numpy arrays, plain Python objects); with torch installed they are
torch datasets whose items are tensors sharing the arrays' memory. Each sample is deterministic
in its index and the set's seed, in any worker, forked or spawned::

    from torch.utils.data import DataLoader
    import neuspike as ns
    from neuspike.data import SampleDataset

    samples = ns.Samples(size=64, seed=0)          # neuspike dataset's options, cameras drawn
    loader = DataLoader(SampleDataset(samples), batch_size=16, shuffle=True, num_workers=2)
    for batch in loader:
        spike, events, truth = batch["spike"], batch["events"], batch["truth"]
"""

import random

try:
    import torch
    from torch.utils.data import Dataset as _Dataset
    from torch.utils.data import IterableDataset as _IterableDataset
    from torch.utils.data import get_worker_info as _worker_info
except ImportError:  # numpy only
    torch = None
    _Dataset = object
    _IterableDataset = object

    def _worker_info():
        return None


__all__ = ["ARRAYS", "SampleDataset", "SampleStream"]

#: The arrays of a sample, as tensors under torch.
ARRAYS = ("spike", "events", "truth", "tfp", "tfi")


def _as_tensors(sample):
    """A sample's arrays as tensors sharing their memory (as they are without torch)."""
    if torch is None:
        return sample
    out = dict(sample)
    for k in ARRAYS:
        out[k] = torch.from_numpy(out[k])
    out["also"] = {k: torch.from_numpy(v) for k, v in sample["also"].items()}
    return out


class SampleDataset(_Dataset):
    """Sample ``i`` of a :class:`neuspike.Samples`, made when asked for (map-style)."""

    def __init__(self, samples):
        self.samples = samples

    def __len__(self):
        return len(self.samples)

    def __getitem__(self, i):
        return _as_tensors(self.samples[i])


class SampleStream(_IterableDataset):
    """The samples of a :class:`neuspike.Samples` in batches of ``batch_size`` made side by side
    on the package's threads, each epoch in an order drawn from ``seed`` and the epoch (set it
    with :meth:`set_epoch`), shared out between a ``DataLoader``'s workers without overlap.
    Use it with ``DataLoader(stream, batch_size=None)``: its items are batches already."""

    def __init__(self, samples, batch_size=16, *, shuffle=True, seed=0, drop_last=False):
        if batch_size < 1:
            raise ValueError(f"batch_size = {batch_size}: must be at least 1")
        self.samples = samples
        self.batch_size = batch_size
        self.shuffle = shuffle
        self.seed = seed
        self.drop_last = drop_last
        self.epoch = 0

    def set_epoch(self, epoch):
        """The epoch whose order the next iteration takes."""
        self.epoch = epoch

    def order(self):
        """This epoch's order of the sample indices."""
        idx = list(range(len(self.samples)))
        if self.shuffle:
            random.Random(self.seed * 1_000_003 + self.epoch).shuffle(idx)
        return idx

    def batches(self):
        """The epoch's batches of indices (all of them, before sharing between workers)."""
        idx = self.order()
        out = [idx[i : i + self.batch_size] for i in range(0, len(idx), self.batch_size)]
        if self.drop_last and out and len(out[-1]) < self.batch_size:
            out.pop()
        return out

    def __len__(self):
        return len(self.batches())

    def __iter__(self):
        info = _worker_info()
        mine = self.batches()
        if info is not None:
            mine = mine[info.id :: info.num_workers]
        for b in mine:
            yield _as_tensors(self.samples.batch(b))
