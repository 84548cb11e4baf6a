"""A trained BRA / BRA-P model: networks + normalisation + joint lists, save/load, inference.

Two file formats, chosen by the suffix:

``.onnx`` (what ships, inference without torch, issue 20): ``<name>.onnx`` holds the
denoising network (input ``x`` (B, f, m) float32 -> outputs ``y`` (B, f, n), ``h``
(B, f, hidden)), ``<name>.perceptual.onnx`` the perceptual autoencoder of a BRA-P model
(``x`` (B, f, n) -> ``y``, ``h``). The first file's ONNX metadata entry ``mocapkit``
is a JSON object: ``meta`` (below) and the normalisation ``mean_in``, ``std_in``,
``mean_out``, ``std_out``. Read with onnxruntime (a core dependency); written by
:meth:`Bundle.export_onnx`, which needs torch and onnx (the ``neural`` extra) and is
only called by training / export scripts, never at run time.

``.pt`` (training output, needs torch: ``torch.save`` of a flat dict, read back with
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
FORMAT_VERSION = 2
"""2: issue 20 (residual / fill / mask parameters in ``params``); version 1 files load too."""
SUPPORTED_VERSIONS = (1, 2)
ONNX_OPSET = 17


class OnnxNet:
    """An exported network run with onnxruntime: ``run(x) -> (y, h)`` on float32 arrays."""

    def __init__(self, path: str | os.PathLike):
        self.path = os.fspath(path)
        self._sessions: dict[int, Any] = {}
        self._session(1)

    def _session(self, threads: int):
        s = self._sessions.get(threads)
        if s is None:
            try:
                import onnxruntime as ort
            except ImportError:
                from ..errors import MissingDependencyError

                raise MissingDependencyError("the neural methods (bra, bra-p) need onnxruntime: "
                                             "pip install onnxruntime==1.31.1") from None
            so = ort.SessionOptions()
            so.intra_op_num_threads = int(threads)
            so.inter_op_num_threads = 1
            so.log_severity_level = 3
            try:
                s = ort.InferenceSession(self.path, so, providers=["CPUExecutionProvider"])
            except FileNotFoundError:
                raise MocapValueError(f"{self.path}: no such model file") from None
            except Exception as e:  # noqa: BLE001 - a broken / foreign file
                raise MocapFormatError(self.path, f"not a readable ONNX model ({type(e).__name__}: {e})") from None
            self._sessions[threads] = s
        return s

    def metadata(self) -> dict[str, str]:
        return dict(self._session(1).get_modelmeta().custom_metadata_map)

    def run(self, x: np.ndarray, threads: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        s = self._session(max(1, int(threads or 1)))
        y, h = s.run(["y", "h"], {"x": np.ascontiguousarray(x, dtype=np.float32)})
        return y, h

    def eval(self) -> "OnnxNet":
        return self


def _is_onnx(path: str | os.PathLike) -> bool:
    return os.fspath(path).lower().endswith(".onnx")


def perceptual_onnx_path(path: str | os.PathLike) -> str:
    """``x/bra-p.onnx`` -> ``x/bra-p.perceptual.onnx``."""
    p = os.fspath(path)
    return p[:-len(".onnx")] + ".perceptual.onnx"


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
    def input_channels(self) -> int:
        """m: positions (3K), their high-pass part when ``base_sigma`` > 0 (3K), mask (K)."""
        return _input_channels(self.meta)

    @property
    def same_topology(self) -> bool:
        return self.joints_in == self.joints_out

    def output_skeleton(self) -> Skeleton:
        return Skeleton(tuple(self.joints_out), self.parents_out,
                        np.asarray(self.meta["offsets_out"], dtype=float))

    # -- persistence -------------------------------------------------------------------------
    def save(self, path: str | os.PathLike, *, half: bool = False) -> None:
        """Write ``.pt`` (torch) or, for a ``.onnx`` path, :meth:`export_onnx`."""
        if _is_onnx(path):
            self.export_onnx(path)
            return
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
        """Read a ``.onnx`` (onnxruntime, no torch) or ``.pt`` (torch) model."""
        if _is_onnx(path):
            return cls._load_onnx(path)
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
        _check_version(path, meta)
        p = meta["params"]
        m, n = _input_channels(meta), 3 * len(meta["joints_out"])
        nets = {}
        for prefix, mm in (("denoise", m), ("perceptual", n)):
            sd = {k[len(prefix) + 1:]: v.float() if v.is_floating_point() else v
                  for k, v in d.items() if k.startswith(prefix + ".")}
            if not sd:
                nets[prefix] = None
                continue
            net = build(mm, n, int(p["hidden"]), float(p["dropout"]),
                        residual=bool(p.get("residual", False)) and prefix == "denoise",
                        wide=bool(p.get("wide_fc", False)) and prefix == "denoise")
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

    @classmethod
    def _load_onnx(cls, path: str | os.PathLike) -> "Bundle":
        if not os.path.isfile(path):
            raise MocapValueError(f"{path}: no such model file")
        net = OnnxNet(path)
        try:
            head = json.loads(net.metadata()["mocapkit"])
            meta = head["meta"]
        except (KeyError, ValueError, TypeError):
            raise MocapFormatError(path, "not a mocapkit neural model (no 'mocapkit' ONNX metadata)") from None
        if meta.get("format") != FORMAT:
            raise MocapFormatError(path, "not a mocapkit neural model (no 'mocapkit-neural' header)")
        _check_version(path, meta)
        pp = perceptual_onnx_path(path)
        perc = OnnxNet(pp) if meta.get("has_perceptual") and os.path.isfile(pp) else None
        if meta.get("has_perceptual") and perc is None:
            raise MocapFormatError(path, f"the perceptual network {os.path.basename(pp)} is missing next to it")
        norm_in = C.Normaliser(np.asarray(head["mean_in"], float), float(head["std_in"]))
        norm_out = C.Normaliser(np.asarray(head["mean_out"], float), float(head["std_out"]))
        return cls(net, perc, norm_in, norm_out, meta)

    def export_onnx(self, path: str | os.PathLike) -> list[str]:
        """Write the networks as ONNX (module docstring); needs torch and onnx. Returns the files."""
        torch = require_torch()
        if isinstance(self.denoise_net, OnnxNet):
            raise MocapValueError("this model is already an ONNX model")
        from ..io._atomic import atomic_write

        meta = dict(self.meta)
        meta["format"], meta["version"] = FORMAT, FORMAT_VERSION
        meta["has_perceptual"] = self.perceptual_net is not None
        meta["dtype"] = "float32"
        head = {"meta": meta, "mean_in": self.norm_in.mean.tolist(), "std_in": self.norm_in.std,
                "mean_out": self.norm_out.mean.tolist(), "std_out": self.norm_out.std}
        out = []
        for net, target, extra in ((self.denoise_net, os.fspath(path), {"mocapkit": json.dumps(head)}),
                                   (self.perceptual_net, perceptual_onnx_path(path), {})):
            if net is None:
                continue
            data = _export_one(torch, net, extra)
            atomic_write(target, lambda f, d=data: f.write(d), binary=True)
            out.append(target)
        return out

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
        post = self.meta.get("postprocess", True) if postprocess is None else postprocess
        post = bool(post) and self.perceptual_net is not None
        if isinstance(self.denoise_net, OnnxNet):
            out = []
            for s in range(0, len(Z), batch):
                y, _ = self.denoise_net.run(Z[s:s + batch], threads)
                if post:
                    y, _ = self.perceptual_net.run(y, threads)
                out.append(y)
            return np.concatenate(out, axis=0).astype(np.float64)
        torch = require_torch()
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
        if self.perceptual_net is None:
            raise MocapValueError("this model has no perceptual autoencoder (a BRA model)")
        if isinstance(self.perceptual_net, OnnxNet):
            return self.perceptual_net.run(Z, threads)[1].astype(np.float64)
        torch = require_torch()
        self.perceptual_net.eval()
        with _threads(torch, threads), torch.inference_mode():
            h = self.perceptual_net.encode(torch.from_numpy(np.ascontiguousarray(Z, dtype=np.float32)))
        return h.numpy().astype(np.float64)

    def run_turned(self, W: np.ndarray, turns: int = 1, **kw) -> np.ndarray:
        """:meth:`run_windows` averaged over ``turns`` rotations of the windows about the
        vertical (by 360/turns degrees; each output turned back), a test-time average
        over the rotation the network was trained to be indifferent to.

        Only for networks trained rotation-augmented (``params['augment']``: their mean
        pose is horizontally centred, so a turn of the normalised channels is a turn of
        the positions); others, and ``turns=1``, run once. Measured on 9 held-out clips
        at 3 cm noise (a bra-p checkpoint at 4,800 steps): 1.050 cm with one pass, 1.037
        with 2 turns, 1.032 with 4 (mixed noise 1.158 / 1.150 / 1.143); the shipped bra-p
        on the 30 held-out motions of ``bra-heldout`` (constant bones): 0.946 with one
        pass, 0.936 with 4. 4 turns cost 4 network passes.
        """
        p = self.meta.get("params", {})
        turns = max(int(turns or 1), 1)
        if turns == 1 or not p.get("augment"):
            return self.run_windows(W, **kw)
        up = int(self.meta.get("up_axis", C.UP_AXIS))
        n_pos = self.input_channels - (len(self.joints_in) if p.get("mask_input") else 0)   # not the mask
        angles = 2 * np.pi * np.arange(turns) / turns
        stack = np.concatenate([_turn(W, a, n_pos, up) for a in angles])
        Y = self.run_windows(stack, **kw).reshape(turns, len(W), *W.shape[1:2], -1)
        n_out = Y.shape[-1]
        return np.mean([_turn(y, -a, n_out, up) for y, a in zip(Y, angles)], axis=0)

    def refine_local(self, P: np.ndarray, observed: np.ndarray, *, postprocess: bool | None = None,
                     threads: int | None = None, network: bool = True, turns: int = 1,
                     constant_bones: bool = False) -> np.ndarray:
        """Refine 60-fps positions of the input joints (T, K_in, 3) cm -> (T, K_out, 3) cm.

        ``P`` may hold NaN where ``observed`` is False. Horizontal reference, normalisation,
        clipping and the cross-fade reassembly are done here (module :mod:`clips`);
        ``turns``: :meth:`run_turned`; ``constant_bones``: the output's bones are set to
        their median lengths (:func:`clips.project_bones`).
        """
        P = np.asarray(P, dtype=np.float64)
        T, K, _ = P.shape
        up = int(self.meta.get("up_axis", C.UP_AXIS))
        ref = C.ground_reference(P[:, 0], observed[:, 0], sigma=float(self.meta["reference_sigma"]),
                                 up_axis=up, fallback=C.joint_mean_track(P))
        local = np.where(observed[..., None], P, np.nan) - ref[:, None, :]
        self._check_scale(local, observed)
        p = self.meta.get("params", {})
        Z = C.model_input(self.norm_in.forward(local.reshape(T, -1)), observed,
                          fill=bool(p.get("fill_input", False)), mask=bool(p.get("mask_input", False)),
                          base_sigma=float(p.get("base_sigma", 0.0) or 0.0),
                          highpass_gain=float(p.get("highpass_gain", 1.0) or 1.0),
                          base_filter=str(p.get("base_filter", "lowpass")),
                          reference=C.reference_channels(ref, K, self.norm_in))
        f = int(self.meta["clip_frames"])
        W, starts, left = C.split_clips(Z, f, int(self.meta["clip_hop"]))
        if network:
            Y = self.run_turned(W, turns, postprocess=postprocess, threads=threads)
        else:                     # the residual base alone (what the network corrects)
            Y = W[..., :3 * len(self.joints_out)]
        out = self.norm_out.inverse(C.overlap_add(Y, starts, T, left))
        out = out.reshape(T, -1, 3) + ref[:, None, :]
        return C.project_bones(out, self.parents_out) if constant_bones and network else out

    #: the input's body may be this much smaller or larger than the training bodies
    SCALE_RANGE = (0.4, 2.5)

    def _check_scale(self, local: np.ndarray, observed: np.ndarray) -> None:
        """Refuse a body whose size is far from the training data's (issue 18: a clip in
        metres or millimetres came back tens of cm off).  Size = the median over frames
        (with >= 3 observed joints) of the RMS distance of the joints from their centroid,
        compared with the same for the training clips (``meta['body_size_cm']``; older
        models: the training mean pose ``norm_in.mean``)."""
        size = C.body_size(local, observed)
        ref = self.meta.get("body_size_cm")
        if ref is None:      # older models: the training mean pose
            mp = self.norm_in.mean.reshape(-1, 3)
            ref = float(np.sqrt(((mp - mp.mean(axis=0)) ** 2).sum(axis=1).mean()))
        ref = float(ref)
        if not (ref > 0 and np.isfinite(size)):
            return
        lo, hi = self.SCALE_RANGE
        if not lo <= size / ref <= hi:
            raise MocapValueError(
                f"the motion's body is {size / ref:.3g} times the size of the bodies this network "
                f"was trained on (joint spread {size:.3g} cm vs {ref:.3g} cm): check the units "
                f"(metres or millimetres read as cm?) or train on such data")

    def refine(self, motion: Motion, *, postprocess: bool | None = None, threads: int | None = None,
               network: bool = True, turns: int = 1, constant_bones: bool = False) -> Motion:
        """Refine a whole motion.

        Same topology: returns a Motion with the input's skeleton, frames and fps (joints
        outside the model's subset: the input's own smoothed tracks, or following their kept
        ancestor where the input misses them, :func:`clips.attach_dropped`).
        Different topology: a Motion on the model's output skeleton, same frames and fps.
        ``network=False`` skips the network (a residual model's base filter alone, for
        measuring what the network adds).
        """
        C.check_joints(motion.skeleton, self.joints_in)
        fps = float(self.meta["fps"])
        lo, hi = self.meta.get("fps_range", FPS_RANGE)
        if not lo <= float(motion.fps) <= hi:
            raise MocapValueError(
                f"the motion is at {float(motion.fps):g} fps; this network was trained at {fps:g} fps "
                f"and accepts {lo:g}-{hi:g} fps inputs (resampled to {fps:g}): resample it first "
                f"(Motion.resample) only if its motion is smooth at that rate")
        P, obs = C.prepare_positions(motion, self.joints_in, fps)
        if not obs.any():
            raise MocapValueError("the motion has no observed value of the model's joints")
        out = self.refine_local(P, obs, postprocess=postprocess, threads=threads, network=network, turns=turns,
                                constant_bones=constant_bones)
        out = _resample_back(out, fps, motion.fps, motion.n_frames)
        if self.same_topology or all(j in motion.skeleton.names for j in self.joints_out):
            from ..signal import estimate_noise

            sigma = estimate_noise(motion.matrix(), motion.matrix_mask(), pool="all", fallback=0.0)
            full = C.attach_dropped(out, motion.skeleton, self.joints_out, source=motion.positions,
                                    source_observed=motion.observed)
            full = clean_blend(full, motion.positions, motion.observed, sigma,
                               float(self.meta.get("clean_blend_cm", CLEAN_BLEND_CM)))
            src = dict(motion.source)
            src.pop("per_frame", None)
            return Motion(full, motion.skeleton, motion.fps, None, src)
        return Motion(out, self.output_skeleton(), motion.fps, None, {"refined_from": motion.source.get("path")})


def _turn(W: np.ndarray, angle: float, n: int, up: int) -> np.ndarray:
    """W (..., C) with its first ``n`` channels (x, y, z triplets) turned by ``angle``
    (radians) about axis ``up`` (:func:`clips.turn`); the other channels (the mask) unchanged."""
    out = np.array(W, dtype=np.float64, copy=True)
    out[..., :n] = C.turn(out[..., :n].reshape(*W.shape[:-1], -1, 3), angle, up).reshape(*W.shape[:-1], n)
    return out


CLEAN_BLEND_CM = 0.3
"""Noise level (cm) at which :func:`clean_blend` gives the input and the network equal weight."""


def clean_blend(out: np.ndarray, inp: np.ndarray, observed: np.ndarray, noise_cm: float,
                sigma0: float = CLEAN_BLEND_CM) -> np.ndarray:
    """"Do no harm" on near-clean input (issue 20): observed samples become
    ``w inp + (1 - w) out`` with ``w = 1 / (1 + (noise_cm / sigma0)^2)``, ``noise_cm`` the
    input's robust noise estimate (:func:`mocapkit.signal.estimate_noise`, ``pool="all"``).

    The network corrects a smoothed input (:func:`clips.model_input`; the low-pass base
    of the earlier models costs a clean fast motion up to ~0.6 cm); a clean capture (estimated noise ~0.05 cm,
    w ~ 0.97) thus comes back as it was, while at 1 cm noise w = 0.08 and at 3 cm 0.01
    (the network's result). ``sigma0 <= 0`` turns the blend off. Missing samples keep the
    network's value.
    """
    if not sigma0 or sigma0 <= 0:
        return out
    w = 1.0 / (1.0 + (float(noise_cm) / float(sigma0)) ** 2)
    if w < 1e-4:
        return out
    res = np.array(out, dtype=np.float64)
    obs = np.asarray(observed, bool)
    res[obs] = w * np.asarray(inp, dtype=np.float64)[obs] + (1 - w) * res[obs]
    return res


def _input_channels(meta: dict) -> int:
    p, k = meta.get("params", {}), len(meta["joints_in"])
    return 3 * k * (2 if float(p.get("base_sigma", 0.0) or 0.0) > 0 else 1) + (k if p.get("mask_input") else 0)


def _check_version(path, meta: dict) -> None:
    if meta.get("version") not in SUPPORTED_VERSIONS:
        raise MocapFormatError(path, f"neural model format version {meta.get('version')} is not "
                                     f"supported (expected one of {SUPPORTED_VERSIONS})")


def _export_one(torch: Any, net: Any, metadata: dict[str, str]) -> bytes:
    """ONNX bytes of a MotionAutoencoder (inputs x; outputs y, h; dynamic batch and frames)."""
    import io as _io
    import warnings

    import onnx

    class _Wrap(torch.nn.Module):
        def __init__(self, n):
            super().__init__()
            self.n = n

        def forward(self, x):
            return self.n(x)

    net = net.cpu().eval()
    x = torch.zeros(2, 120, net.m)
    buf = _io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(_Wrap(net), (x,), buf, input_names=["x"], output_names=["y", "h"],
                          dynamic_axes={"x": {0: "batch", 1: "frames"}, "y": {0: "batch", 1: "frames"},
                                        "h": {0: "batch", 1: "frames"}},
                          opset_version=ONNX_OPSET, dynamo=False)
    model = onnx.load_from_string(buf.getvalue())
    for k, v in metadata.items():
        e = model.metadata_props.add()
        e.key, e.value = k, v
    onnx.checker.check_model(model)
    return model.SerializeToString()


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


FPS_RANGE = (24.0, 1000.0)
"""Input frame rates accepted (resampled to the model's 60 fps); below 24 fps the cubic
upsampling invents the motion between samples and the network was never trained on it."""


def make_meta(method: str, params: dict, joints_in: Sequence[str], joints_out: Sequence[str],
              parents_out: np.ndarray, offsets_out: np.ndarray, **extra: Any) -> dict:
    meta = {"format": FORMAT, "version": FORMAT_VERSION, "method": method, "params": dict(params),
            "joints_in": list(joints_in), "joints_out": list(joints_out),
            "parents_out": [int(p) for p in parents_out],
            "offsets_out": np.asarray(offsets_out, dtype=float).round(6).tolist(),
            "fps": C.FPS, "clip_frames": int(params.get("clip_frames", C.CLIP_FRAMES)),
            "clip_hop": int(params.get("clip_frames", C.CLIP_FRAMES)) // 2,
            "reference_sigma": float(params.get("reference_sigma", C.REFERENCE_SIGMA)),
            "up_axis": C.UP_AXIS, "postprocess": bool(params.get("postprocess", method == "bra-p")),
            "fps_range": list(FPS_RANGE)}
    meta.update(extra)
    return meta
