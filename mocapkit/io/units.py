"""Length units of the motion files that do not state one in a fixed vocabulary: one table
for the ``units=`` option of the BVH and ASF/AMC readers (and the BVH unit inference).

C3D, TRC and Kinect text keep their own tables (:data:`mocapkit.io.c3d.UNITS`,
:data:`mocapkit.io.trc.UNITS`, the Kinect candidates): those are the spellings their files
write in a header field, or, for Kinect, the candidates its inference picks from.

The CMU unit: ASF skeletons of CMU and HDM05 state ``:units length 0.45``, i.e. file
lengths are inches x 0.45, so one unit is 1/0.45 inch = 2.54 / 0.45 = 5.644444 cm
(:data:`CMU_CM_PER_UNIT`); the cgspeed BVH conversions of CMU use the same unit. Methods
that follow papers run in these units (the low-rank completion methods divide the (T, 3J)
matrix by it before solving).
"""
from __future__ import annotations

__all__ = ["CMU_CM_PER_UNIT", "LENGTH_UNITS", "UNIT_LABELS", "unit_name"]

#: cm per CMU / HDM05 ASF length unit (``:units length 0.45``): 2.54 / 0.45 = 5.644444.
CMU_CM_PER_UNIT = 2.54 / 0.45

#: unit name -> cm per file unit (the candidates of the BVH unit inference, in this order)
LENGTH_UNITS: dict[str, float] = {
    "cm": 1.0,
    "mm": 0.1,
    "m": 100.0,
    "inch": 2.54,
    "cmu": CMU_CM_PER_UNIT,
}

#: unit name -> words for ``motion.source['units']['label']``
UNIT_LABELS: dict[str, str] = {"cm": "centimetre", "mm": "millimetre", "m": "metre", "inch": "inch",
                               "cmu": "CMU unit (1/0.45 inch = 5.644444 cm)"}

_ALIASES = {"in": "inch", "inches": "inch", "centimeter": "cm", "centimetre": "cm",
            "millimeter": "mm", "millimetre": "mm", "meter": "m", "metre": "m",
            "cmu_unit": "cmu", "cmu units": "cmu"}


def unit_name(name: str) -> str | None:
    """The :data:`LENGTH_UNITS` key for a unit name or alias (any case), or None if unknown.

    Examples
    --------
    >>> unit_name("Inches"), unit_name("CMU"), unit_name("furlong")
    ('inch', 'cmu', None)
    """
    key = _ALIASES.get(name.lower(), name.lower())
    return key if key in LENGTH_UNITS else None
