"""RTKLIB time-tag files (`<log>.tag`): PC arrival times of a logged byte stream.

Layout (RTKLIB `stream.c`, written by `str2str -t`/`rtknavi` when time tags are on): a 60-byte
text header starting "TIMETAG RTKLIB", then `uint32 tick_f` (ms), `uint32 t_sec`, `float64 t_frac`
(start time: GPST as seconds since 1970-01-01 without leap seconds), then `uint32 tick_ms,
uint32 byte_offset` pairs written after each chunk: by `tick_ms` ms after the start the file held
`byte_offset` bytes. A line is stamped with the first tag whose offset covers its last byte; the
sensor's own counter is then fitted linearly to these arrival times (least squares), which removes
the jitter of the serial link and keeps the sensor's sample spacing.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tpos_cli.errors import InvalidInputError
from tpos_cli.importers.gpstime import GPS_EPOCH_UNIX_S
from tpos_cli.io.bounded import read_source_bytes

HEADER_LEN = 60


@dataclass(frozen=True)
class TimeTags:
    """Start time (GPS seconds since the GPS epoch) and (tick_ms, byte_offset) pairs."""

    start_gps_s: float
    tick_ms: np.ndarray  # (K,) int64, ms after the start
    byte_offset: np.ndarray  # (K,) int64, bytes in the file at that tick


@dataclass(frozen=True)
class ClockFit:
    """t = intercept_s + slope * (counter_s - counter0_s), with the fit residual statistics."""

    counter0_s: float
    intercept_s: float
    slope: float
    residual_sd_s: float
    n_used: int

    def __call__(self, counter_s):
        return self.intercept_s + self.slope * (np.asarray(counter_s, float) - self.counter0_s)


def read_time_tags(path: Path) -> TimeTags:
    """Parse an RTKLIB .tag file; InvalidInputError if it is not one."""
    data = read_source_bytes(Path(path), text=False)
    if len(data) < HEADER_LEN + 16 or not data.startswith(b"TIMETAG"):
        raise InvalidInputError(f"{path}: not an RTKLIB time-tag file (no 'TIMETAG' header)")
    _tick_f, t_sec = struct.unpack("<II", data[HEADER_LEN : HEADER_LEN + 8])
    (t_frac,) = struct.unpack("<d", data[HEADER_LEN + 8 : HEADER_LEN + 16])
    body = data[HEADER_LEN + 16 :]
    n = len(body) // 8
    pairs = np.frombuffer(body[: 8 * n], dtype="<u4").reshape(n, 2).astype(np.int64)
    return TimeTags(t_sec - GPS_EPOCH_UNIX_S + t_frac, pairs[:, 0], pairs[:, 1])


def line_arrival_gps_s(tags: TimeTags, line_end_offsets: np.ndarray) -> np.ndarray:
    """GPS seconds at which each line (given by the byte offset just past its end) had arrived; NaN past the tags."""
    idx = np.searchsorted(tags.byte_offset, np.asarray(line_end_offsets), side="left")
    out = np.full(idx.shape, np.nan)
    ok = idx < tags.byte_offset.size
    out[ok] = tags.start_gps_s + tags.tick_ms[idx[ok]] * 1e-3
    return out


def fit_counter_to_arrival(counter_s: np.ndarray, arrival_s: np.ndarray) -> ClockFit:
    """Least-squares line arrival = a + b (counter - counter0) over the finite pairs."""
    ok = np.isfinite(counter_s) & np.isfinite(arrival_s)
    if ok.sum() < 2:
        raise InvalidInputError("time tags: fewer than two lines have both a counter and an arrival time")
    c = counter_s[ok]
    c0 = float(c[0])
    A = np.column_stack([np.ones(c.size), c - c0])
    coef, *_ = np.linalg.lstsq(A, arrival_s[ok], rcond=None)
    res = arrival_s[ok] - A @ coef
    return ClockFit(c0, float(coef[0]), float(coef[1]), float(res.std(ddof=2)), int(ok.sum()))


def line_end_offsets(line_lengths: np.ndarray, terminator_bytes: int) -> np.ndarray:
    """Byte offset just past each line, for lines of `line_lengths` bytes (without terminator)."""
    return np.cumsum(np.asarray(line_lengths, np.int64) + terminator_bytes)


def guess_terminator_bytes(raw: bytes, n_lines: int, tags: TimeTags) -> int:
    """1 (LF) or 2 (CRLF): the line ending the file had when it was tagged.

    A copy converted from CRLF to LF keeps the tags' offsets of the original, which then run past
    the file's end by about one byte per line; that is the evidence used here.
    """
    if b"\r\n" in raw[:4096]:
        return 1  # CR still present: counted in the line lengths already
    overshoot = int(tags.byte_offset.max()) - len(raw)
    return 2 if overshoot > n_lines // 2 else 1
