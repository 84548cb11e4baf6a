"""Figures, GIF and the HTML report (rendered in headless Chromium when it is installed)."""
import json
import shutil
import subprocess

import numpy as np
import pytest

from mocapkit import corrupt, denoise, io
from mocapkit.cli import main
from mocapkit.datasets import bundled
from mocapkit.viz.report import render_report, write_report


@pytest.fixture(scope="module")
def trio():
    truth = io.read(bundled("16_15.amc")).slice(0, 120)
    noisy, _ = corrupt.combine(truth, [("gaussian", {"sigma_cm": 2}), ("missing", {"ratio": 0.1})], seed=0)
    return truth, noisy, denoise.get("gaussian").denoise(noisy)


def test_plot_commands(trio, tmp_path):
    from mocapkit.viz import plots
    truth, noisy, clean = trio
    png = plots.plot_trajectories(tmp_path / "t.png", [truth, noisy, clean], ["t", "n", "c"], ["ltibia"])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = plots.plot_error(tmp_path / "e.svg", truth, [clean], ["c"])
    assert b"<svg" in svg.read_bytes()[:500]
    gif = plots.animate_gif(tmp_path / "a.gif", [truth, clean], ["t", "c"], max_frames=5)
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    rows = [{"protocol": "p", "clip": "c", "condition": "x", "method": m, "metric": "rmse", "unit": "cm",
             "value": v, "paper_value": 1.0, "seconds": 0.1} for m, v in (("a", 1.5), ("b", 0.7))]
    (tmp_path / "b.json").write_text(json.dumps(rows))
    assert main(["plot", str(tmp_path / "b.json"), "--bench", "-o", str(tmp_path / "b.png")]) == 0
    assert (tmp_path / "b.png").stat().st_size > 1000


def test_report_content_and_errors(trio, tmp_path):
    truth, noisy, clean = trio
    html = render_report([truth, noisy, clean], ["truth", "noisy", "clean"])
    assert html.count("<canvas") >= 2 and "http://" not in html and "https://" not in html
    payload = json.loads(html.split("const P=")[1].split(";const D=")[0])
    assert len(payload["data"]["motions"]) == 3 and len(payload["errors"]["per_frame"]) == 2
    from mocapkit.errors import MocapValueError
    with pytest.raises(MocapValueError):
        render_report([truth, clean.slice(0, 50)])


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if shutil.which(name):
            return shutil.which(name)
    return None


def test_report_renders_in_headless_chromium(trio, tmp_path):
    exe = _chromium()
    if exe is None:
        pytest.skip("Chromium not installed (Debian: apt-get install chromium); report browser test skipped")
    truth, noisy, clean = trio
    page = tmp_path / "report.html"
    write_report(page, [truth, noisy, clean], ["truth", "noisy", "clean"])
    # Run the page, let the player advance, then dump the DOM state the script exposes.
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run([exe, *flags, "--virtual-time-budget=3000", "--dump-dom", page.as_uri()],
                         capture_output=True, text=True, timeout=120).stdout
    assert 'id="flabel"' in dom
    label = dom.split('id="flabel">')[1].split("<")[0]
    assert label.startswith("frame ") and not label.startswith("frame 0 ")   # playback advanced
    shot = tmp_path / "shot.png"
    subprocess.run([exe, *flags, f"--screenshot={shot}", "--window-size=1200,900", page.as_uri()],
                   capture_output=True, timeout=120)
    assert shot.exists() and shot.stat().st_size > 5000
    # the skeleton canvases are not blank: some non-white pixels in the view area
    from PIL import Image
    img = np.asarray(Image.open(shot).convert("L"))
    assert (img[150:550, :] < 200).mean() > 0.001
