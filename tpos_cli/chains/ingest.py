"""The `ingest` chain: ingestion, validation and time alignment only (a quick health check)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.chains.context import ChainOutput, RunContext
from tpos_cli.config import params_to_dict, parse_params
from tpos_cli.session import Session


@dataclass(frozen=True)
class IngestParams:
    """No parameters yet; the section exists so that unknown keys are still caught."""


def run(session: Session, params: dict, ctx: RunContext) -> ChainOutput:
    p = parse_params(IngestParams, params.get("ingest"), "ingest")
    t = session.imu.t_s
    results = {
        "imu": {"samples": int(t.size), "duration_s": float(t[-1] - t[0]),
                "measured_rate_hz": float((t.size - 1) / (t[-1] - t[0])) if t[-1] > t[0] else None},
        "gps_valid_fixes": int(session.gps.valid.sum()) if session.gps is not None else 0,
        "gps_outage_total_s": float(np.sum(np.diff(session.gps_outages_s, axis=1))) if len(session.gps_outages_s) else 0.0,
    }
    return ChainOutput(summary={"config": {"ingest": params_to_dict(p)}, **results})
