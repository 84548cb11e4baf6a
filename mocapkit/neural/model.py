"""The motion autoencoder of BRA / BRA-P (Li et al. 2020, seed 002, Sec. III.B, Fig. 5).

Encoder, eq. (1)::

    H = E(X) = BiLSTM_1(W3 (W2 (W1 X + b1) + b2) + b3)      X (B, f, m) -> H (B, f, h)

Decoder, eq. (2)::

    Y = D(H) = W6 (W5 (W4 BiLSTM_2(H) + b4) + b5) + b6        H (B, f, h) -> Y (B, f, n)

The fully connected layers have the widths m -> h/4 -> h/2 -> h and h -> h/2 -> h/4 -> n
(128, 256, 512 for the paper's h = 512) and, as in eqs. (1)-(2), no activation between
them. Each BiLSTM has h/2 units per direction, their outputs concatenated (f x h, the
"120 x 512" of the paper). Dropout (0.2 in the paper, "dropout wrapper on Bi-LSTM layer")
is applied to each BiLSTM's output during training. ``m`` (input channels) and ``n``
(output channels) may differ: the different-topology case (Kinect 25 joints -> mocap 59
joints in the paper).

``wide=True`` (issue 20) makes every fully connected layer ``hidden`` wide: with no
activation between them the paper's m -> h/4 -> h/2 -> h stack is one linear map of rank
h/4, which for a residual network with the low-pass, high-pass and mask channels (m = 147
for 21 joints) would drop most of its input.

Residual form (``residual=True``, decision of issue 20, measured in docs/results/bra.md):
``Y = X[..., :n] + D(E(X))``: the network predicts a *correction* of its input (the
first ``n`` input channels must be the output channels in the same normalisation, the
same-topology case; extra input channels, e.g. the observation mask, follow them). The
last linear layer starts at zero, so an untrained residual network is the identity. The
paper's absolute form (``residual=False``) has to rebuild every coordinate through the
LSTMs; undertrained on a CPU it returned ~5 cm error whatever the input (issue 20).

torch is imported lazily (:func:`build`), so this module imports without it.
"""
from __future__ import annotations

from typing import Any

from . import require_torch


def build(m: int, n: int, hidden: int = 512, dropout: float = 0.2, residual: bool = False,
          wide: bool = False) -> Any:
    """A new :class:`MotionAutoencoder` (m input channels, n output channels)."""
    require_torch()
    return _classes()["MotionAutoencoder"](m, n, hidden, dropout, residual, wide)


_CACHE: dict[str, type] = {}


def _classes() -> dict[str, type]:
    if _CACHE:
        return _CACHE
    torch = require_torch()
    nn = torch.nn

    class MotionAutoencoder(nn.Module):
        """Eqs. (1)-(2). ``forward(x)`` returns (Y, H); shapes (B, f, n) and (B, f, hidden)."""

        def __init__(self, m: int, n: int, hidden: int = 512, dropout: float = 0.2, residual: bool = False,
                     wide: bool = False):
            super().__init__()
            if hidden % 4 or hidden < 4:
                raise ValueError(f"hidden must be a positive multiple of 4, got {hidden}")
            if residual and m < n:
                raise ValueError(f"a residual network needs m >= n input channels, got m={m}, n={n}")
            self.m, self.n, self.hidden, self.dropout_p = int(m), int(n), int(hidden), float(dropout)
            self.residual = bool(residual)
            self.wide = bool(wide)
            h1, h2 = (hidden, hidden) if wide else (hidden // 4, hidden // 2)
            self.enc_fc = nn.Sequential(nn.Linear(m, h1), nn.Linear(h1, h2), nn.Linear(h2, hidden))
            self.lstm1 = nn.LSTM(hidden, hidden // 2, batch_first=True, bidirectional=True)
            self.lstm2 = nn.LSTM(hidden, hidden // 2, batch_first=True, bidirectional=True)
            self.dec_fc = nn.Sequential(nn.Linear(hidden, h2), nn.Linear(h2, h1), nn.Linear(h1, n))
            self.drop = nn.Dropout(dropout)
            if self.residual:                 # start at the identity
                nn.init.zeros_(self.dec_fc[-1].weight)
                nn.init.zeros_(self.dec_fc[-1].bias)

        def encode(self, x):
            h, _ = self.lstm1(self.enc_fc(x))
            return self.drop(h)

        def decode(self, h):
            y, _ = self.lstm2(h)
            return self.dec_fc(self.drop(y))

        def forward(self, x):
            h = self.encode(x)
            y = self.decode(h)
            if self.residual:
                y = x[..., :self.n] + y
            return y, h

    _CACHE["MotionAutoencoder"] = MotionAutoencoder
    return _CACHE


def n_parameters(model: Any) -> int:
    return int(sum(p.numel() for p in model.parameters()))
