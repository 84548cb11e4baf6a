"""Motion retrieval (thesis seed 003 Ch. 5): HOD / GPF bag-of-words features, AMFS
feature selection with its baselines, and a searchable index of a motion library.

Entry points used by the CLI::

    build_index(paths_or_dir, output, progress=True, *, method="amfs", d=0.3, ...) -> dict
    search(index_path, query_path, k=10) -> list[(path, distance)]
"""
from .amfs import AMFS, laplacian_score, spec_score, udfs_score
from .evaluate import average_precision, retrieval_scores
from .features import GPFCodebook, Prepared, find_keypoints, gpf, hod, prepare
from .index import MotionIndex, RetrievalModel, build_index, describe, label_of, search

__all__ = ["AMFS", "laplacian_score", "spec_score", "udfs_score", "average_precision",
           "retrieval_scores", "GPFCodebook", "Prepared", "find_keypoints", "gpf", "hod",
           "prepare", "MotionIndex", "RetrievalModel", "build_index", "describe", "label_of",
           "search"]
