"""Search speed of a 10,000-clip motion index (issue #8 target: < 50 ms per query).

The library is made of real motion: random 1-4 s crops of the HDM05 clips (120 fps) and
of the MSR-Action3D sequences (15 fps) in ../shared/data, each crop described like a file
(HOD + GPF frames). An AMFS index (d = 30 % of the features, 128-word codebook learnt on
3,000 crops) is built, saved and loaded; then 200 held-out crops are searched (k = 10).
Per query we time, separately: feature extraction from the motion (``describe``), the
embedding (LLC coding + selection) and the ranking over the whole index; the ranking is
checked against a brute-force ``argsort`` of every distance.

Writes docs/results/retrieval_speed.json. Run:
``.venv/bin/python benchmarks/retrieval_speed.py [--n 10000] [--data DIR]``
"""
from __future__ import annotations

import argparse
import json
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit import io  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402
from mocapkit.errors import MocapError  # noqa: E402
from mocapkit.retrieval.index import MotionIndex, RetrievalModel, describe  # noqa: E402

OUT = ROOT / "docs" / "results" / "retrieval_speed.json"


def sources(data: Path) -> list[tuple[str, object]]:
    out = []
    for f in sorted((data / "hdm05" / "asfamc").glob("*/HDM_*.amc")):
        out.append((f.parent.name, io.read(f)))
    for f in sorted((data / "msr_action3d" / "skeleton3d").glob("a*_skeleton3D.txt")):
        m = io.read(f)
        if m.observed.any():
            out.append((re.match(r"(a\d\d)", f.name).group(1), m))
    return out


def crops(src, n: int, rng) -> tuple[list, list[str]]:
    """n described random crops (1-4 s, at least 10 frames) of the source motions."""
    descs, labels = [], []
    while len(descs) < n:
        lab, m = src[rng.integers(len(src))]
        length = max(10, int(rng.uniform(1.0, 4.0) * m.fps))
        if m.n_frames <= length:
            sub = m
        else:
            s = int(rng.integers(0, m.n_frames - length))
            sub = m.slice(s, s + length)
        try:
            descs.append(describe(sub))
        except MocapError:
            continue
        labels.append(lab)
    return descs, labels


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--data")
    ap.add_argument("--out", type=Path, default=OUT)
    a = ap.parse_args()
    data = shared_data_dir(a.data)
    if data is None:
        raise SystemExit("shared data not found (--data DIR)")
    rng = np.random.default_rng(0)
    src = sources(data)
    t0 = time.perf_counter()
    descs, labels = crops(src, a.n, rng)
    t_describe = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = RetrievalModel("amfs", d=0.3, max_fit=3000).fit(descs)
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    emb = model.embed(descs)
    t_embed = time.perf_counter() - t0
    index = MotionIndex(model, emb, [f"crop{i:05d}" for i in range(len(descs))], labels)
    with tempfile.TemporaryDirectory() as tmp:
        path = index.save(Path(tmp) / "lib.idx")
        size_mb = path.stat().st_size / 2 ** 20
        t0 = time.perf_counter()
        index = MotionIndex.load(path)
        t_load = time.perf_counter() - t0

    # held-out queries, motions kept so feature extraction is timed too
    qrng = np.random.default_rng(1)
    q_motions = []
    while len(q_motions) < a.queries:
        _, m = src[qrng.integers(len(src))]
        length = max(10, int(qrng.uniform(1.0, 4.0) * m.fps))
        s = int(qrng.integers(0, max(m.n_frames - length, 1)))
        sub = m.slice(s, min(s + length, m.n_frames))
        if sub.observed.any():
            q_motions.append(sub)
    t_desc, t_emb, t_rank, agree = [], [], [], 0
    for m in q_motions:
        t0 = time.perf_counter()
        d = describe(m)
        t1 = time.perf_counter()
        q = index.model.embed([d])[0]
        t2 = time.perf_counter()
        idx, dist = index.search_embedding(q, 10)
        t3 = time.perf_counter()
        t_desc.append(t1 - t0)
        t_emb.append(t2 - t1)
        t_rank.append(t3 - t2)
        # brute force: the 10 smallest of all distances (compared as distances: crops of a
        # clip shorter than the crop length are identical, so tied indices may differ)
        ref = np.sort(np.linalg.norm(index.emb.astype(np.float64) - q, axis=1))[:10]
        agree += int(np.allclose(ref, dist, rtol=1e-5, atol=1e-6))
    ms = lambda v: {"median": 1000 * float(np.median(v)), "p95": 1000 * float(np.percentile(v, 95))}  # noqa: E731
    res = {
        "n_indexed": len(descs), "n_queries": len(q_motions), "k": 10,
        "embedding_dim": int(index.emb.shape[1]), "index_file_mb": round(size_mb, 2),
        "build_seconds": {"describe": t_describe, "fit_selection": t_fit, "embed": t_embed},
        "load_seconds": t_load,
        "query_ms": {"describe": ms(t_desc), "embed": ms(t_emb), "rank": ms(t_rank),
                     "embed_plus_rank": ms(np.add(t_emb, t_rank)),
                     "total": ms(np.add(np.add(t_desc, t_emb), t_rank))},
        "top10_equal_to_bruteforce": f"{agree}/{len(q_motions)}",
        "machine": f"{platform.processor() or platform.machine()}, {platform.python_version()}",
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
