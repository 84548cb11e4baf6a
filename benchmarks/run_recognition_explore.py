"""Exploration for issue #17: ensembles over views / seeds, HYDRA, test-time augmentation.

Usage::

    python benchmarks/run_recognition_explore.py cache               # series of MSR-Action3D (once)
    python benchmarks/run_recognition_explore.py fit COMPS FOLDS     # e.g. base0,arms cs,in1,in3
    python benchmarks/run_recognition_explore.py summarise           # -> docs/results/recognition_explore.json

Each *component* is one augmented MultiRocket (or HYDRA) + grouped-LOO ridge model on one
view of the clips (``base0``/``base1``: the joint trajectories of the default classifier,
transform seeds 0 / 1000; ``arms``: hand-relative arm trajectories, elbow/wrist - shoulder
and wrist - head per side, divided by the arm length; ``hydra``: HYDRA counts of the joint
trajectories and their difference instead of MultiRocket). Its ridge scores on the held-out
clips of each *fold* are cached; an ensemble is the sum of its components' scores (so any
subset is scored without refitting). Folds: ``in1 .. in9`` leave one TRAINING subject out
(subjects 1,3,5,7,9; the inner validation used to choose), ``cs`` the cross-subject test split
(transform seed 0), ``half0`` / ``half1`` the first two outer half/half splits, ``ih0`` /
``ih1`` a half split inside their training halves (inner, as ``run_recognition.py --select``). ``tta``: the
scores averaged over 4 perturbed copies of each test clip (time warp +-5 %, turn +-7.5 deg),
measured for ``base0`` on the folds where the cache has them. One BLAS thread; the data come
from the protocol cache (``mocapkit.bench.protocols.retrieval._recog_data``).
"""
from __future__ import annotations

import itertools
import json
import os
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
import numpy as np  # noqa: E402

CACHE = Path(os.environ.get("MOCAPKIT_EXPLORE_CACHE", "/tmp/h17"))
OUT = ROOT / "docs" / "results" / "recognition_explore.json"
from mocapkit.recognition.rocket import MiniRocket, POOLINGS, augment_series, ridge_group_loo, _difference, KERNEL_LENGTH
from mocapkit.bench.protocols.retrieval import _class_halves

KP = ("root","neck","head","lshoulder","lelbow","lwrist","rshoulder","relbow","rwrist","lhip","lknee","lankle","rhip","rknee","rankle")

def joint(X, j):
    return X[:, 3*j:3*j+3]                      # (n, 3, L); j>0 root-relative

def arms_view(X, kp, frame="none"):
    k = dict(zip(KP, kp))
    out = []
    parts = []
    for s in "lr":
        sh, el, wr = joint(X, k[s+"shoulder"]), joint(X, k[s+"elbow"]), joint(X, k[s+"wrist"])
        alen = np.median(np.linalg.norm(el-sh, axis=1) + np.linalg.norm(wr-el, axis=1), axis=1)[:, None, None]
        parts.append((el-sh)/alen); parts.append((wr-sh)/alen)
        parts.append((wr-joint(X, k["head"]))/alen)
    V = np.concatenate(parts, axis=1)          # (n, 18, L)
    if frame == "shoulders":
        d = (joint(X, k["lshoulder"]) - joint(X, k["rshoulder"])).mean(2)   # (n,3)
        ang = np.arctan2(d[:, 2], d[:, 0])[:, None, None]                    # rotate so l-r along x
        J3 = V.reshape(len(V), -1, 3, V.shape[2]).copy()
        x, z = J3[:, :, 0].copy(), J3[:, :, 2].copy()
        J3[:, :, 0] = np.cos(ang)*x + np.sin(ang)*z
        J3[:, :, 2] = -np.sin(ang)*x + np.cos(ang)*z
        V = J3.reshape(V.shape)
    return V

def clipstd_view(X, kp):
    m = X.mean(2, keepdims=True); s = X.std(2, keepdims=True)
    return (X - m) / np.maximum(s, 1e-3)

