"""NeuSpike-Net (Zhang et al., ICCV 2021, Sec. 3.3): a two-path network that fuses the spike
camera's texture with the event camera's motion.

- Two encoder paths of identical structure: the *texture* path reads the spike representation
  (1 ISI channel + 31 raw planes), the *motion* path the event integration (32 channels, Eq. 8).
  Each is a head convolution to `base` channels, then `N_e = 3` stride-2 layers doubling the
  channels.
- A feature fusion module after each encoder layer (Eq. 11-12): channel attention on each path's
  features, their sum; the skip connection it hands the decoder is that sum weighted by a spatial
  attention map computed on (sum + the decoder's feature at that scale).
- `N_r = 2` residual blocks on the deepest fused feature, `N_d = 3` decoder layers (transposed
  convolutions) each taking its scale's skip connection, then a depthwise convolution, a 1x1
  convolution and a sigmoid.

The output of a model that reads spikes is the spike camera's firing rate (spikes per tick, in
[0, 1]), not luminance: the rate is what the inputs can tell, and `luminance = rate * phi /
light_scale` is the camera's calibration, applied by the infer node (`lum_per_rate`) exactly as for
TFP. Events carry no absolute level (only log-intensity changes, whatever the light), so the
event-only model cannot know that calibration: it predicts luminance itself. `output` names which
(`rate` or `luminance`); the ONNX output carries that name and the infer node reads it. Inputs need
heights and widths that are multiples of 8 (`STRIDE`); the infer node pads.

`mode` builds the paper's Table 2 ablations with the same blocks: `fused` (both paths),
`spike` (texture path alone) and `event` (motion path alone).

`features` is the finest scale the decoder computes at. `full` is the paper's. `half` (the
`-lite` networks, for a live camera) stops the decoder at half resolution: its last feature gives
each pixel of the 2x2 block below a point (a 3x3 convolution to 4 channels and a sub-pixel
shuffle: `PixelShuffle`, ONNX `DepthToSpace`), and the full-resolution detail comes from a 1x1
convolution of each path's head feature, added before the sigmoid. The paper's layout spent about
30% of its time in the full-resolution decoder and its skip; a `half` network with no head at all
(the first encoder layer reading the input at stride 2) lost 2.6 dB on the held-out set's normal
scenes.
"""

import torch
import torch.nn.functional as F
from torch import nn

STRIDE = 8
ENCODER_LAYERS = 3
RESIDUAL_BLOCKS = 2
MODES = ("fused", "spike", "event")
FEATURES = ("full", "half")


