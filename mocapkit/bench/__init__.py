"""Benchmark protocols reproducing the papers' experiments (see :mod:`mocapkit.bench.core`)."""
from .core import PROTOCOLS, Context, Row, Timer, available, protocol, run, to_json, to_markdown  # noqa: F401
