"""io.tables text columns and the anchor-range ids read through them (the factorized paths)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.helpers.sessions import write_minimal_session
from tpos_cli.errors import InvalidInputError
from tpos_cli.io.tables import _to_text
from tpos_cli.session import load_session


def _cell_by_cell(s: pd.Series) -> np.ndarray:
    return np.array(["" if (v is None or (isinstance(v, float) and np.isnan(v))) else str(v).strip() for v in s], dtype=object)


@pytest.mark.parametrize(
    "s",
    [
        pd.Series(["A1", None, " A2", "A2", "A1 ", "", " "], dtype="str"),
        pd.Series(["é", "ß ", np.nan], dtype="str"),
        pd.Series([], dtype="str"),
        pd.Series([1.0, np.nan, -0.0, 0.0]),  # numbers: -0.0 and 0.0 stay apart
        pd.Series([1, True, 1.0, None, " x"], dtype=object),  # 1, True and 1.0 stay apart
    ],
)
def test_text_column_is_the_cell_by_cell_conversion(s):
    got = _to_text(s)
    want = _cell_by_cell(s)
    assert got.dtype == object and list(got) == list(want)
    assert all(type(v) is str for v in got)


def _anchor_session(tmp_path, fmt):
    s = write_minimal_session(tmp_path / "s", with_anchors=True)
    d = pd.read_csv(s / "anchor_ranges.csv")
    d["id"] = [f" {a} " if i % 3 == 0 else a for i, a in enumerate(d["id"].astype(str))]  # padded ids are the same ids
    if fmt == "parquet":
        (s / "anchor_ranges.csv").unlink()
        d.to_parquet(s / "anchor_ranges.parquet", index=False)
    else:
        d.to_csv(s / "anchor_ranges.csv", index=False)
    return s, d


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_anchor_ranges_ids_map_to_anchors_row_by_row(tmp_path, fmt):
    s, d = _anchor_session(tmp_path, fmt)
    ses = load_session(s)
    ids = list(ses.anchors.ids)
    idx = np.array([ids.index(a.strip()) for a in d["id"]])
    kept = np.isfinite(d["range"].to_numpy()) & ~pd.DataFrame({"t": d["t"], "a": idx}).duplicated().to_numpy()
    assert ses.anchor_ranges.anchor.dtype == np.int64
    assert np.array_equal(ses.anchor_ranges.anchor, idx[kept])
    assert len(set(ids)) == len(ids) and all(i == i.strip() for i in ids)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_unknown_anchor_id_is_named_with_its_row(tmp_path, fmt):
    s, d = _anchor_session(tmp_path, fmt)
    d.loc[9, "id"] = "A9"
    if fmt == "parquet":
        d.to_parquet(s / "anchor_ranges.parquet", index=False)
    else:
        d.to_csv(s / "anchor_ranges.csv", index=False)
    with pytest.raises(InvalidInputError) as exc:
        load_session(s)
    assert f"anchor_ranges.{fmt}: column 'id', row 10: anchor id 'A9' is not in anchors.csv" in str(exc.value)
