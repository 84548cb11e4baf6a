"""A trained BRA / BRA-P model: networks + normalisation + joint lists, save/load, inference.

File format (``.pt``, ``torch.save`` of a flat dict, read back with
``torch.load(weights_only=True)``):

``meta``         JSON string: ``format`` ("mocapkit-neural"), ``version``
                 (:data:`FORMAT_VERSION`), ``method`` ("bra-p" / "bra"), ``params`` (the
                 training configuration), ``joints_in`` / ``joints_out`` (names, model
                 order), ``parents_out`` (bone tree of the output joints), ``offsets_out``
                 (rest offsets, cm), ``fps``, ``clip_frames``, ``clip_hop``,
                 ``reference_sigma``, ``postprocess``, ``training`` (data, steps, time,
                 final losses), ``dtype`` of the stored weights.
``mean_in``, ``std_in``, ``mean_out``, ``std_out``   float64 tensors (cm).
``denoise.<name>``     state dict of the denoising autoencoder (E_d, D_d).
``perceptual.<name>``  state dict of the perceptual autoencoder (E_p, D_p), BRA-P only.

Weights may be stored as float16 to keep shipped files small; they are cast back to
float32 at load time.
"""
from __future__ import annotations

import json
import os
from contextlib import contextmanager
from typing import Any, Sequence

import numpy as np

from ..errors import MocapFormatError, MocapValueError
from ..motion import Motion
from ..skeleton import Skeleton
from . import clips as C
from . import require_torch

FORMAT = "mocapkit-neural"
FORMAT_VERSION = 1