# ------------------------------------------------------------------- HYDRA (numpy)
class Hydra:
    def __init__(self, k=8, g=64, max_ch=3, seed=0):
        self.k, self.g, self.max_ch, self.seed = k, g, max_ch, seed
    def fit(self, X):
        n, C, L = X.shape
        rng = np.random.default_rng(self.seed)
        me = int(np.log2((L - 1) / (KERNEL_LENGTH - 1)))
        self.dil = 2 ** np.arange(me + 1)
        self.W = []
        for d in self.dil:
            W = rng.standard_normal((KERNEL_LENGTH, C, self.g * self.k))
            mask = np.zeros((C, self.g))
            for gi in range(self.g):
                mask[rng.choice(C, min(C, self.max_ch), replace=False), gi] = 1
            W -= W.mean(0, keepdims=True)
            W /= np.abs(W).sum(0, keepdims=True)
            W *= np.repeat(mask, self.k, axis=1)[None]
            self.W.append(W)
        return self
    def transform(self, X):
        n, C, L = X.shape
        out = []
        for d, W in zip(self.dil, self.W):
            pad = (KERNEL_LENGTH - 1) * d // 2
            Xp = np.zeros((n, L + 2*pad, C)); Xp[:, pad:pad+L] = X.transpose(0, 2, 1)
            Z = np.zeros((n, L, W.shape[2]))
            for t in range(KERNEL_LENGTH):
                Z += Xp[:, t*d:t*d+L] @ W[t]
            Z = Z.reshape(n, L, self.g, self.k)
            imax = Z.argmax(3); vmax = Z.max(3); imin = Z.argmin(3)
            oh = np.arange(self.k)[None, None, None, :]
            cmax = ((imax[..., None] == oh) * vmax[..., None]).sum(1)       # (n,g,k)
            cmin = (imin[..., None] == oh).sum(1).astype(float)
            out += [cmax.reshape(n, -1), cmin.reshape(n, -1)]
        F = np.concatenate(out, 1)
        return np.sqrt(np.clip(F, 0, None))

# ------------------------------------------------------------------- classifier
class Clf:
    def __init__(self, views=("base",), n_features=5000, seeds=(0,), augment=2, hydra=False, tta=0, seed=0, kp=None,
                 rocket=True, pooling=POOLINGS):
        self.__dict__.update(dict(views=views, n_features=n_features, seeds=seeds, augment=augment, hydra=hydra,
                                  tta=tta, seed=seed, kp=kp, rocket=rocket, pooling=pooling))
    def _views(self, X):
        out = []
        for v in self.views:
            if v == "base": out.append(X)
            elif v == "arms": out.append(arms_view(X, self.kp))
            elif v == "arms-sh": out.append(arms_view(X, self.kp, "shoulders"))
            elif v == "clipstd": out.append(clipstd_view(X, self.kp))
        return out
    def fit(self, X, y):
        V = self._views(X)
        self.tr = []
        for vi, Xv in enumerate(V):
            for s in self.seeds:
                sd = self.seed + 100 * vi + 2 * s
                if self.rocket:
                    self.tr.append(("r", 0, MiniRocket(n_features=self.n_features, pooling=self.pooling, seed=sd).fit(Xv)))
                    self.tr.append(("r", 1, MiniRocket(n_features=self.n_features, pooling=self.pooling, seed=sd+1).fit(_difference(Xv))))
                if self.hydra:
                    self.tr.append(("h", 0, Hydra(seed=sd + 50).fit(Xv)))
                    self.tr.append(("h", 1, Hydra(seed=sd + 51).fit(_difference(Xv))))
        rng = np.random.default_rng([self.seed, 7])
        Xa, owner = augment_series(X, self.augment, rng)
        F = self.feats(np.concatenate([X, Xa]))
        groups = np.concatenate([np.arange(len(X)), owner]); ya = y[groups]
        self.mu = F.mean(0); sd = F.std(0); self.sc = np.where(sd > 1e-12, sd, 1.0)
        F = (F - self.mu) / self.sc
        self.classes = np.unique(y)
        Y = np.where(ya[:, None] == self.classes[None], 1.0, -1.0)
        self.alpha, A, _ = ridge_group_loo(F, Y, groups, np.logspace(-3, 5, 17))
        self.coef = F.T @ A; self.icpt = Y.mean(0)
        return self
    def feats(self, X):
        V = self._views(X)
        Fs = []
        i = 0
        per = len(self.tr) // len(V)
        for vi, Xv in enumerate(V):
            D = _difference(Xv)
            for kind, isd, t in self.tr[vi*per:(vi+1)*per]:
                Fs.append(t.transform(D if isd else Xv))
        return np.concatenate(Fs, 1)
    def predict(self, X):
        S = ((self.feats(X) - self.mu) / self.sc) @ self.coef + self.icpt
        if self.tta:
            rng = np.random.default_rng([self.seed, 11])
            Xa, owner = augment_series(X, self.tta, rng, time_warp=0.05, rot_deg=7.5)
            Sa = ((self.feats(Xa) - self.mu) / self.sc) @ self.coef + self.icpt
            for c in range(S.shape[1]):
                S[:, c] += np.bincount(owner, Sa[:, c], len(X))
        return self.classes[S.argmax(1)]



