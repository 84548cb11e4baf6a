"""NMC parameter sweep on inner validation folds (never the test halves).

For outer splits 0 and 1 of ``nmc-recognition`` (a random half of each MSR-Action3D class
for training), the training half is split again in halves per class; each NMC setting is
trained on the inner half and scored on the other (transductive, as the thesis). Shows
whether a different setting would close the gap to the thesis' 93.33 %.

Writes docs/results/nmc_sweep.json (rendered by benchmarks/run_retrieval.py). Run:
``.venv/bin/python benchmarks/nmc_sweep.py [--data DIR]`` (~3 min on 2 cores).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from mocapkit.bench.core import Context  # noqa: E402
from mocapkit.bench.protocols import retrieval as R  # noqa: E402
from mocapkit.datasets import shared_data_dir  # noqa: E402
from mocapkit.recognition.nmc import NMCClassifier  # noqa: E402

CONFIGS = [{}, {"n_clusters": 64}, {"n_clusters": 256}, {"window": 6, "stride": 3},
           {"window": 15, "stride": 5}, {"window": 10, "stride": 2}, {"bow_levels": (1, 2, 4)},
           {"C": 1.0}, {"C": 100.0}, {"block_weights": (1.0, 0.5)}, {"block_weights": (1.0, 2.0)},
           {"lam2": 0.0}, {"lam2": 0.1}, {"eta": 1.0},
           # the thesis' own window (Sec. 6.3.4: "stride M/2 which is 30", i.e. M = 60 frames;
           # MSR-Action3D clips average 40 frames, so mostly one window per clip)
           {"window": 20, "stride": 10}, {"window": 60, "stride": 30}]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "nmc_sweep.json")
    a = ap.parse_args()
    ctx = Context(data_dir=shared_data_dir(a.data), progress=False)
    items, labels, _, _ = R._cached(ctx, "msr", "prep")
    P = [it[0] for it in items]
    rows = []
    with R._one_thread():
        for cfg in CONFIGS:
            accs, t0 = [], time.perf_counter()
            for outer in (0, 1):
                tr, _ = R._class_halves(labels, outer)
                i_tr, i_va = R._class_halves(labels[tr], 100 + outer)
                i_tr, i_va = tr[i_tr], tr[i_va]
                m = NMCClassifier(seed=0, **cfg).fit([P[i] for i in i_tr], labels[i_tr],
                                                     test_seqs=[P[i] for i in i_va])
                accs.append(float((m.predict() == labels[i_va]).mean()))
            rows.append({"change": {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()},
                         "accuracy": accs, "mean": float(np.mean(accs)),
                         "seconds": time.perf_counter() - t0})
            print(rows[-1], flush=True)
    a.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