class Bundle:
    """Networks and everything needed to apply them (see module docstring).

    Attributes
    ----------
    denoise_net, perceptual_net : torch modules (perceptual_net None for BRA).
    norm_in, norm_out : :class:`~mocapkit.neural.clips.Normaliser`.
    meta : dict (JSON-able).
    """

    def __init__(self, denoise_net: Any, perceptual_net: Any, norm_in: C.Normaliser,
                 norm_out: C.Normaliser, meta: dict):
        self.denoise_net = denoise_net
        self.perceptual_net = perceptual_net
        self.norm_in = norm_in
        self.norm_out = norm_out
        self.meta = dict(meta)

    # -- properties ------------------------------------------------------------------------
    @property
    def joints_in(self) -> list[str]:
        return list(self.meta["joints_in"])

    @property
    def joints_out(self) -> list[str]:
        return list(self.meta["joints_out"])

    @property
    def parents_out(self) -> np.ndarray:
        return np.asarray(self.meta["parents_out"], dtype=np.int64)

    @property
    def same_topology(self) -> bool:
        return self.joints_in == self.joints_out

    def output_skeleton(self) -> Skeleton:
        return Skeleton(tuple(self.joints_out), self.parents_out,
                        np.asarray(self.meta["offsets_out"], dtype=float))

    # -- persistence -------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, half: bool = False) -> None:
        torch = require_torch()
        from ..io._atomic import atomic_write

        meta = dict(self.meta)
        meta["format"], meta["version"] = FORMAT, FORMAT_VERSION
        meta["dtype"] = "float16" if half else "float32"
        d: dict[str, Any] = {"meta": json.dumps(meta)}
        for k, n in (("in", self.norm_in), ("out", self.norm_out)):
            d[f"mean_{k}"] = torch.tensor(n.mean, dtype=torch.float64)
            d[f"std_{k}"] = torch.tensor(n.std, dtype=torch.float64)
        for prefix, net in (("denoise", self.denoise_net), ("perceptual", self.perceptual_net)):
            if net is None:
                continue
            for name, t in net.state_dict().items():
                t = t.detach().cpu()
                d[f"{prefix}.{name}"] = t.half() if (half and t.is_floating_point()) else t.clone()
        atomic_write(path, lambda f: torch.save(d, f), binary=True)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Bundle":
        torch = require_torch()
        from .model import build

        try:
            d = torch.load(os.fspath(path), map_location="cpu", weights_only=True)
            meta = json.loads(d["meta"])
        except FileNotFoundError:
            raise MocapValueError(f"{path}: no such model file") from None
        except Exception as e:  # noqa: BLE001 - any unpickling/zip problem is a format error
            raise MocapFormatError(path, f"not a mocapkit neural model ({type(e).__name__}: {e})") from None
        if meta.get("format") != FORMAT:
            raise MocapFormatError(path, "not a mocapkit neural model (no 'mocapkit-neural' header)")
        if meta.get("version") != FORMAT_VERSION:
            raise MocapFormatError(path, f"neural model format version {meta.get('version')} is not "
                                         f"supported (expected {FORMAT_VERSION})")
        p = meta["params"]
        m, n = 3 * len(meta["joints_in"]), 3 * len(meta["joints_out"])
        nets = {}
        for prefix, mm in (("denoise", m), ("perceptual", n)):
            sd = {k[len(prefix) + 1:]: v.float() if v.is_floating_point() else v
                  for k, v in d.items() if k.startswith(prefix + ".")}
            if not sd:
                nets[prefix] = None
                continue
            net = build(mm, n, int(p["hidden"]), float(p["dropout"]))
            try:
                net.load_state_dict(sd)
            except RuntimeError as e:
                raise MocapFormatError(path, f"weights do not match the stored configuration ({e})") from None
            net.eval()
            nets[prefix] = net
        if nets["denoise"] is None:
            raise MocapFormatError(path, "model file has no denoising network")
        norm_in = C.Normaliser(d["mean_in"].numpy(), float(d["std_in"]))
        norm_out = C.Normaliser(d["mean_out"].numpy(), float(d["std_out"]))
        return cls(nets["denoise"], nets["perceptual"], norm_in, norm_out, meta)

    # -- inference -------------------------------------------------------------------------------
    def run_windows(self, Z: np.ndarray, *, postprocess: bool | None = None, batch: int = 256,
                    threads: int | None = None) -> np.ndarray:
        """Normalised windows (K, f, m) -> refined normalised windows (K, f, n).

        BRA-P's output is D_p(E_p(X_R)) (postprocessing by the perceptual autoencoder);
        ``postprocess=False`` returns X_R (the BRA-P-D ablation of Table 2).
        ``threads``: torch threads during the call (default 1, restored afterwards): the
        LSTMs step through 120 frames with small matrices, so extra threads gain little
        and on a busy machine they slow inference down many times (measured: 5,000 vs
        120-1,800 frames/s on 2 shared cores).
        """
        torch = require_torch()
        post = self.meta.get("postprocess", True) if postprocess is None else postprocess
        post = bool(post) and self.perceptual_net is not None
        out = []
        self.denoise_net.eval()
        if self.perceptual_net is not None:
            self.perceptual_net.eval()
        with _threads(torch, threads), torch.inference_mode():
            for s in range(0, len(Z), batch):
                x = torch.from_numpy(np.ascontiguousarray(Z[s:s + batch], dtype=np.float32))
                y, _ = self.denoise_net(x)
                if post:
                    y, _ = self.perceptual_net(y)
                out.append(y.numpy())
        return np.concatenate(out, axis=0).astype(np.float64)

    def encode_perceptual(self, Z: np.ndarray, *, threads: int | None = None) -> np.ndarray:
        """Hidden units E_p(X) (K, f, h) of normalised output-space windows (for the P metric)."""
        torch = require_torch()
        if self.perceptual_net is None:
            raise MocapValueError("this model has no perceptual autoencoder (a BRA model)")
        self.perceptual_net.eval()
        with _threads(torch, threads), torch.inference_mode():
            h = self.perceptual_net.encode(torch.from_numpy(np.ascontiguousarray(Z, dtype=np.float32)))
        return h.numpy().astype(np.float64)

    def refine_local(self, P: np.ndarray, observed: np.ndarray, *, postprocess: bool | None = None,
                     threads: int | None = None) -> np.ndarray:
        """Refine 60-fps positions of the input joints (T, K_in, 3) cm -> (T, K_out, 3) cm.

        ``P`` may hold NaN where ``observed`` is False. Horizontal reference, normalisation,
        clipping and the cross-fade reassembly are done here (module :mod:`clips`).
        """
        P = np.asarray(P, dtype=np.float64)
        T, K, _ = P.shape
        up = int(self.meta.get("up_axis", C.UP_AXIS))
        ref = C.ground_reference(P[:, 0], observed[:, 0], sigma=float(self.meta["reference_sigma"]),
                                 up_axis=up, fallback=C.joint_mean_track(P))
        local = np.where(observed[..., None], P, np.nan) - ref[:, None, :]
        self._check_scale(local, observed)
        Z = self.norm_in.forward_fill(local.reshape(T, -1))
        f = int(self.meta["clip_frames"])
        W, starts, left = C.split_clips(Z, f, int(self.meta["clip_hop"]))
        Y = self.run_windows(W, postprocess=postprocess, threads=threads)
        out = self.norm_out.inverse(C.overlap_add(Y, starts, T, left))
        return out.reshape(T, -1, 3) + ref[:, None, :]

    #: the input's body may be this much smaller or larger than the training bodies
    SCALE_RANGE = (0.4, 2.5)

    def _check_scale(self, local: np.ndarray, observed: np.ndarray) -> None:
        """Refuse a body whose size is far from the training data's (issue 18: a clip in
        metres or millimetres came back tens of cm off).  Size = the median over frames
        (with >= 3 observed joints) of the RMS distance of the joints from their centroid,
        compared with the same for the training mean pose (``norm_in.mean``)."""
        ok = observed.sum(axis=1) >= 3
        if not ok.any():
            return
        L = local[ok]
        W = observed[ok][..., None]
        n = W.sum(axis=1)
        c = np.where(W, np.nan_to_num(L), 0.0).sum(axis=1) / n
        d2 = np.where(W[..., 0], ((np.nan_to_num(L) - c[:, None]) ** 2).sum(axis=2), 0.0)
        size = float(np.median(np.sqrt(d2.sum(axis=1) / n[:, 0])))
        mp = self.norm_in.mean.reshape(-1, 3)
        ref = float(np.sqrt(((mp - mp.mean(axis=0)) ** 2).sum(axis=1).mean()))
        if not (ref > 0 and np.isfinite(size)):
            return
        lo, hi = self.SCALE_RANGE
        if not lo <= size / ref <= hi:
            raise MocapValueError(
                f"the motion's body is {size / ref:.3g} times the size of the bodies this network "
                f"was trained on (joint spread {size:.3g} cm vs {ref:.3g} cm): check the units "
                f"(metres or millimetres read as cm?) or train on such data")

    def refine(self, motion: Motion, *, postprocess: bool | None = None, threads: int | None = None) -> Motion:
        """Refine a whole motion.

        Same topology: returns a Motion with the input's skeleton, frames and fps (joints
        outside the model's subset attached rigidly, :func:`clips.attach_dropped`).
        Different topology: a Motion on the model's output skeleton, same frames and fps.
        """
        C.check_joints(motion.skeleton, self.joints_in)
        fps = float(self.meta["fps"])
        P, obs = C.prepare_positions(motion, self.joints_in, fps)
        if not obs.any():
            raise MocapValueError("the motion has no observed value of the model's joints")
        out = self.refine_local(P, obs, postprocess=postprocess, threads=threads)
        out = _resample_back(out, fps, motion.fps, motion.n_frames)
        if self.same_topology or all(j in motion.skeleton.names for j in self.joints_out):
            full = C.attach_dropped(out, motion.skeleton, self.joints_out)
            src = dict(motion.source)
            src.pop("per_frame", None)
            return Motion(full, motion.skeleton, motion.fps, None, src)
        return Motion(out, self.output_skeleton(), motion.fps, None, {"refined_from": motion.source.get("path")})


