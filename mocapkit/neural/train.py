"""Training of BRA / BRA-P (Li et al. 2020, seed 002, Sec. III.D and IV.A).

Two stages (BRA-P):

1. the **perceptual autoencoder** (E_p, D_p) on clean clips X_C, eq. (8):
   ``L_p = l1 L_R(X_C, X'_C) + l2 L_S(X'_C) + l3 L_B(X'_C)`` with (l1, l2, l3) =
   (1, 1e-4, 1e-4), Adam, learning rate 1e-5;
2. the **denoising autoencoder** (E_d, D_d) on noisy/clean pairs, eq. (9):
   ``L_d = l1 L_R(X_C, X_R) + l2 L_S(X_R) + l3 L_B(X_R) + l4 L_P(X_C, X_R)`` with
   (1, 1e-3, 1e-3, 10), Adam, learning rate 1e-3, E_p frozen.

BRA (Li et al. 2019, the paper's [13] and its Table 2 row "BRA(512)") is stage 2 without
the perceptual term and without stage 1. Batch 16, dropout 0.2; the paper trains each
network 300 epochs (defaults here; CPU runs pass ``steps_*``).

Training set (DS_syn, Sec. IV.A), generated on the fly from the clean clips with
:mod:`mocapkit.corrupt`: each sample gets one of four noise types with equal
probability (the paper builds N_CMU/2 clips of each type, so an epoch of stage 2 is
2 N_CMU samples): Gaussian noise at SNR 1 dB or 5 dB on every joint; or 30 % / 40 % of
the joints of every frame missing (set to zero in the normalised data) and Gaussian
noise at 15 dB on the rest. SNR as defined in :mod:`mocapkit.corrupt` (root-relative
signal power of the clip).

Reproducibility: one seed drives numpy (clip order, noise) and torch (initialisation,
dropout); checkpoints store both generator states, so a resumed run continues the same
sequence. ``torch.set_num_threads`` is set to ``threads`` (default: the CPU cores this
process may use).
"""
from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import MocapValueError
from ..frames import mirror_permutation
from ..motion import Motion
from ..skeleton import Skeleton
from . import clips as C
from . import require_torch
from .bundle import Bundle, make_meta

NOISE_MIX: tuple[tuple[str, float, float], ...] = (
    ("gaussian", 0.0, 1.0),
    ("gaussian", 0.0, 5.0),
    ("missing", 0.3, 15.0),
    ("missing", 0.4, 15.0),
)
"""The paper's training noise: (kind, missing ratio, Gaussian SNR dB)."""

NOISE_MIX_V2: tuple[tuple[str, float, float], ...] = NOISE_MIX + (
    ("sigma", 0.0, 8.0),
    ("sigma", 0.0, 8.0),
    ("sigma", 0.0, 8.0),
    ("sigma", 0.2, 4.0),
    ("spikes", 0.15, 3.0),
    ("spikes", 0.15, 3.0),
)
"""Issue 20's training noise: the paper's four types (40 % of the samples) plus
``("sigma", r, s)``: Gaussian noise of a sigma drawn log-uniformly in [0.05, s] cm
(clean-looking to heavy; a network must learn to leave a clean clip alone) with up to
``r`` of the joints of every frame missing; and ``("spikes", r, s)``: Gaussian noise of
U[0.3, s] cm plus a fraction U[0, r] of the joint positions moved by 15 cm in a random
direction."""

SPIKE_CM = 15.0

CHECKPOINT_VERSION = 1


OPERATING_POINT: dict[str, Any] = dict(
    hidden=256, dropout=0.0, batch_size=16, wide_fc=True,
    lambdas_perceptual=(1.0, 1e-4, 1e-4), lambdas_denoise=(1.0, 1e-3, 1e-3, 10.0),
    lr_perceptual=1e-3, lr_denoise=1e-3, lr_schedule="cosine", lr_floor=0.05, grad_clip=1.0,
    reproduction="rms",
    residual=True, fill_input=True, mask_input=True, base_sigma=1.0, base_filter="gcv", augment=True,
    scale_range=(0.85, 1.15), random_offsets=True, noise=NOISE_MIX_V2)
"""Settings of the shipped models (issue 20; benchmarks/train_neural.py) and the defaults
of :func:`train_cli`: the paper's losses and lambdas (eq. 3 as the per-clip RMS), hidden
256, residual output on the input's GCV smoothing spline (``base_filter="gcv"``; the
models before it corrected a median-5 + Gaussian low-pass), bridged + masked input,
augmentation, cosine learning rate."""


