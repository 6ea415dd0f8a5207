"""`drive_smooth.process_drive` with a helper thread (more than one CPU) gives the same bits as in sequence."""

import numpy as np
import pytest

import tpos_cli.chains.drive_smooth as ds
from tpos_cli.config import DriveSmoothParams
from tpos_cli.session import load_session
from tpos_cli.sim.drive import simulate_drive


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    sim = simulate_drive(150.0, seed=5, outages=((70.0, 20.0),))
    return load_session(sim.write(tmp_path_factory.mktemp("drive") / "s"))


def _run(session, monkeypatch, spare: bool, names):
    monkeypatch.setattr(ds, "spare_cpu", lambda: spare)
    return ds.process_drive(session, DriveSmoothParams(), None, names=names)


@pytest.mark.parametrize("names", [("forward", "backward", "smoothed", "rts", "two_filter"), ("smoothed",)])
def test_the_helper_thread_gives_the_same_bits(session, monkeypatch, names):
    seq = _run(session, monkeypatch, False, names)
    par = _run(session, monkeypatch, True, names)
    assert list(par.solutions) == list(seq.solutions)
    for k, a in seq.solutions.items():
        b = par.solutions[k]
        np.testing.assert_array_equal(b.idx, a.idx)
        for f in ("nav", "C_nb", "P9", "bias"):
            np.testing.assert_array_equal(getattr(b, f), getattr(a, f), err_msg=f"{k}.{f}")
    np.testing.assert_array_equal(par.flag, seq.flag)
    for run in ("forward", "backward"):
        a, b = getattr(seq, run), getattr(par, run)
        for f in ("nav", "C_nb", "bias", "ep_idx", "ev_nu", "ev_nis"):
            np.testing.assert_array_equal(getattr(b, f), getattr(a, f), err_msg=f"{run}.{f}")
        np.testing.assert_array_equal(b.ep_P.tril, a.ep_P.tril)
