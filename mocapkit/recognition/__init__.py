"""Action recognition (thesis seed 003 Ch. 6): NMF-based motion clustering (NMC) with a
bag-of-words classifier (the thesis method), a skeleton-sequence classifier, and the
MiniRocket/MultiRocket classifier with an augmented training set (the default of
``mocapkit classify train``).

Entry points used by the CLI::

    train_classifier(paths_or_dir, output, labels=None, progress=True, *, C=1.0,
                     method='minirocket') -> dict
    classify(model_path, motion_path) -> (label, confidence)
    load_model(path) -> a classifier with .predict(motion) -> (label, confidence)
"""
from .classifier import DEFAULT_METHOD, METHODS, SkeletonClassifier, classify, sequence_features, train_classifier
from .model_file import load_model
from .nmc import NMCClassifier, gonmf, nmf_objective
from .rocket import MiniRocket, RocketClassifier, trajectories

__all__ = ["SkeletonClassifier", "classify", "load_model", "sequence_features", "train_classifier",
           "DEFAULT_METHOD", "METHODS", "NMCClassifier", "gonmf", "nmf_objective",
           "MiniRocket", "RocketClassifier", "trajectories"]