@dataclass
class TrainConfig:
    """Training parameters; defaults are the paper's (Sec. III.D).

    ``steps_perceptual`` / ``steps_denoise`` (optimizer steps) override the epoch counts.
    ``perceptual=False`` trains BRA (no perceptual AE, no perceptual loss, no
    postprocessing). ``random_offsets=True`` draws each training clip at a random start
    in its motion instead of from the fixed half-overlapping clip set (a superset of the
    paper's clips; used for the small CPU runs). ``device`` is a torch device name
    (``"cuda"`` for a GPU run; the saved model is always moved back to the CPU).
    """

    hidden: int = 512
    dropout: float = 0.2
    batch_size: int = 16
    clip_frames: int = C.CLIP_FRAMES
    lambdas_perceptual: tuple[float, float, float] = (1.0, 1e-4, 1e-4)
    lambdas_denoise: tuple[float, float, float, float] = (1.0, 1e-3, 1e-3, 10.0)
    lr_perceptual: float = 1e-5
    lr_denoise: float = 1e-3
    epochs_perceptual: float = 300.0
    epochs_denoise: float = 300.0
    steps_perceptual: int | None = None
    steps_denoise: int | None = None
    perceptual: bool = True
    postprocess: bool = True
    seed: int = 0
    threads: int | None = None
    checkpoint_every: int = 200
    reference_sigma: float = C.REFERENCE_SIGMA
    random_offsets: bool = False
    noise: tuple = NOISE_MIX
    device: str = "cpu"
    residual: bool = False
    mask_input: bool = False
    fill_input: bool = False
    augment: bool = False
    scale_range: tuple[float, float] = (0.85, 1.15)
    lr_schedule: str = "constant"
    lr_floor: float = 0.05
    base_sigma: float = 0.0
    base_filter: str = "lowpass"
    grad_clip: float = 0.0
    reproduction: str = "mse"
    wide_fc: bool = False
    highpass_gain: float = 1.0

    def to_json(self) -> dict:
        d = asdict(self)
        d["noise"] = [list(n) for n in self.noise]
        d["lambdas_perceptual"] = list(self.lambdas_perceptual)
        d["lambdas_denoise"] = list(self.lambdas_denoise)
        d["scale_range"] = list(self.scale_range)
        return d

    @classmethod
    def from_params(cls, **params: Any) -> "TrainConfig":
        names = set(cls.__dataclass_fields__)
        bad = sorted(set(params) - names)
        if bad:
            raise MocapValueError(f"unknown training parameter(s) {bad}; known: {', '.join(sorted(names))}")
        p = dict(params)
        if "noise" in p:
            p["noise"] = tuple(tuple(n) for n in p["noise"])
        for k in ("lambdas_perceptual", "lambdas_denoise", "scale_range"):
            if k in p:
                p[k] = tuple(float(x) for x in p[k])
        return cls(**p)