@contextmanager
def _threads(torch: Any, n: int | None):
    """Run with ``n`` torch threads (default 1), restoring the previous setting."""
    prev = torch.get_num_threads()
    want = max(1, int(n or 1))
    if want != prev:
        torch.set_num_threads(want)
    try:
        yield
    finally:
        if want != prev:
            torch.set_num_threads(prev)


def _resample_back(X: np.ndarray, fps_model: float, fps: float, T: int) -> np.ndarray:
    """(T', K, 3) at fps_model -> (T, K, 3) at the motion's fps (cubic spline in time)."""
    if np.isclose(fps_model, fps) and len(X) == T:
        return X
    t_model = np.arange(len(X)) / fps_model
    t = np.clip(np.arange(T) / fps, 0.0, t_model[-1])
    flat = X.reshape(len(X), -1)
    if len(X) >= 4:
        from scipy.interpolate import CubicSpline

        Y = CubicSpline(t_model, flat, axis=0)(t)
    elif len(X) >= 2:
        Y = np.stack([np.interp(t, t_model, flat[:, c]) for c in range(flat.shape[1])], axis=1)
    else:
        Y = np.repeat(flat, T, axis=0)
    return Y.reshape(T, *X.shape[1:])


def make_meta(method: str, params: dict, joints_in: Sequence[str], joints_out: Sequence[str],
              parents_out: np.ndarray, offsets_out: np.ndarray, **extra: Any) -> dict:
    meta = {"format": FORMAT, "version": FORMAT_VERSION, "method": method, "params": dict(params),
            "joints_in": list(joints_in), "joints_out": list(joints_out),
            "parents_out": [int(p) for p in parents_out],
            "offsets_out": np.asarray(offsets_out, dtype=float).round(6).tolist(),
            "fps": C.FPS, "clip_frames": int(params.get("clip_frames", C.CLIP_FRAMES)),
            "clip_hop": int(params.get("clip_frames", C.CLIP_FRAMES)) // 2,
            "reference_sigma": float(params.get("reference_sigma", C.REFERENCE_SIGMA)),
            "up_axis": C.UP_AXIS, "postprocess": bool(params.get("postprocess", method == "bra-p"))}
    meta.update(extra)
    return meta
