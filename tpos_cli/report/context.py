"""`ReportContext`: everything the report's pages draw, computed once from the run and its session."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from tpos_cli.io.columns import Columns
from tpos_cli.report import layout as L
from tpos_cli.report import qc
from tpos_cli.report.accuracy import Accuracy, SolutionErrors
from tpos_cli.report.health import Health
from tpos_cli.report.rundir import RunData
from tpos_cli.report.truth import ReportTruth

if TYPE_CHECKING:
    import pandas as pd

KIND_TITLES = {"drive": "vehicle drive", "target": "target survey (static observer)", "ranging": "ranging (anchors)"}


@dataclass(frozen=True)
class ShotWindows:
    ids: tuple[str, ...]
    t0: np.ndarray  # logger clock
    t1: np.ndarray


@dataclass(frozen=True)
class ReportContext:
    run: RunData
    session: object | None  # tpos_cli.session.Session, or None when the session is not available
    session_note: str  # why the session's own data are not shown ("" when they are)
    truth: ReportTruth | None
    acc: Accuracy
    health: Health
    series: dict[str, qc.Series]
    order: list[str]  # trajectory solutions, best first
    kind: str  # drive | target | ranging | the session's kind
    t_ref: float  # logger clock of the first IMU sample
    shots: ShotWindows | None
    targets: pd.DataFrame | None  # combined targets of the best target solution
    target_solution: str | None
    verdict: dict | None
    gps: qc.GpsQuality | None
    mag: qc.MagField | None
    anchors: qc.AnchorVisibility | None
    estimated: Columns
    full: bool
    inputs_note: str
    notes: tuple[str, ...] = field(default=())

    @property
    def best(self) -> str | None:
        return self.order[0] if self.order else None

    @property
    def name(self) -> str:
        return (self.run.summary.get("session") or {}).get("name") or self.run.path.name

    @property
    def has_truth(self) -> bool:
        """Independent truth for the pages: a reference trajectory, GPS fixes withheld from the run,
        or surveyed targets. GPS fixes the run itself used are not truth (see `gps_agreement`)."""
        return self.truth is not None and (self.truth_is_independent or self.truth.targets is not None)

    @property
    def gps_agreement_only(self) -> bool:
        """The only reference is the GPS the run used: its residuals, not its accuracy."""
        tt = self.truth.trajectory if self.truth is not None else None
        return tt is not None and not self.truth_is_independent

    @property
    def static_observer(self) -> bool:
        """A tripod target log: every solution is one fixed point."""
        return self.kind == "target" or (bool(self.series) and all(s.is_static for s in self.series.values()))

    @property
    def truth_is_independent(self) -> bool:
        tt = self.truth.trajectory if self.truth is not None else None
        return tt is not None and bool(tt.independent.any())

    def errors(self, name: str, independent_only: bool = True) -> SolutionErrors | None:
        """Errors of a solution against the trajectory truth; where the truth holds GPS fixes the run
        used (GPS truth, or a publisher's truth that is the receiver's solution) only at its
        independent epochs (withheld fixes), none when no fix was withheld."""
        se = next((se for se in self.acc.solutions if se.solution == name), None)
        if se is None or not independent_only or self.truth.trajectory.independent.all():
            return se
        if not se.independent.any():
            return None
        keep = se.independent[:, None]
        att = None if se.att_err_deg is None else {k: np.where(se.independent, v, np.nan) for k, v in se.att_err_deg.items()}
        return replace(se, err_ned_m=np.where(keep, se.err_ned_m, np.nan), att_err_deg=att)

    def shown(self, n: int = 2) -> list[str]:
        """Solutions drawn on time plots: the best and, for a moving platform, the causal filter it
        improves on; for a target log the federated solution and its local filters."""
        if self.static_observer:
            keep = [s for s in self.order if s in ("fkf_cal", "fkf", "lf1", "lf2", "gyro")]
            return (keep or self.order)[:4]
        out = self.order[:1]
        for pref in ("forward", "fatci", "tc", "lc"):
            if pref in self.order and pref not in out:
                out.append(pref)
                break
        return out[:n]

    def color(self, name: str) -> str:
        return L.COLORS[self.order.index(name) % len(L.COLORS)] if name in self.order else "k"

    @cached_property
    def _time(self) -> tuple[float, str]:
        spans = [s.t[-1] - s.t[0] for s in self.series.values() if s.t.size]
        _, label, scale = L.time_axis([0.0, max(spans) if spans else 0.0], 0.0)
        return scale, label

    @property
    def time_scale(self) -> float:
        """Seconds per unit of the time axis (1 or 60)."""
        return self._time[0]

    @property
    def time_label(self) -> str:
        return self._time[1]

    def x(self, t) -> np.ndarray:
        """Time-axis values of logger-clock times (s or min since the first IMU sample)."""
        return (np.asarray(t, dtype=float) - self.t_ref) / self._time[0]

    @property
    def time_limits(self) -> tuple[float, float]:
        ts = [s.t for s in self.series.values() if s.t.size]
        if not ts:
            return 0.0, 1.0
        return float(self.x(min(t[0] for t in ts))), float(self.x(max(t[-1] for t in ts)))

    def innovation_solution(self) -> str | None:
        """The solution whose innovations the report shows: the best one that has any."""
        inn = self.run.innovations
        if inn is None or not len(inn):
            return None
        have = {str(s) for s in set(inn["solution"].tolist())}  # the few labels, not a string per row
        for s in ["forward"] + self.order if not self.static_observer else self.order:
            if s in have:
                return s
        return str(inn["solution"][0])