# ----------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------
class SyntheticSource:
    """Clean root-local clips of the training motions and the on-the-fly DS_syn noise.

    Parameters
    ----------
    motions : clean training motions (any fps; resampled to 60), all containing ``joints``.
    joints : model joints (first = root); default :data:`clips.CMU_21`.
    f : clip length (frames).
    augment : the statistics (:class:`clips.Normaliser`) are those of the rotation-augmented
        data: horizontal means 0 (a uniform rotation about the vertical averages them out).
    mask_input : the network input carries the K mask channels (``m = 4 K``).
    """

    def __init__(self, motions: Sequence[Motion], joints: Sequence[str] = C.CMU_21,
                 f: int = C.CLIP_FRAMES, *, augment: bool = False, mask_input: bool = False,
                 base_sigma: float = 0.0, base_filter: str = "lowpass"):
        if not motions:
            raise MocapValueError("training needs at least one motion")
        self.joints = list(joints)
        self.f = int(f)
        sk0 = motions[0].skeleton
        self.parents = C.subset_parents(sk0, self.joints)
        if self.parents[0] != -1:
            raise MocapValueError(f"the first model joint ({self.joints[0]}) must be the root of the subset")
        rest = sk0.rest_positions()[sk0.indices(self.joints)]
        self.offsets = np.where(self.parents[:, None] >= 0, rest - rest[np.maximum(self.parents, 0)], rest)
        self.skeleton = Skeleton(tuple(self.joints), self.parents, self.offsets)
        self.bones = C.bones_of(self.parents)
        self.mirror = mirror_permutation(self.joints)     # None: some sided joint has no partner
        self.local: list[np.ndarray] = []
        self.tracks: list[np.ndarray] = []           # the horizontal root paths taken off
        self.names: list[str] = []
        for m in motions:
            P, obs = C.prepare_positions(m, self.joints, C.FPS)
            if not obs.all():
                raise MocapValueError(f"training motion {m!r} has missing joints; fill them first")
            ref = C.ground_reference(P[:, 0], sigma=0.0)        # exact root: the paper's frame
            L = P - ref[:, None, :]
            L, _ = C.pad_edges(L, self.f)
            self.local.append(L)
            self.tracks.append(C.pad_edges(ref, self.f)[0])
            self.names.append(str(m.source.get("path", f"motion{len(self.names)}")))
        self.clips = [(i, int(s)) for i, L in enumerate(self.local) for s in C.training_windows(len(L), self.f)]
        allX = np.concatenate([L.reshape(len(L), -1) for L in self.local], axis=0)
        self.norm = C.Normaliser.fit(allX)
        if augment:
            mean = self.norm.mean.reshape(-1, 3).copy()
            mean[:, [a for a in range(3) if a != C.UP_AXIS]] = 0.0
            mean = mean.reshape(-1)
            self.norm = C.Normaliser(mean, float(np.sqrt(np.mean((allX - mean) ** 2))))
        self.norm_in = self.norm_out = self.norm
        self.body_size = C.body_size(np.concatenate(self.local))
        self.n = 3 * len(self.joints)
        self.mask_input = bool(mask_input)
        self.base_sigma = float(base_sigma)
        self.base_filter = str(base_filter)
        self.m = self.n * (2 if base_sigma > 0 else 1) + (len(self.joints) if mask_input else 0)
        self.joints_in = self.joints_out = self.joints

    @property
    def n_clips(self) -> int:
        return len(self.clips)

    def _clean(self, rng: np.random.Generator, B: int, cfg: "TrainConfig", queue: list
               ) -> tuple[np.ndarray, np.ndarray]:
        """B clean root-local clips (B, f, K, 3) and their horizontal root paths (B, f, 3)
        (the world frame of :func:`clips.model_input`'s GCV base), augmented alike."""
        out, paths = [], []
        for _ in range(B):
            if cfg.random_offsets:
                lens = np.array([len(L) - self.f + 1 for L in self.local], dtype=float)
                i = int(rng.choice(len(self.local), p=lens / lens.sum()))
                s = int(rng.integers(0, len(self.local[i]) - self.f + 1))
            else:
                if not queue:
                    queue.extend(int(k) for k in rng.permutation(len(self.clips)))
                i, s = self.clips[queue.pop()]
            out.append(self.local[i][s:s + self.f])
            paths.append(self.tracks[i][s:s + self.f])
        X = np.concatenate([np.stack(out), np.stack(paths)[:, :, None]], axis=2)   # (B, f, K + 1, 3)
        if getattr(cfg, "augment", False):
            X = self.augment(X, rng, cfg.scale_range)
        return X[:, :, :-1], X[:, :, -1]

    def augment(self, X: np.ndarray, rng: np.random.Generator, scale_range=(0.85, 1.15)) -> np.ndarray:
        """Rotate (B, f, K, 3) root-local clips about the vertical, mirror half of them
        left/right, scale them (vectorised; the root stays on the vertical axis). A
        (K + 1)-th point (the root path, :meth:`_clean`) is mirrored onto itself."""
        B = len(X)
        X = np.array(X, dtype=np.float64)
        flip = rng.random(B) < 0.5
        if flip.any():
            if self.mirror is None:
                raise MocapValueError("augmentation mirrors left and right: every sided model joint "
                                      f"needs a partner by name ({', '.join(self.joints)})")
            perm = np.append(self.mirror, len(self.mirror))[:X.shape[2]]     # the path maps to itself
            Y = X[flip][:, :, perm]
            Y[..., C.MIRROR_AXIS] *= -1.0
            X[flip] = Y
        X = C.turn(X, rng.uniform(0.0, 2 * np.pi, B)[:, None, None])
        lo, hi = scale_range
        X *= rng.uniform(lo, hi, B)[:, None, None, None]
        return X

    def ref_lengths(self, X: np.ndarray, std: float) -> np.ndarray:
        """Mean bone lengths over each clean clip (B, nb), in units of std."""
        b = self.bones
        L = np.linalg.norm(X[:, :, b[:, 0]] - X[:, :, b[:, 1]], axis=-1).mean(axis=1)
        return L / std

    def clean_batch(self, rng, B, cfg: TrainConfig, queue: list) -> dict[str, np.ndarray]:
        X, _ = self._clean(rng, B, cfg, queue)                   # (B, f, K, 3)
        Z = self.norm.forward(X.reshape(B, self.f, -1))
        return {"x_clean": Z, "ref": self.ref_lengths(X, self.norm.std)}

    def corrupt(self, X: np.ndarray, kind: str, ratio: float, level: float,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """One noisy copy of a clean clip X (f, K, 3): (positions with NaN, observed (f, K))."""
        f, K, _ = X.shape
        obs = np.ones((f, K), bool)
        if kind in ("gaussian", "missing"):
            rel = X[:, 1:] - X[:, :1]
            sigma = float(np.sqrt(np.mean(rel ** 2) / 10.0 ** (float(level) / 10.0)))
            miss = float(ratio) if kind == "missing" else 0.0
        elif kind == "sigma":
            sigma = float(np.exp(rng.uniform(np.log(0.05), np.log(float(level)))))
            miss = float(rng.uniform(0.0, float(ratio))) if ratio else 0.0
        elif kind == "spikes":
            sigma = float(rng.uniform(0.3, float(level)))
            miss = 0.0
        else:
            raise MocapValueError(f"unknown training noise kind {kind!r}")
        P = X + rng.normal(0.0, sigma, X.shape)
        if kind == "spikes":
            sel = rng.random((f, K)) < rng.uniform(0.0, float(ratio))
            d = rng.normal(size=(int(sel.sum()), 3))
            P[sel] += SPIKE_CM * d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        if miss > 0:
            n = int(round(miss * K))
            if n:
                idx = np.argsort(rng.random((f, K)), axis=1)[:, :n]
                np.put_along_axis(obs, idx, False, axis=1)
                P[~obs] = np.nan
        return P, obs

    def noisy_batch(self, rng, B, cfg: TrainConfig, queue: list) -> dict[str, np.ndarray]:
        clean, paths = self._clean(rng, B, cfg, queue)
        xin, xc, refs = [], [], []
        for X, path in zip(clean, paths):
            kind, ratio, level = cfg.noise[int(rng.integers(len(cfg.noise)))]
            P, obs = self.corrupt(X, kind, ratio, level, rng)
            ref = C.ground_reference(P[:, 0], obs[:, 0], sigma=cfg.reference_sigma,
                                     fallback=C.joint_mean_track(P))
            Z = self.norm.forward((P - ref[:, None]).reshape(self.f, -1))
            xin.append(C.model_input(Z, obs, fill=getattr(cfg, "fill_input", False), mask=self.mask_input,
                                     base_sigma=self.base_sigma, highpass_gain=cfg.highpass_gain,
                                     base_filter=self.base_filter,
                                     reference=C.reference_channels(ref + path, len(self.joints), self.norm)))
            T = X - ref[:, None]
            xc.append(self.norm.forward(T.reshape(self.f, -1)))
            refs.append(T)
        return {"x_in": np.stack(xin), "x_clean": np.stack(xc),
                "ref": self.ref_lengths(np.stack(refs), self.norm.std)}


class PairedSource:
    """Fixed noisy/clean pairs, possibly of different skeletons (the paper's DS_raw case).

    Parameters
    ----------
    inputs : list of (T_i, m) arrays, the noisy data in the model's input frame (cm; NaN
        = missing, set to zero after normalisation).
    targets : list of (T_i, n) arrays, the clean data (cm), frames aligned with inputs.
    joints_in, joints_out : names (m/3 and n/3 joints); parents_out : bone tree of the
        output joints (-1 for the root), for the bone-length loss.
    """

    def __init__(self, inputs: Sequence[np.ndarray], targets: Sequence[np.ndarray],
                 joints_in: Sequence[str], joints_out: Sequence[str], parents_out: Sequence[int],
                 offsets_out: np.ndarray | None = None, f: int = C.CLIP_FRAMES):
        if len(inputs) != len(targets) or not inputs:
            raise MocapValueError("PairedSource needs as many input as target sequences (at least one)")
        self.f = int(f)
        self.joints_in, self.joints_out = list(joints_in), list(joints_out)
        self.m, self.n = 3 * len(self.joints_in), 3 * len(self.joints_out)
        self.parents = np.asarray(parents_out, dtype=np.int64)
        self.bones = C.bones_of(self.parents)
        self.offsets = np.zeros((len(self.joints_out), 3)) if offsets_out is None else np.asarray(offsets_out)
        self.inp, self.tgt = [], []
        for a, b in zip(inputs, targets):
            a, b = np.asarray(a, float), np.asarray(b, float)
            if a.ndim != 2 or b.ndim != 2 or a.shape[1] != self.m or b.shape[1] != self.n or len(a) != len(b):
                raise MocapValueError(f"pair shapes {a.shape} / {b.shape} do not match m={self.m}, n={self.n}")
            self.inp.append(C.pad_edges(a, self.f)[0])
            self.tgt.append(C.pad_edges(b, self.f)[0])
        self.clips = [(i, int(s)) for i, L in enumerate(self.tgt) for s in C.training_windows(len(L), self.f)]
        A = np.concatenate(self.inp)
        mean_in = np.nanmean(A, axis=0)
        self.norm_in = C.Normaliser(mean_in, float(np.sqrt(np.nanmean((A - mean_in) ** 2))))
        self.norm_out = C.Normaliser.fit(np.concatenate(self.tgt))
        self.norm = self.norm_out

    @property
    def n_clips(self) -> int:
        return len(self.clips)

    def _pick(self, rng, B, cfg, queue):
        out = []
        for _ in range(B):
            if cfg.random_offsets:
                i = int(rng.integers(len(self.tgt)))
                s = int(rng.integers(0, len(self.tgt[i]) - self.f + 1))
            else:
                if not queue:
                    queue.extend(int(k) for k in rng.permutation(len(self.clips)))
                i, s = self.clips[queue.pop()]
            out.append((self.inp[i][s:s + self.f], self.tgt[i][s:s + self.f]))
        return out

    def _ref(self, T: np.ndarray) -> np.ndarray:
        X = T.reshape(T.shape[0], T.shape[1], -1, 3)
        b = self.bones
        return np.linalg.norm(X[:, :, b[:, 0]] - X[:, :, b[:, 1]], axis=-1).mean(axis=1) / self.norm_out.std

    def clean_batch(self, rng, B, cfg, queue):
        T = np.stack([t for _, t in self._pick(rng, B, cfg, queue)])
        return {"x_clean": self.norm_out.forward(T), "ref": self._ref(T)}

    def noisy_batch(self, rng, B, cfg, queue):
        pairs = self._pick(rng, B, cfg, queue)
        A = np.stack([a for a, _ in pairs])
        T = np.stack([t for _, t in pairs])
        return {"x_in": self.norm_in.forward_fill(A), "x_clean": self.norm_out.forward(T), "ref": self._ref(T)}


# ----------------------------------------------------------------------------------------
# trainer
# ----------------------------------------------------------------------------------------
@contextlib.contextmanager
def _flush_denormals(torch: Any) -> Iterator[None]:
    """Flush denormal floats to zero while training, and restore the processor's mode after.

    Measured (issue 20): without it, denormal floats in the LSTM made CPU training steps
    5-10x slower after a few hundred steps (0.3 s -> 2-4 s per step). The mode is
    process-wide (the CPU's FTZ/DAZ flags), so leaving it on would change every later float
    computation in the process -- the fuzz tests' Hypothesis refuses to run under it -- hence
    it is switched back when training ends.
    """
    was_on = bool(np.float64(sys.float_info.min) / np.float64(2.0) == 0.0)
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(was_on)


def available_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)


