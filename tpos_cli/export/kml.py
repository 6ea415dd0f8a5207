"""KML 2.2 (OGC 07-147r2), as Google Earth and QGIS read it.

Targets are Point placemarks; a trajectory is a LineString placemark (the track) and a folder of
epoch placemarks with their TimeStamp. Geometry is `clampToGround`: KML's `absolute` altitude is
above the geoid, tpos heights are ellipsoidal, so the ellipsoidal height `h` travels in ExtendedData
(and as the coordinate's third value, which clampToGround ignores) instead of being misplaced by
the geoid undulation.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pandas as pd

from tpos_cli.export.meta import COLUMN_DOC, ExportMeta, decimals, target_summary

NS = "http://www.opengis.net/kml/2.2"


def _coord(lon, lat, h) -> str:
    return f"{lon:.9f},{lat:.9f},{h:.4f}" if math.isfinite(h) else f"{lon:.9f},{lat:.9f}"


def _sub(parent, tag, text=None, **attrib):
    e = ET.SubElement(parent, tag, attrib)
    if text is not None:
        e.text = str(text)
    return e


def _fmt(k, v) -> str:
    if isinstance(v, (float, np.floating)):
        return "" if not math.isfinite(v) else f"{v:.{decimals(k)}f}"
    return str(v)


def _document(meta: ExportMeta, columns):
    """The KML document with its styles; its description explains the data fields the placemarks carry
    (`columns`), not every field an export can have (a target has no velocity or attitude)."""
    root = ET.Element("kml", {"xmlns": NS})
    doc = _sub(root, "Document")
    _sub(doc, "name", meta.title)
    present = set(columns)
    fields = "; ".join(f"{k}: {v}" for k, v in COLUMN_DOC.items() if k in present)
    _sub(doc, "description", meta.description + (" Data fields: " + fields + "." if fields else ""))
    for sid, color, scale in (("target", "ff0000ff", "1.0"), ("observer", "ffff0000", "1.1"), ("epoch", "ff00ffff", "0.4")):
        st = _sub(doc, "Style", id=sid)
        icon = _sub(st, "IconStyle")
        _sub(icon, "color", color)
        _sub(icon, "scale", scale)
    st = _sub(doc, "Style", id="track")
    ls = _sub(st, "LineStyle")
    _sub(ls, "color", "ff0000ff")
    _sub(ls, "width", "3")
    return root, doc


def _placemark(parent, name, style, record: dict, lon, lat, h, when=None, desc=None):
    pm = _sub(parent, "Placemark")
    _sub(pm, "name", name)
    if desc is not None:
        _sub(pm, "description", desc)
    if when is not None:
        ts = _sub(pm, "TimeStamp")
        _sub(ts, "when", when)
    _sub(pm, "styleUrl", f"#{style}")
    ext = _sub(pm, "ExtendedData")
    for k, v in record.items():
        d = _sub(ext, "Data", name=k)
        _sub(d, "value", _fmt(k, v))
    pt = _sub(pm, "Point")
    _sub(pt, "coordinates", _coord(lon, lat, h))
    return pm


def _bytes(root) -> bytes:
    ET.indent(root, space=" ")
    return ET.tostring(root, encoding="utf-8", xml_declaration=True)


def targets(table: pd.DataFrame, meta: ExportMeta, observer: pd.DataFrame | None = None) -> bytes:
    root, doc = _document(meta, [*table.columns, *(observer.columns if observer is not None else ())])
    for rows, style in ((table, "target"), (observer, "observer")):
        if rows is None:
            continue
        for r in rows.to_dict("records"):
            if math.isfinite(r["lat"]) and math.isfinite(r["lon"]):
                _placemark(doc, r.get("id", style), style, r, r["lon"], r["lat"], r["h"], desc=target_summary(r))
    return _bytes(root)


def track(table: pd.DataFrame, meta: ExportMeta) -> bytes:
    root, doc = _document(meta, table.columns)
    pm = _sub(doc, "Placemark")
    _sub(pm, "name", f"track {meta.solution}")
    _sub(pm, "styleUrl", "#track")
    ls = _sub(pm, "LineString")
    _sub(ls, "tessellate", "1")
    _sub(ls, "coordinates", " ".join(_coord(lo, la, h) for lo, la, h in zip(table["lon"], table["lat"], table["h"])))
    folder = _sub(doc, "Folder")
    _sub(folder, "name", "epochs")
    times = table["time_utc"].to_numpy() if "time_utc" in table else [None] * len(table)
    for r, when in zip(table.to_dict("records"), times):
        _placemark(folder, f"t = {r['t']:.2f} s", "epoch", r, r["lon"], r["lat"], r["h"], when)
    return _bytes(root)
