"""mocapkit: clean, search and label motion-capture data.

Positions are in centimetres everywhere (see :mod:`mocapkit.motion`).
"""
from .errors import MocapError, MocapFormatError, MocapValueError
from .motion import Motion
from .skeleton import Skeleton

__version__ = "0.1.0"
__all__ = ["Motion", "Skeleton", "MocapError", "MocapFormatError", "MocapValueError", "__version__"]
