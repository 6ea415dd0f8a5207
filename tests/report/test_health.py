"""Filter health (`report.health`): the NIS table shows the band the verdict tested, so the
report and page 1's verdict never disagree on the same mean."""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy import stats

from tpos_cli.report.health import nis_table


def _innovations(n: int = 400) -> pd.DataFrame:
    rng = np.random.default_rng(0)
    return pd.DataFrame({
        "solution": ["forward"] * n + ["backward"] * n,
        "kind": ["range"] * (2 * n),
        "nis": np.r_[0.95 * rng.chisquare(1, n), rng.chisquare(1, n)],
        "dof": 1.0,
        "accepted": True,
    })


def test_rows_the_verdict_checked_carry_its_band_and_the_others_the_plain_95_band():
    inn = _innovations()
    fwd = inn["nis"][inn["solution"] == "forward"]
    checks = {"nis.forward.range": {"n": 400, "n_accepted": 400, "dof": 1.0, "mean_nis": float(fwd.mean()),
                                    "expected": 1.0, "band": [0.0, 10.0], "ratio": float(fwd.mean())},
              "nis.forward.other": "not a figure"}
    t = nis_table(inn, checks).to_pandas().set_index("solution")
    f, b = t.loc["forward"], t.loc["backward"]
    assert f["band_source"] == "verdict" and (f["mean_lo"], f["mean_hi"]) == (0.0, 10.0) and f["consistent"]
    assert f["mean_nis"] == float(fwd.mean())
    assert b["band_source"] == "95 %"
    lo, hi = stats.chi2.ppf([0.025, 0.975], 400) / 400  # the plain band of 400 one-dof values
    assert np.allclose([b["mean_lo"], b["mean_hi"]], [lo, hi], rtol=1e-9, atol=0)


def test_without_checks_every_row_has_the_plain_band():
    t = nis_table(_innovations(), None)
    assert (t["band_source"] == "95 %").all()
    assert (nis_table(_innovations(), {"nis.forward.range": {"band": [float("nan"), 1.0], "mean_nis": 1.0}})["band_source"] == "95 %").all()
