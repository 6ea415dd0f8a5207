"""The README's page-1 images (docs/report-*-page1.png): rendered from the bundled sample sessions
exactly as the README's commands make them, so that `test_readme_images.py` can tell when they no
longer show what the code renders. Regenerate them after a change to the report or the chains:

    python -m tests.report.readme_images          # rewrites docs/report-target-page1.png, docs/report-drive-page1.png

Each session is copied into a scratch `demo/sample_logs/`, processed with `tpos process SESSION -o
runs/NAME-PIPELINE` and reported with `tpos report`, both as subprocesses in `demo/` (the paths in
the provenance print are then those of the README); page 1 is rendered with poppler's `pdftoppm`
at 530 pixels wide (about 64 dpi).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DOCS = REPO / "docs"
WIDTH_PX = 530
# README image -> (sample session, its default pipeline)
IMAGES = {
    "report-target-page1.png": ("target_wall", "target-fkf"),
    "report-drive-page1.png": ("drive_outage", "drive-smooth"),
}


def have_pdftoppm() -> bool:
    return shutil.which("pdftoppm") is not None


def render_page1(image: str, work: Path) -> Path:
    """Process and report the sample session of README image `image` in a scratch demo/ directory;
    returns the PNG of its page 1, copied into `work`. The scratch directory is always a fresh
    `tempfile` one, whoever calls: the provenance print holds its path, and a longer one (pytest's
    tmp_path) wraps those lines differently and moves the figures above them (1.1 % of the pixels)."""
    session, pipeline = IMAGES[image]
    with tempfile.TemporaryDirectory() as tmp:
        demo = Path(tmp) / "demo"
        shutil.copytree(REPO / "sample_logs" / session, demo / "sample_logs" / session)
        run = f"runs/{session}-{pipeline}"
        env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        for args in (["process", f"sample_logs/{session}", "-o", run, "-q"], ["report", run]):
            subprocess.run([sys.executable, "-m", "tpos_cli", *args], cwd=demo, env=env, check=True, capture_output=True, text=True)
        stem = demo / f"{session}-page"
        size = ["-scale-to-x", str(WIDTH_PX), "-scale-to-y", "-1"]
        page1 = ["pdftoppm", "-f", "1", "-l", "1", "-singlefile", *size, "-png", f"{run}/report.pdf", str(stem)]
        subprocess.run(page1, cwd=demo, check=True)
        out = Path(work) / stem.with_suffix(".png").name
        shutil.copyfile(stem.with_suffix(".png"), out)
    return out


def main() -> None:
    if not have_pdftoppm():
        raise SystemExit("pdftoppm (poppler-utils) is needed to render the README images")
    for image in IMAGES:
        with tempfile.TemporaryDirectory() as tmp:
            shutil.copyfile(render_page1(image, Path(tmp)), DOCS / image)
        print(f"wrote docs/{image}")


if __name__ == "__main__":
    main()
