"""docs/methods.md's "Where each method lives" table matches the registry.

Every registered name appears exactly once, its class is defined in the estimator file
the table names, and every solver file it names exists -- so the map a newcomer reads
cannot drift from the code.
"""
from __future__ import annotations

import inspect
import re
from pathlib import Path

from mocapkit.denoise import available

ROOT = Path(__file__).resolve().parents[1]


def _rows() -> dict[str, list[str]]:
    text = (ROOT / "docs" / "methods.md").read_text(encoding="utf-8")
    section = text.split("## Where each method lives", 1)[1].split("\n## ", 1)[0]
    rows: dict[str, list[str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 5 and cells[0].startswith("`"):
            name = cells[0].strip("`")
            assert name not in rows, f"{name} listed twice"
            rows[name] = cells
    return rows


def test_every_registered_method_is_listed_once():
    rows = _rows()
    assert sorted(rows) == sorted(available())


def test_class_lives_in_the_named_file():
    for name, (_, cls_name, est_file, _, _) in _rows().items():
        cls = available()[name]
        assert cls.__name__ == cls_name.strip("`"), name
        src = Path(inspect.getsourcefile(cls)).resolve().relative_to(ROOT).as_posix()
        assert src == est_file.strip("`"), f"{name}: class in {src}, table says {est_file}"


def test_solver_files_exist():
    for name, cells in _rows().items():
        for path in re.findall(r"`(mocapkit/[^`]+\.py)`", cells[3]):
            assert (ROOT / path).is_file(), f"{name}: {path} does not exist"
