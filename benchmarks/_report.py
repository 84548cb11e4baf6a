"""The one ``main`` of the benchmark scripts whose Markdown report is rendered from a JSON
run: run into ``<out>.json`` (with the run's wall seconds), then render ``<out>``;
``--render-only`` re-renders from the JSON already there.

>>> import tempfile
>>> from pathlib import Path
>>> out = Path(tempfile.mkdtemp()) / "demo.md"
>>> _ = out.with_suffix(".json").write_text('{"seconds": 1.0, "rows": [1, 2]}')
>>> run_or_render(out, None, lambda doc: f"{len(doc['rows'])} rows\\n", "demo", argv=["--render-only"]) # doctest: +ELLIPSIS
wrote ...demo.md
0
>>> out.read_text()
'2 rows\\n'
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence


def run_or_render(out: Path | Callable[[argparse.Namespace], Path],
                  run: Callable[[Path, argparse.Namespace], dict] | None,
                  render: Callable[[dict], str], description: str,
                  options: Sequence[tuple[str, dict]] = (), argv: Sequence[str] | None = None) -> int:
    """Parse ``--data DIR``, ``--render-only`` and ``options`` ((flag, add_argument kwargs));
    unless rendering only, ``run(data, args)`` returns the document (``rows`` and any
    settings), written with ``seconds`` to ``out``'s .json; ``render(doc)`` writes ``out``
    (``out(args)`` where the report depends on an option, e.g. a clip set)."""
    from mocapkit.datasets import shared_data_dir

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data")
    ap.add_argument("--render-only", action="store_true")
    for flag, kw in options:
        ap.add_argument(flag, **kw)
    a = ap.parse_args(argv)
    if callable(out):
        out = out(a)
    js = out.with_suffix(".json")
    if not a.render_only:
        if a.data and not Path(a.data).is_dir():       # (shared_data_dir would look elsewhere)
            raise SystemExit(f"{Path(sys.argv[0]).name}: --data {a.data}: no such folder")
        data = shared_data_dir(a.data)
        if data is None:
            raise SystemExit(f"{Path(sys.argv[0]).name}: ../shared/data not found (--data DIR)")
        t0 = time.time()
        doc = run(Path(data), a)
        rows = doc.pop("rows")
        js.write_text(json.dumps({**doc, "seconds": time.time() - t0, "rows": rows}, indent=0, default=float))
    out.write_text(render(json.loads(js.read_text())))
    print(f"wrote {out}")
    return 0


def method_time(main: Callable[[], Any]) -> Any:
    """``main()`` with the gap policy's self-validation of fills off, for the scripts that
    time methods: since 2026-12-05 a method that fills gaps longer than 2 frames runs twice
    more under the default policy (:func:`mocapkit.denoise.fill_auto.unvalidated_fills`);
    the method's own time leaves that out."""
    from mocapkit.gaps import use_policy

    with use_policy(validate_cm=None):
        return main()


def replace_section(out: Path, begin: str, end: str, lines: Sequence[str],
                    title: str = "# I/O results") -> str:
    """Write ``lines`` between the markers ``begin`` and ``end`` of the shared Markdown
    report ``out`` (several scripts own a section each of one file, e.g. docs/results/io.md):
    the section is replaced where it stands, or appended; a missing file starts with
    ``title``. Returns the section written.

    >>> import tempfile
    >>> out = Path(tempfile.mkdtemp()) / "io.md"
    >>> _ = replace_section(out, "<!-- A -->", "<!-- /A -->", ["one"])
    >>> _ = replace_section(out, "<!-- B -->", "<!-- /B -->", ["two"])
    >>> _ = replace_section(out, "<!-- A -->", "<!-- /A -->", ["three"])
    >>> print(out.read_text())
    # I/O results
    <BLANKLINE>
    <!-- A -->
    three
    <!-- /A -->
    <BLANKLINE>
    <!-- B -->
    two
    <!-- /B -->
    <BLANKLINE>
    """
    section = begin + "\n" + "\n".join(lines).rstrip() + "\n" + end + "\n"
    out.parent.mkdir(parents=True, exist_ok=True)
    old = out.read_text() if out.exists() else title + "\n\n"
    if begin in old and end in old:
        new = re.sub(re.escape(begin) + r".*?" + re.escape(end) + r"\n?", lambda _: section, old, flags=re.S)
    else:
        new = old.rstrip("\n") + "\n\n" + section
    out.write_text(new)
    return section