class ChannelAttention(nn.Module):
    """Squeeze and excitation: global mean, bottleneck, sigmoid gate per channel."""

    def __init__(self, channels: int, reduction: int = 4):
        super().__init__()
        hidden = max(channels // reduction, 4)
        self.gate = nn.Sequential(
            nn.AdaptiveAvgPool2d(1),
            nn.Conv2d(channels, hidden, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(hidden, channels, 1),
            nn.Sigmoid(),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.gate(x)


class SpatialAttention(nn.Module):
    """A sigmoid map from the channel mean and max of its input (7x7 convolution)."""

    def __init__(self):
        super().__init__()
        self.conv = nn.Conv2d(2, 1, 7, padding=3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        mean = x.mean(dim=1, keepdim=True)
        peak = x.amax(dim=1, keepdim=True)
        return torch.sigmoid(self.conv(torch.cat([mean, peak], dim=1)))


class Fusion(nn.Module):
    """Eq. 11-12: CA on each path, summed; the skip is the sum times SA(sum + decoder feature).

    `gated` scales each path after the first by a learned per-channel weight that starts at 0
    (as ReZero starts its residual branches): the network starts as the texture path alone and
    lets the motion path in as far as training finds it helps. Ungated, both paths weigh 1."""

    def __init__(self, channels: int, paths: int, gated: bool = False):
        super().__init__()
        self.ca = nn.ModuleList(ChannelAttention(channels) for _ in range(paths))
        self.sa = SpatialAttention()
        self.gates = (
            nn.ParameterList(nn.Parameter(torch.zeros(1, channels, 1, 1)) for _ in range(paths - 1))
            if gated
            else None
        )

    def fuse(self, feats: list[torch.Tensor]) -> torch.Tensor:
        out = self.ca[0](feats[0])
        for i, (ca, f) in enumerate(zip(self.ca[1:], feats[1:])):
            term = ca(f)
            out = out + (term * self.gates[i] if self.gates is not None else term)
        return out

    def skip(self, fused: torch.Tensor, decoder: torch.Tensor) -> torch.Tensor:
        return fused * self.sa(fused + decoder)


def conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1), nn.ReLU(inplace=True))


class Encoder(nn.Module):
    """Head convolution, then `ENCODER_LAYERS` stride-2 layers doubling the channels."""

    def __init__(self, cin: int, base: int):
        super().__init__()
        self.head = conv(cin, base)
        self.layers = nn.ModuleList(
            nn.Sequential(conv(base << i, base << (i + 1), stride=2), conv(base << (i + 1), base << (i + 1)))
            for i in range(ENCODER_LAYERS)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The feature at each scale, finest first."""
        x = self.head(x)
        out = [x]
        for layer in self.layers:
            x = layer(x)
            out.append(x)
        return out


class Residual(nn.Module):
    def __init__(self, channels: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(channels, channels, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(channels, channels, 3, padding=1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.relu(x + self.body(x))


class NeuSpikeNet(nn.Module):
    """`forward(spike, events)` -> firing rate (or, event-only, luminance) `[B, 1, H, W]`; an
    ablation ignores the input it does not use (it is not even an input of its ONNX export)."""

    def __init__(
        self,
        base: int = 16,
        channels: int = 32,
        mode: str = "fused",
        gated: bool = False,
        features: str = "full",
    ):
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
        if features not in FEATURES:
            raise ValueError(f"features must be one of {FEATURES}, not {features!r}")
        self.mode, self.base, self.channels, self.gated = mode, base, channels, gated
        self.features = features
        self.output = "luminance" if mode == "event" else "rate"
        # The finest scale the decoder computes: 0 (full resolution) or 1 (half).
        self.first = 0 if features == "full" else 1
        paths = 2 if mode == "fused" else 1
        self.encoders = nn.ModuleList(Encoder(channels, base) for _ in range(paths))
        # One fusion module per scale the decoder takes a skip at (the finest included), keyed
        # by scale so that a `half` network's modules have the names of the `full` one's.
        self.fusions = nn.ModuleDict(
            {str(i): Fusion(base << i, paths, gated) for i in range(self.first, ENCODER_LAYERS + 1)}
        )
        deep = base << ENCODER_LAYERS
        self.residual = nn.Sequential(*(Residual(deep) for _ in range(RESIDUAL_BLOCKS)))
        self.up = nn.ModuleList(
            nn.Sequential(nn.ConvTranspose2d(base << (i + 1), base << i, 2, stride=2), nn.ReLU(inplace=True))
            for i in reversed(range(self.first, ENCODER_LAYERS))
        )
        self.merge = nn.ModuleList(
            conv(2 * (base << i), base << i) for i in reversed(range(self.first, ENCODER_LAYERS))
        )
        if self.first == 0:
            self.depthwise = nn.Conv2d(base, base, 3, padding=1, groups=base)
            self.out = nn.Conv2d(base, 1, 1)
        else:
            # Each of the 4 outputs is one pixel of the 2x2 block below its half-resolution point;
            # each path's head adds its full-resolution detail.
            self.depthwise = None
            self.out = nn.Conv2d(base << 1, 4, 3, padding=1)
            self.detail = nn.ModuleList(nn.Conv2d(base, 1, 1) for _ in range(paths))
            for d in self.detail:
                nn.init.zeros_(d.bias)
        # A rate starts dim (0.02 a tick): a dark sample's calibration multiplies the rate by up
        # to 20, and starting at 0.5 sent its first gradients so far that the sigmoid saturated
        # at 0. Luminance has no gain and starts at mid-grey.
        nn.init.constant_(self.out.bias, -4.0 if self.output == "rate" else 0.0)

    def gain(self, lum_per_rate: torch.Tensor) -> torch.Tensor:
        """What turns the output into luminance, per sample `[B, 1, 1, 1]`."""
        g = lum_per_rate if self.output == "rate" else torch.ones_like(lum_per_rate)
        return g[:, None, None, None]

    def inputs(self) -> list[str]:
        return {"fused": ["spike", "events"], "spike": ["spike"], "event": ["events"]}[self.mode]

    def forward(self, *xs: torch.Tensor) -> torch.Tensor:
        feats = [enc(x) for enc, x in zip(self.encoders, xs)]
        # feats[p][s]: path p's feature at scale s (0: full resolution).
        fused = {int(s): f.fuse([p[int(s)] for p in feats]) for s, f in self.fusions.items()}
        x = self.residual(fused[ENCODER_LAYERS])
        for k, (up, merge) in enumerate(zip(self.up, self.merge)):
            scale = ENCODER_LAYERS - 1 - k
            x = up(x)
            skip = self.fusions[str(scale)].skip(fused[scale], x)
            x = merge(torch.cat([x, skip], dim=1))
        if self.depthwise is None:
            logit = F.pixel_shuffle(self.out(x), 2)
            for d, p in zip(self.detail, feats):
                logit = logit + d(p[0])
            return torch.sigmoid(logit)
        return torch.sigmoid(self.out(self.depthwise(x)))


def parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
