"""The `ingest` chain: ingestion, validation and time alignment only (a quick health check)."""

from __future__ import annotations

import numpy as np

from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import IngestParams
from tpos_cli.session import Session


def run(session: Session, p: IngestParams, ctx: RunContext) -> ChainOutput:
    t = session.imu.t_s
    results = {
        "imu": {"samples": int(t.size), "duration_s": float(t[-1] - t[0]),
                "measured_rate_hz": float((t.size - 1) / (t[-1] - t[0])) if t[-1] > t[0] else None},
        "gps_valid_fixes": int(session.gps.valid.sum()) if session.gps is not None else 0,
        "gps_outage_total_s": float(np.sum(np.diff(session.gps_outages_s, axis=1))) if len(session.gps_outages_s) else 0.0,
    }
    return ChainOutput(summary=results)
