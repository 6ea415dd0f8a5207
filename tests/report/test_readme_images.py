"""The README's page-1 images show what the code renders now: each is rendered again from its sample
session as the README's commands make it (`tests/report/readme_images.py`) and compared pixel by
pixel. Two renders of the same code differ only in the provenance print (time stamps, scratch
paths): 0.12 % of the pixels by more than a quarter of the grey range. A changed figure, table or
verdict moves several per cent (the images of the previous session's code: 3.3 % and 3.6 %)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.report.readme_images import DOCS, IMAGES, have_pdftoppm, render_page1

MAX_CHANGED = 0.01  # fraction of pixels differing by more than 64 of 255 levels in any channel


@pytest.mark.skipif(not have_pdftoppm(), reason="pdftoppm (poppler-utils) renders the PDF pages")
@pytest.mark.parametrize("image", sorted(IMAGES))
def test_readme_image_matches_the_current_report(image, tmp_path):
    from PIL import Image

    fresh = np.asarray(Image.open(render_page1(image, tmp_path)).convert("RGB"), dtype=float)
    shown = np.asarray(Image.open(DOCS / image).convert("RGB"), dtype=float)
    regenerate = "regenerate the README images: python -m tests.report.readme_images"
    size = f"docs/{image} is {shown.shape[1]}x{shown.shape[0]} px, page 1 renders {fresh.shape[1]}x{fresh.shape[0]}"
    assert fresh.shape == shown.shape, f"{size}; {regenerate}"
    changed = float(np.mean(np.abs(fresh - shown).max(axis=2) > 64))
    assert changed < MAX_CHANGED, f"docs/{image}: {changed:.1%} of its pixels differ from page 1 as the code renders it now; {regenerate}"
