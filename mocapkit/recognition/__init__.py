"""Action recognition (thesis seed 003 Ch. 6): NMF-based motion clustering (NMC) with a
bag-of-words classifier, and a skeleton-sequence classifier as the modern reference.

Entry points used by the CLI::

    train_classifier(paths_or_dir, output, labels=None, progress=True, *, C=1.0) -> dict
    classify(model_path, motion_path) -> (label, confidence)
"""
from .classifier import SkeletonClassifier, classify, sequence_features, train_classifier
from .nmc import NMCClassifier, gonmf, nmf_objective

__all__ = ["SkeletonClassifier", "classify", "sequence_features", "train_classifier",
           "NMCClassifier", "gonmf", "nmf_objective"]
