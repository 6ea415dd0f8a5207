"""GeoJSON (RFC 7946): a FeatureCollection in WGS-84 with [lon, lat, h] positions (h ellipsoidal, m).

Targets are Point features; a trajectory is one LineString feature (the track) followed by one Point
feature per exported epoch carrying its time and sigmas. No `crs` member (RFC 7946 section 4).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from tpos_cli.export.meta import ExportMeta, decimals

COORD_DECIMALS = 9  # 1e-9 deg is 0.1 mm: below any sigma tpos writes


def _clean(k, v):
    if isinstance(v, (float, np.floating)):
        return round(float(v), decimals(k)) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def _position(lon, lat, h) -> list:
    p = [round(float(lon), COORD_DECIMALS), round(float(lat), COORD_DECIMALS)]
    return p + [round(float(h), 4)] if math.isfinite(h) else p


def _points(df: pd.DataFrame, extra: dict | None = None) -> list[dict]:
    props = [{k: _clean(k, v) for k, v in r.items()} for r in df.drop(columns=["lat", "lon"]).to_dict("records")]
    return [
        {"type": "Feature", "geometry": {"type": "Point", "coordinates": _position(lo, la, h)}, "properties": {**(extra or {}), **p}}
        for lo, la, h, p in zip(df["lon"].to_numpy(float), df["lat"].to_numpy(float), df["h"].to_numpy(float), props)
    ]


def _collection(features: list[dict], meta: ExportMeta) -> bytes:
    doc = {"type": "FeatureCollection", "name": meta.title, "description": meta.description, "features": features}
    return json.dumps(doc, allow_nan=False, separators=(",", ":")).encode("utf-8")


def targets(table: pd.DataFrame, meta: ExportMeta, observer: pd.DataFrame | None = None) -> bytes:
    """One Point per target (and one for the observer, `role` = "observer", when given)."""
    ok = np.isfinite(table[["lat", "lon"]].to_numpy(float)).all(axis=1)
    feats = _points(table[ok], {"role": "target"})
    if observer is not None:
        feats += _points(observer, {"role": "observer"})
    return _collection(feats, meta)


def track(table: pd.DataFrame, meta: ExportMeta) -> bytes:
    """The track as a LineString feature, then one Point feature per epoch."""
    line = [
        _position(lo, la, h) for lo, la, h in zip(table["lon"].to_numpy(float), table["lat"].to_numpy(float), table["h"].to_numpy(float))
    ]
    t = table["t"].to_numpy(float)
    head = {
        "type": "Feature",
        "geometry": {"type": "LineString", "coordinates": line},
        "properties": {"role": "track", "solution": meta.solution, "n_points": len(line), "t_first": float(t[0]), "t_last": float(t[-1])},
    }
    return _collection([head] + _points(table, {"role": "epoch"}), meta)