class Trainer:
    """Runs the two stages with progress bar, periodic checkpoints and resume.

    Parameters
    ----------
    source : :class:`SyntheticSource` or :class:`PairedSource`.
    config : :class:`TrainConfig`.
    checkpoint : path of the checkpoint file (None: no checkpoints).
    progress : show a tqdm bar with the running losses.
    log : optional callable(str) for one-line messages.
    """

    def __init__(self, source: Any, config: TrainConfig, *, checkpoint: str | os.PathLike | None = None,
                 progress: bool = True, log: Callable[[str], None] | None = None):
        torch = require_torch()
        from .model import build

        self.torch = torch
        self.src = source
        self.cfg = config
        self.checkpoint = None if checkpoint is None else Path(checkpoint)
        self.progress = progress
        self.log = log or (lambda s: None)
        torch.set_num_threads(int(config.threads or available_cores()))
        torch.manual_seed(int(config.seed))
        self.rng = np.random.default_rng(int(config.seed))
        self.queue: list[int] = []
        n = source.n
        self.device = torch.device(config.device)
        self.perceptual = (build(n, n, config.hidden, config.dropout).to(self.device)
                           if config.perceptual else None)
        self.denoise = build(source.m, n, config.hidden, config.dropout,
                             residual=bool(config.residual), wide=bool(config.wide_fc)).to(self.device)
        self.opt_p = (torch.optim.Adam(self.perceptual.parameters(), lr=config.lr_perceptual)
                      if self.perceptual is not None else None)
        self.opt_d = torch.optim.Adam(self.denoise.parameters(), lr=config.lr_denoise)
        self.phase = "perceptual" if config.perceptual else "denoise"
        self.step = 0                      # step within the current phase
        self.history: list[dict] = []
        self.seconds = 0.0
        self.bones = torch.as_tensor(source.bones, dtype=torch.long, device=self.device)
        self.mean_over_std = torch.as_tensor(source.norm_out.mean / source.norm_out.std, dtype=torch.float32,
                                             device=self.device)

    # -- schedule ------------------------------------------------------------------------------
    def total_steps(self, phase: str) -> int:
        c = self.cfg
        if phase == "perceptual":
            if c.steps_perceptual is not None:
                return int(c.steps_perceptual)
            return int(np.ceil(c.epochs_perceptual * self.src.n_clips / c.batch_size))
        if c.steps_denoise is not None:
            return int(c.steps_denoise)
        return int(np.ceil(c.epochs_denoise * 2 * self.src.n_clips / c.batch_size))

    # -- one step ------------------------------------------------------------------------------
    def _tensor(self, a: np.ndarray):
        return self.torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32)).to(self.device)

    def _losses_perceptual(self, batch: dict) -> tuple[Any, dict]:
        from . import losses as L

        x = self._tensor(batch["x_clean"])
        ref = self._tensor(batch["ref"])
        y, _ = self.perceptual(x)
        lr, ls = L.reproduction(y, x), L.smoothness(y)
        lb = L.bone_length(L.denormalised(y, self.mean_over_std), self.bones, ref)
        l1, l2, l3 = self.cfg.lambdas_perceptual
        total = l1 * lr + l2 * ls + l3 * lb
        return total, {"loss": total.item(), "R": lr.item(), "S": ls.item(), "B": lb.item()}

    def _losses_denoise(self, batch: dict) -> tuple[Any, dict]:
        from . import losses as L

        xin, xc = self._tensor(batch["x_in"]), self._tensor(batch["x_clean"])
        ref = self._tensor(batch["ref"])
        y, _ = self.denoise(xin)
        rep = L.reproduction_rms if self.cfg.reproduction == "rms" else L.reproduction
        lr, ls = rep(y, xc), L.smoothness(y)
        lb = L.bone_length(L.denormalised(y, self.mean_over_std), self.bones, ref)
        l1, l2, l3, l4 = self.cfg.lambdas_denoise
        total = l1 * lr + l2 * ls + l3 * lb
        logs = {"R": lr.item(), "S": ls.item(), "B": lb.item()}
        if self.perceptual is not None and l4:
            hr = self.perceptual.encode(y)
            with self.torch.no_grad():
                hc = self.perceptual.encode(xc)
            lp = L.perceptual(hr, hc)
            total = total + l4 * lp
            logs["P"] = lp.item()
        logs["loss"] = total.item()
        return total, logs

    def train_step(self) -> dict:
        """One optimisation step of the current phase; returns the loss components."""
        B = self.cfg.batch_size
        if self.phase == "perceptual":
            self.perceptual.train()
            batch = self.src.clean_batch(self.rng, B, self.cfg, self.queue)
            loss, logs = self._losses_perceptual(batch)
            opt = self.opt_p
        else:
            self.denoise.train()
            batch = self.src.noisy_batch(self.rng, B, self.cfg, self.queue)
            loss, logs = self._losses_denoise(batch)
            opt = self.opt_d
        lr = self.learning_rate()
        for g in opt.param_groups:
            g["lr"] = lr
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if self.cfg.grad_clip and self.cfg.grad_clip > 0:
            params = [p for g in opt.param_groups for p in g["params"]]
            self.torch.nn.utils.clip_grad_norm_(params, float(self.cfg.grad_clip))
        opt.step()
        self.step += 1
        logs["lr"] = lr
        return logs

    def learning_rate(self) -> float:
        """Learning rate of the current step (``lr_schedule``, see :class:`TrainConfig`)."""
        c = self.cfg
        base = c.lr_perceptual if self.phase == "perceptual" else c.lr_denoise
        if c.lr_schedule == "constant":
            return float(base)
        if c.lr_schedule != "cosine":
            raise MocapValueError(f"lr_schedule must be 'constant' or 'cosine', not {c.lr_schedule!r}")
        frac = min(1.0, self.step / max(1, self.total_steps(self.phase)))
        return float(base * (c.lr_floor + (1 - c.lr_floor) * 0.5 * (1 + np.cos(np.pi * frac))))

    def _enter_denoise(self) -> None:
        self.phase = "denoise"
        self.step = 0
        self.queue = []
        if self.perceptual is not None:
            self.perceptual.eval()
            for p in self.perceptual.parameters():
                p.requires_grad_(False)

    def run(self) -> "Trainer":
        """Train until both phases reach their step counts (continuing a resumed run)."""
        with _flush_denormals(self.torch):
            return self._run()

    def _run(self) -> "Trainer":
        from tqdm import tqdm

        if self.phase == "done" and self.step < self.total_steps("denoise"):
            self.phase = "denoise"           # resumed with more denoising steps than before
        while self.phase != "done":
            total = self.total_steps(self.phase)
            if self.phase == "perceptual" and self.perceptual is not None and self.step == 0:
                self.log(f"stage 1: perceptual autoencoder, {total} steps")
            bar = tqdm(total=total, initial=self.step, desc=f"{self.phase} AE", disable=None if self.progress else True,
                       leave=False, dynamic_ncols=True)
            acc: dict[str, list[float]] = {}
            t0 = time.perf_counter()
            while self.step < total:
                logs = self.train_step()
                for k, v in logs.items():
                    acc.setdefault(k, []).append(v)
                bar.update(1)
                if self.step % 10 == 0 or self.step == total:
                    bar.set_postfix({k: f"{np.mean(v[-50:]):.4g}" for k, v in acc.items()})
                if self.step % 50 == 0 or self.step == total:
                    self.history.append({"phase": self.phase, "step": self.step,
                                         "seconds": round(self.seconds + time.perf_counter() - t0, 1),
                                         **{k: float(np.mean(v[-50:])) for k, v in acc.items()}})
                    self.log(f"{self.phase} {self.step}/{total} " + " ".join(
                        f"{k}={np.mean(v[-50:]):.4g}" for k, v in acc.items()))
                if self.checkpoint is not None and self.cfg.checkpoint_every and (
                        self.step % self.cfg.checkpoint_every == 0) and self.step < total:
                    self.seconds += time.perf_counter() - t0
                    t0 = time.perf_counter()
                    self.save_checkpoint()
            bar.close()
            self.seconds += time.perf_counter() - t0
            self.phase = "denoise" if self.phase == "perceptual" else "done"
            if self.phase == "denoise":
                self._enter_denoise()
            if self.checkpoint is not None:
                self.save_checkpoint()
        return self

    # -- checkpoints ---------------------------------------------------------------------------
    def _meta(self) -> dict:
        return {"version": CHECKPOINT_VERSION, "config": self.cfg.to_json(), "phase": self.phase,
                "step": self.step, "rng": self.rng.bit_generator.state, "queue": list(self.queue),
                "history": self.history, "seconds": self.seconds, "n_clips": self.src.n_clips,
                "m": self.src.m, "n": self.src.n}

    def save_checkpoint(self, path: str | os.PathLike | None = None) -> None:
        from ..io._atomic import atomic_write

        torch = self.torch
        path = Path(path) if path is not None else self.checkpoint
        d = {"meta": json.dumps(self._meta()), "torch_rng": torch.get_rng_state(),
             "denoise": self.denoise.state_dict(), "opt_d": self.opt_d.state_dict()}
        if self.perceptual is not None:
            d["perceptual"] = self.perceptual.state_dict()
            d["opt_p"] = self.opt_p.state_dict()
        atomic_write(path, lambda f: torch.save(d, f), binary=True)

    def load_checkpoint(self, path: str | os.PathLike) -> "Trainer":
        """Restore a checkpoint written by :meth:`save_checkpoint` (same config and data)."""
        torch = self.torch
        d = torch.load(os.fspath(path), map_location="cpu", weights_only=True)
        meta = json.loads(d["meta"])
        mine = self.cfg.to_json()
        theirs = meta["config"]
        ignore = {"steps_perceptual", "steps_denoise", "epochs_perceptual", "epochs_denoise",
                  "checkpoint_every", "threads", "device"}
        defaults = TrainConfig().to_json()        # fields added after the checkpoint was written
        diff = sorted(k for k in mine if k not in ignore and mine[k] != theirs.get(k, defaults.get(k)))
        if diff:
            raise MocapValueError(f"checkpoint {path} was written with other settings ({', '.join(diff)}); "
                                  f"start without resume or use the same parameters")
        if meta["n_clips"] != self.src.n_clips or meta["m"] != self.src.m or meta["n"] != self.src.n:
            raise MocapValueError(f"checkpoint {path} was written for other training data "
                                  f"({meta['n_clips']} clips, now {self.src.n_clips})")
        self.denoise.load_state_dict(d["denoise"])
        self.opt_d.load_state_dict(d["opt_d"])
        if self.perceptual is not None:
            self.perceptual.load_state_dict(d["perceptual"])
            self.opt_p.load_state_dict(d["opt_p"])
        torch.set_rng_state(d["torch_rng"])
        self.rng.bit_generator.state = meta["rng"]
        self.queue = list(meta["queue"])
        self.phase, self.step = meta["phase"], int(meta["step"])
        self.history = list(meta["history"])
        self.seconds = float(meta["seconds"])
        if self.phase in ("denoise", "done") and self.perceptual is not None:
            self.perceptual.eval()
            for p in self.perceptual.parameters():
                p.requires_grad_(False)
        return self

    # -- result -----------------------------------------------------------------------------------
    def bundle(self, method: str | None = None, training_info: dict | None = None) -> Bundle:
        cfg = self.cfg
        method = method or ("bra-p" if cfg.perceptual else "bra")
        params = cfg.to_json()
        params["postprocess"] = bool(cfg.postprocess and cfg.perceptual)
        info = {"steps_perceptual": self.total_steps("perceptual") if cfg.perceptual else 0,
                "steps_denoise": self.total_steps("denoise"), "seconds": round(self.seconds, 1),
                "n_clips": self.src.n_clips, "final": self.history[-1:] and self.history[-1],
                "history": self.history[::max(1, len(self.history) // 40)]}
        info.update(training_info or {})
        extra = {"body_size_cm": round(float(self.src.body_size), 3)} if hasattr(self.src, "body_size") else {}
        meta = make_meta(method, params, self.src.joints_in, self.src.joints_out, self.src.parents,
                         self.src.offsets, training=info, **extra)
        self.denoise.cpu().eval()
        if self.perceptual is not None:
            self.perceptual.cpu().eval()
        return Bundle(self.denoise, self.perceptual, self.src.norm_in, self.src.norm_out, meta)


def train_motions(motions: Sequence[Motion], config: TrainConfig, *, joints: Sequence[str] = C.CMU_21,
                  checkpoint: str | os.PathLike | None = None, resume: bool = False,
                  progress: bool = False, log: Callable[[str], None] | None = None,
                  training_info: dict | None = None) -> Bundle:
    """Train BRA-P (``config.perceptual``) or BRA on clean motions; returns the Bundle."""
    src = SyntheticSource(motions, joints, config.clip_frames, augment=config.augment,
                          mask_input=config.mask_input, base_sigma=config.base_sigma,
                          base_filter=config.base_filter)
    tr = Trainer(src, config, checkpoint=checkpoint, progress=progress, log=log)
    if resume and checkpoint is not None and Path(checkpoint).is_file():
        tr.load_checkpoint(checkpoint)
        if log:
            log(f"resumed from {checkpoint}: phase {tr.phase}, step {tr.step}")
    tr.run()
    return tr.bundle(training_info=training_info)


# ----------------------------------------------------------------------------------------
# command line entry point
# ----------------------------------------------------------------------------------------
_MOTION_EXT = (".amc", ".bvh")


def _collect(data: str | os.PathLike | Iterable[str | os.PathLike]) -> list[Path]:
    if isinstance(data, (str, os.PathLike)):
        items = [Path(data)]
    else:
        items = [Path(p) for p in data]
    files: list[Path] = []
    for p in items:
        if p.is_dir():
            files.extend(sorted(q for q in p.rglob("*") if q.suffix.lower() in _MOTION_EXT))
        elif p.is_file():
            files.append(p)
        else:
            raise MocapValueError(f"{p}: no such file or folder")
    return files


def train_cli(data: str | os.PathLike | Iterable[str | os.PathLike], output: str | os.PathLike, *,
              method: str = "bra-p", resume: bool = False, progress: bool = True,
              exclude: Sequence[str] = (), half: bool = False,
              log: Callable[[str], None] | None = print, **params: Any) -> Bundle:
    """Train BRA-P or BRA on a folder (or list) of motion files and write the model.

    Parameters
    ----------
    data : folder (searched recursively for ``.amc`` / ``.bvh``) or files. Files whose
        skeleton lacks the 21 joints are skipped with a message.
    output : model path (``.pt``); the checkpoint goes to ``output + '.ckpt'``.
    method : ``'bra-p'`` (perceptual AE + denoising AE) or ``'bra'``.
    resume : continue from ``output + '.ckpt'`` when it exists.
    exclude : file stems to hold out (e.g. ``['16_15', '131_03']``).
    half : store the weights as float16 (half the size).
    params : :class:`TrainConfig` fields (``hidden``, ``steps_denoise``, ``lr_perceptual`` ...);
        unspecified ones take :data:`OPERATING_POINT` (``residual=False, fill_input=False,
        mask_input=False, base_sigma=0, augment=False, lr_schedule='constant',
        noise=NOISE_MIX`` is the paper's original network).

    Returns
    -------
    The trained :class:`~mocapkit.neural.bundle.Bundle` (also written to ``output``).
    """
    from .. import io

    if method not in ("bra-p", "bra"):
        raise MocapValueError(f"train_cli trains 'bra-p' or 'bra', not {method!r}")
    params = {**OPERATING_POINT, **dict(params)}
    params.setdefault("perceptual", method == "bra-p")
    cfg = TrainConfig.from_params(**params)
    files = [f for f in _collect(data) if f.stem not in set(exclude)]
    motions, used, skipped = [], [], []
    for f in files:
        try:
            m = io.read(f)
            C.check_joints(m.skeleton, C.CMU_21)
        except Exception as e:  # noqa: BLE001 - report and go on
            skipped.append(f"{f.name} ({e})")
            continue
        motions.append(m)
        used.append(f.stem)
    if log:
        for s in skipped:
            log(f"skipped {s}")
    if not motions:
        raise MocapValueError(f"no usable training motion in {data!r} (need the 21 CMU joints)")
    if log:
        log(f"training {method} on {len(motions)} motions "
            f"({sum(m.duration for m in motions):.0f} s); threads={cfg.threads or available_cores()}")
    out = Path(output)
    bundle = train_motions(motions, cfg, checkpoint=str(out) + ".ckpt", resume=resume, progress=progress,
                           log=log, training_info={"motions": used, "excluded": list(exclude)})
    bundle.save(out, half=half)
    if log:
        log(f"wrote {out}")
    return bundle
