"""Where the project's neighbours are: `../shared` beside the checkout (absent in a bare clone)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
SHARED_DATA = SHARED / "data"
