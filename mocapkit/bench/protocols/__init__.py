"""Every protocol module; importing this package registers them all.

One module per paper/family. A module missing (not written yet) is skipped; a real
import error inside one is raised.
"""
import importlib

_MODULES = ("smoke", "lowrank", "louchai", "xiao", "thesis", "bra", "retrieval", "real_gaps", "auto")

for _m in _MODULES:
    try:
        importlib.import_module(f"{__name__}.{_m}")
    except ModuleNotFoundError as _e:
        if _e.name != f"{__name__}.{_m}":
            raise
