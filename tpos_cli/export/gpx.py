"""GPX 1.1 (topografix.com/GPX/1/1): targets as waypoints, a trajectory as one track segment.

`ele` holds the WGS-84 ellipsoidal height (m), as the metadata description says; GPX has no field
for a position SD, so the sigmas and the 95 % ellipse travel in `<extensions>` under the tpos
namespace, which GPX 1.1 allows and readers that do not know it skip.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd

from tpos_cli.export.meta import ExportMeta, decimals, target_summary

NS = "http://www.topografix.com/GPX/1/1"
NS_TPOS = "urn:tpos:gpx-extensions:1"
SCHEMA = "http://www.topografix.com/GPX/1/1 http://www.topografix.com/GPX/1/1/gpx.xsd"
IN_GPX = ("lat", "lon", "h", "id", "time_utc", "time_first_utc")  # written as GPX elements, not extensions

ET.register_namespace("", NS)
ET.register_namespace("tpos", NS_TPOS)
ET.register_namespace("xsi", "http://www.w3.org/2001/XMLSchema-instance")


def _q(tag: str, ns: str = NS) -> str:
    return f"{{{ns}}}{tag}"


def _sub(parent, tag, text=None, ns: str = NS, **attrib):
    e = ET.SubElement(parent, _q(tag, ns), attrib)
    if text is not None:
        e.text = str(text)
    return e


def _root(meta: ExportMeta):
    root = ET.Element(
        _q("gpx"),
        {"version": "1.1", "creator": f"tpos {meta.tpos_version}", "{http://www.w3.org/2001/XMLSchema-instance}schemaLocation": SCHEMA},
    )
    md = _sub(root, "metadata")
    _sub(md, "name", meta.title)
    _sub(md, "desc", meta.description)
    return root


def _point(parent, tag, r: dict, when=None, name=None, sym=None, desc=None):
    # GPX 1.1 wptType child order: ele, time, ..., name, cmt, desc, src, link, sym, type, ..., extensions
    p = _sub(parent, tag, lat=f"{r['lat']:.9f}", lon=f"{r['lon']:.9f}")
    if math.isfinite(r["h"]):
        _sub(p, "ele", f"{r['h']:.4f}")
    if when is not None:
        _sub(p, "time", when)
    if name is not None:
        _sub(p, "name", name)
    if desc is not None:
        _sub(p, "desc", desc)
    if sym is not None:
        _sub(p, "sym", sym)
    ext_vals = [(k, v) for k, v in r.items() if k not in IN_GPX]
    ext_vals = [(k, v) for k, v in ext_vals if not (isinstance(v, (float, np.floating)) and not math.isfinite(v))]
    if ext_vals:
        ext = _sub(p, "extensions")
        for k, v in ext_vals:
            _sub(ext, k, f"{v:.{decimals(k)}f}" if isinstance(v, (float, np.floating)) else v, ns=NS_TPOS)
    return p


def _bytes(root) -> bytes:
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def targets(table: pd.DataFrame, meta: ExportMeta, observer: pd.DataFrame | None = None) -> bytes:
    root = _root(meta)
    for rows, sym in ((table, "Flag, Red"), (observer, "Flag, Blue")):
        if rows is None:
            continue
        for r in rows.to_dict("records"):
            if math.isfinite(r["lat"]) and math.isfinite(r["lon"]):
                _point(
                    root, "wpt", r, when=r.get("time_first_utc") or None, name=str(r.get("id", "observer")), sym=sym, desc=target_summary(r)
                )
    return _bytes(root)


def track(table: pd.DataFrame, meta: ExportMeta) -> bytes:
    root = _root(meta)
    trk = _sub(root, "trk")
    _sub(trk, "name", f"{meta.session} {meta.solution}")
    seg = _sub(trk, "trkseg")
    times = table["time_utc"].to_numpy() if "time_utc" in table else [None] * len(table)
    for r, when in zip(table.to_dict("records"), times):
        _point(seg, "trkpt", r, when=when)
    return _bytes(root)