def cache() -> None:
    from mocapkit import bench
    from mocapkit.bench.protocols import retrieval as R
    from mocapkit.datasets import shared_data_dir
    from mocapkit.recognition.rocket import series_keypoints

    ctx = bench.Context(data_dir=shared_data_dir(None), progress=False)
    CACHE.mkdir(parents=True, exist_ok=True)
    for which in ("msr", "hdm"):
        D = R._recog_data(ctx, which)
        kp = series_keypoints(R._motions(ctx, which)[0][3].skeleton)
        full = dict(zip(KP, [0] * len(KP)))
        full.update(zip(("head", "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist"), kp))
        np.savez(CACHE / f"{which}.npz", X=D["X"], y=D["labels"], g=D["groups"].astype(str),
                 kp=np.array([full[k] for k in KP]))


def load(which):
    d = np.load(CACHE / f"{which}.npz")
    return d["X"], d["y"], d["g"], d["kp"]


COMP = {"base0": {}, "base1": {"seed_off": 1}, "arms": {"views": ("arms",)}, "hydra": {"hydra": True, "rocket": False},
        "clipstd": {"views": ("clipstd",)}}


def folds(y, g):
    gi = g.astype(int)
    tr_cs = np.flatnonzero(gi % 2 == 1)
    out = {f"in{s}": (tr_cs[gi[tr_cs] != s], tr_cs[gi[tr_cs] == s]) for s in (1, 3, 5, 7, 9)}
    out["cs"] = (np.flatnonzero(gi % 2 == 1), np.flatnonzero(gi % 2 == 0))
    for s in (0, 1):
        out[f"half{s}"] = _class_halves(y, s)
        tr = _class_halves(y, s)[0]
        a, b = _class_halves(y[tr], 100 + s)        # inner half split (as run_recognition.py --select)
        out[f"ih{s}"] = (tr[a], tr[b])
    return out


def fit(comps, fold_names) -> None:
    X, y, g, kp = load("msr")
    F = folds(y, g)
    for comp in comps:
        for fold in fold_names:
            fn = CACHE / f"sc_{comp}_{fold}.npz"
            if fn.exists():
                continue
            a, b = F[fold]
            kw = dict(COMP[comp])
            off = kw.pop("seed_off", 0)
            t0 = time.time()
            c = Clf(kp=kp, seed=1000 if off else 0, **kw).fit(X[a], y[a])
            t1 = time.time()
            S = ((c.feats(X[b]) - c.mu) / c.sc) @ c.coef + c.icpt
            np.savez(fn, S=S, St=S, b=b, classes=c.classes, fit=t1 - t0, pred=time.time() - t1)
            print(comp, fold, f"{100 * np.mean(c.classes[S.argmax(1)] == y[b]):.1f}", flush=True)


def _acc(y, comps, fold, key="S"):
    S = None
    for c in comps:
        fn = CACHE / f"sc_{c}_{fold}.npz"
        if not fn.exists():
            return None
        z = np.load(fn)
        S = z[key] if S is None else S + z[key]
        b, cl = z["b"], z["classes"]
    return int((cl[S.argmax(1)] == y[b]).sum()), int(len(b))


def summarise() -> list[dict]:
    _, y, _, _ = load("msr")
    rows = []
    for r in range(1, 4):
        for cs in itertools.combinations(list(COMP), r):
            out = {"ensemble": "+".join(cs)}
            inner = [_acc(y, cs, f"in{s}") for s in (1, 3, 5, 7, 9)]
            if all(inner):
                out["inner_cs"] = sum(a for a, _ in inner) / sum(n for _, n in inner)
            inner = [_acc(y, cs, f"ih{s}") for s in (0, 1)]
            if all(inner):
                out["inner_half"] = sum(a for a, _ in inner) / sum(n for _, n in inner)
            for f in ("cs", "half0", "half1"):
                a = _acc(y, cs, f)
                if a:
                    out[f] = a[0] / a[1]
            if len(out) > 1:
                rows.append(out)
    # folds whose base0 cache holds TTA scores (the run of 2026-12-01; in9's was overwritten by a
    # rerun without TTA: its log line read 55/57 without, 54/57 with TTA)
    tta = {f: _acc(y, ["base0"], f, "St") for f in ("cs", "in1", "in3", "in5", "in7")}
    plain = {f: _acc(y, ["base0"], f) for f in tta}
    rows.append({"ensemble": "base0 + test-time augmentation (4 copies)",
                 "folds": {f: [plain[f][0], tta[f][0], tta[f][1]] for f in tta if tta[f]}})
    OUT.write_text(json.dumps(rows, indent=1))
    return rows


if __name__ == "__main__":
    cmd = sys.argv[1] if len(sys.argv) > 1 else "summarise"
    if cmd == "cache":
        cache()
    elif cmd == "fit":
        fit(sys.argv[2].split(","), sys.argv[3].split(","))
    else:
        for r in summarise():
            print(r)
