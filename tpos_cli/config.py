"""Pipeline files: declarative TOML validated by pydantic v2 models before any data is read.

A pipeline file has a `[pipeline]` table (`PipelineHead`) and the table of its chain (one of the
section models below, `SECTIONS`). Every model forbids unknown keys, is frozen, strict about types
(an integer is accepted for a float, nothing else is converted), refuses NaN and infinities, and
bounds each value as its physics says (probabilities in (0, 1), standard deviations >= 0 or > 0).
The defaults of every key live here, in the models, and nowhere else; `pipelines/README.md`
documents each key (a test checks that it lists them all).

A pipeline file names a chain from the fixed registry in `tpos_cli.pipeline`; nothing a file names
is imported or evaluated.
"""

from __future__ import annotations

import difflib
import hashlib
import importlib.resources
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from tpos_cli.errors import InvalidInputError
from tpos_cli.io.bounded import read_toml

# value types with their bounds (all floats finite: the models set allow_inf_nan=False)
Probability = Annotated[float, Field(gt=0.0, lt=1.0)]
Positive = Annotated[float, Field(gt=0.0)]
NonNegative = Annotated[float, Field(ge=0.0)]
Count = Annotated[int, Field(ge=0)]


def _lists_to_tuples(value: Any) -> Any:
    """TOML arrays arrive as lists; the frozen models hold tuples (strict mode takes no list for a tuple)."""
    if isinstance(value, list):
        return tuple(_lists_to_tuples(v) for v in value)
    if isinstance(value, dict):
        return {k: _lists_to_tuples(v) for k, v in value.items()}
    return value


class Section(BaseModel):
    """Base of every pipeline table: unknown keys, wrong types, NaN/inf are errors; frozen."""

    # defer_build: a model's validator is built at its first validation, not at import; a run builds
    # only [pipeline] and its own chain's table (a drive never builds the ranging and target models)
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False, defer_build=True)

    @model_validator(mode="before")
    @classmethod
    def _tuples(cls, data: Any) -> Any:
        return _lists_to_tuples(data) if isinstance(data, dict) else data


# --------------------------------------------------------------------------- [pipeline]
class PipelineHead(Section):
    """`[pipeline]`: what `tpos pipelines` lists and which chain runs."""

    name: str
    description: str = ""
    chain: str
    kinds: tuple[str, ...] = ()


# --------------------------------------------------------------------------- [ingest]
class IngestParams(Section):
    """`[ingest]`: no keys yet; the table exists so that an unknown key is still refused."""


# --------------------------------------------------------------------------- [drive_smooth]
class DriveSmoothParams(Section):
    """`[drive_smooth]` (paper 003): INS/GPS forward/backward filters and smoothers.

    IMU noise figures left unset come from the session's `[imu]`, else the log or MEMS defaults
    (`tpos_cli.fusion.imu_noise`)."""

    smoother: Literal["rts", "two_filter", "simplified"] = "rts"  # the `smoothed` solution
    imu_gap_max_s: Positive = 1.0  # refuse a log with a longer IMU gap: the INS cannot be carried across it
    compare: bool = False  # also write every smoother under its own name
    cov_step_s: Positive = 0.2  # covariance propagation / storage step (NHC rows come at 5 Hz)
    output_rate_hz: NonNegative = 10.0  # rows per second per solution; 0 = every IMU sample
    gate_probability: Probability = 0.9999  # chi-square gate on GPS innovations
    flag_probability: Probability = 0.999  # forward/backward disagreement flag
    heading_min_speed_mps: Positive = 3.0  # course from GPS velocity once this fast
    # initial yaws tried by the filter (0 = trust the course / magnetometer); at most one per degree:
    # each is a filter pass, and 1e8 (a typo) grew past 2.5 GB in 50 s (audit12)
    heading_hypotheses: Annotated[int, Field(ge=0, le=360)] = 12
    heading_search_s: Positive = 30.0  # filter time after the platform first moved 5 m, per hypothesis
    gps_max_rate_hz: NonNegative = 1.0  # fixes used per second at most (0 = all): receiver fixes at
    # 5-20 Hz are correlated in time, and a filter treating them as white trusts them far too much
    init_sigma_pos_m: Positive = 5.0
    init_sigma_vel_mps: Positive = 1.0
    init_sigma_level_deg: Positive = 1.0
    init_sigma_yaw_deg: Positive = 3.0
    # IMU figures (`tpos_cli.imu_noise`): a key set here wins, then the session's [imu], then (white
    # noise) the log's own sample scatter if larger than these defaults, then these defaults
    gyro_noise_dps: Positive = 0.01  # white noise SD per sample
    acc_noise_mg: Positive = 2.0
    gyro_bias_dph: NonNegative = 1080.0  # initial bias SD: consumer MEMS turn-on biases reach 0.1-0.3
    # deg/s (the rtklibexplorer car's board: 60-620 deg/h); a tighter prior locks in a wrong bias
    acc_bias_mg: NonNegative = 10.0
    gyro_bias_inrun_dph: NonNegative = 10.0  # Gauss-Markov in-run bias SD
    acc_bias_inrun_mg: NonNegative = 2.0
    bias_tau_s: Positive = 300.0
    gps_sigma_h_m: Positive = 1.5  # used when gps has no sigma columns
    gps_sigma_floor_m: NonNegative = 0.01  # reported SDs below this are raised to it (a receiver's
    # RTK SDs are used as given: raising them to decimetres lets the solution sit off centimetre fixes)
    gps_float_sd_factor: NonNegative = 1.5  # RTK float epochs: stretches of fixes whose stated horizontal SD reaches
    # this x the log's centimetre median (`fusion.rtk_float.float_fixes`) keep their position rows with a float offset
    # state (fix = truth + b_float + white); 0: off (every fix white, as stated)
    gps_float_sigma_h_m: Positive = 0.15  # stationary SD of that offset per horizontal axis (m): an RTK float
    # solution's decimetre class (`fusion.rtk_float.FLOAT_SIGMA_H_M`)
    gps_float_sigma_v_m: Positive = 0.25  # ... and up (m)
    gps_float_tau_s: Positive = 5.0  # its Gauss-Markov time constant (s): multipath and float ambiguities change
    # over seconds on a moving receiver (`sim.rtk`'s assumed figure)
    max_consecutive_rejections: Count = 5  # then the next rejected fix goes in: as it is in the tuning passes; in the
    # final runs down-weighted to the gate's edge if beyond its stated accuracy (drifts re-acquired sooner: `fusion.reacquire`)
    gps_sigma_v_m: Positive = 2.5
    gps_sigma_vel_mps: Positive = 0.1
    use_gps_velocity: bool = True
    gps_clock_sigma_s: NonNegative = 0.2  # prior SD of the IMU-GPS clock offset state (s); 0: no such state.
    # Estimated with the fixes; output times move to the GPS clock when it is significant (`clock_offset`)
    gps_clock_rw_s_per_sqrt_s: NonNegative = 1e-3  # random walk of the clock offsets: a logger's clock drifts
    # against GPS time (100 ppm is 0.1 ms/s) and its buffering changes; 1e-3: 10 ms in 100 s
    clock_apply_sd: Positive = 3.0  # output on the GPS clock when |offset| exceeds this many of its SDs
    lever_arm: Literal["auto", "on", "off"] = "auto"  # estimate a horizontal correction to the stated
    # GPS lever arm (`fusion.layout.lever_arm_block`); auto: with vehicle axes or a level IMU, fixes
    # under a third of the prior SD and a course that turns (`drive_smooth.lever_arm_states`)
    lever_arm_sigma_m: Positive = 1.0  # prior SD of each component of that correction (m): a car's antenna
    # sits within a metre or two of its IMU; a stated lever arm is usually right to centimetres, but
    # the contract's default (zero) cannot be told from a measured zero
    lever_arm_min_turn_deg: NonNegative = 90.0  # auto: the course must span at least this much
    gps_vel_latency_s: NonNegative | None = None  # how late the logged velocity is (s); None: the clock states
    # estimate it (gps_clock_sigma_s > 0), else from the
    # log's own positions (`fusion.velocity_lag.velocity_latency_s`: receivers that difference positions)
    gps_noise: Literal["estimate", "given"] = "estimate"  # estimate: scale the GPS SDs by covariance
    # matching on a first decimated pass (`fusion.gps_noise`); given: the log's SDs or the defaults
    gps_noise_span_s: NonNegative = 900.0  # log time the estimation passes cover (0 = all)
    gps_error_model: Literal["stated_split", "gauss_markov", "white"] = "stated_split"  # stated_split
    # (default): where the receiver states its position SDs and its fixes at the detected stops scatter
    # significantly (1 %) less than stated, the stated SD is split into a white part (that scatter) and
    # 3 GPS position-error states (Gauss-Markov, `fusion.gps_error.stated_split`) carrying the rest of
    # its variance, so no sigma falls under the receiver's accuracy; else white fixes as stated. white:
    # independent fixes always; gauss_markov: error states fitted on the innovations (their SD has no
    # budget: fitted on one stretch they let the solution wander off good fixes, issue 11)
    gps_gm_tau_s: Positive | None = None  # time constant of the GPS error states; None: fitted
    # (gauss_markov) or 100 s (stated_split: a prior from carrier multipath, `STATED_SPLIT_TAU_S`)
    gps_gm_sigma_h_m: NonNegative | None = None  # gauss_markov: stationary SD of the correlated error; None: estimated
    gps_gm_sigma_v_m: NonNegative | None = None
    outage_min_s: Positive = 2.0  # a gap between fixes longer than this is an outage
    mounting_check_deg: Annotated[float, Field(ge=0.0, le=180.0)] = 20.0  # warn above this median
    # of course - yaw while moving (0 = no check)
    mounting_min_speed_mps: NonNegative = 0.3  # rows faster than this count for the mounting check
    # vehicle motion constraints (issue 11, `fusion.constraints`)
    platform: Literal["auto", "car", "rover", "pedestrian", "uav", "none"] = "auto"  # car/rover: NHC
    # + ZUPT/ZARU on stops; pedestrian: ZUPT on stops; uav/none: no constraint; auto: car when the
    # travel direction stays fixed in the IMU's axes on a first forward run, else pedestrian
    travel_min_speed_sd: Positive = 1.0  # mounting from the travel direction: samples faster than this many
    # horizontal velocity SDs of the first run (above its noise; their mean direction averages it out)
    auto_nhc_nis_max: Positive = 2.0  # auto: wheeled when the non-holonomic rows of a trial pass have a mean
    # NIS at most this (their d.o.f.: the constraint holds within its SD) ...
    auto_nhc_reject_max: Probability = 0.05  # ... and at most this fraction of them is rejected
    nhc_sigma_mps: Positive = 0.1  # lateral and vertical velocity of a wheeled vehicle (SD)
    nhc_rate_hz: Positive = 5.0  # NHC rows per second (slip and vibration errors are correlated over ~0.2 s)
    nhc_axle_sigma_m: Positive = 2.0  # prior SD of the distance from the IMU back to the rear axle (a state)
    mounting_sigma_given_deg: Positive = 0.5  # prior SD of the residual misalignment states (pitch,
    # yaw) when the session gives the mounting, and the least for an estimated one
    mounting_sigma_assumed_deg: Positive = 3.0  # ... when it is assumed aligned
    use_odometry: bool = True  # the session's odometry table as forward-speed updates (wheeled platforms)
    odometer_sigma_mps: Positive = 0.1  # odometer speed SD (CAN speed: quantization, latency, wheel slip)
    odometer_rate_hz: Positive = 1.0  # odometer rows per second at most (its errors are correlated in time)
    odometer_scale_sigma: Positive = 0.05  # prior SD of the odometer scale-factor error (a state)
    zupt_sigma_mps: Positive = 0.02  # velocity SD on a detected stop
    stop_max_speed_mps: Positive = 0.1  # GPS or odometer speed below this for stop_min_duration_s = a stop
    stop_min_duration_s: Positive = 2.0
    stop_noise: Literal["measured", "run"] = "measured"  # measured: on any platform's detected stop the IMU's white
    # noise is the stop's own over 1 s (`imu_noise.stop_noise_factors`); run: the whole run's


# --------------------------------------------------------------------------- [ranging_fatci]
Triangle = tuple[float, float, float]


class FuzzyParams(Section):
    """`[ranging_fatci.fuzzy]`: paper 002's Algorithm 1 rule base (defaults: the paper's three sets)."""

    input_range: tuple[float, float] = (0.0, 3.0)
    output_range: tuple[float, float] = (0.0, 3.0)
    rules: tuple[tuple[str, str], ...] = (("LE", "LE"), ("EQ", "EQ"), ("MO", "MO"))
    input_sets: dict[str, Triangle] = Field(default_factory=lambda: {
        "LE": (-1.0, 0.4, 1.0), "EQ": (0.4, 1.0, 1.6), "MO": (1.0, 1.6, 4.0)})
    output_sets: dict[str, Triangle] = Field(default_factory=lambda: {
        "LE": (0.1, 0.4, 0.7), "EQ": (0.7, 1.0, 1.3), "MO": (1.2, 1.6, 2.0)})

    @model_validator(mode="after")
    def _consistent(self) -> FuzzyParams:
        for name, (a, b, c) in [*self.input_sets.items(), *self.output_sets.items()]:
            if not a <= b <= c or a == c:
                raise ValueError(f"set {name!r} must be [left <= peak <= right] with left < right, got {[a, b, c]}")
        for r_in, r_out in self.rules:
            if r_in not in self.input_sets or r_out not in self.output_sets:
                raise ValueError(f"rule [{r_in!r}, {r_out!r}] names an undefined set")
        for key in ("input_range", "output_range"):
            lo, hi = getattr(self, key)
            if not lo < hi:
                raise ValueError(f"{key} must be [lo, hi] with lo < hi")
        if not self.rules:
            raise ValueError("the rule base is empty")
        from tpos_cli.ranging.fuzzy import uncovered_input  # numba kernels: not at import (a drive never needs them)

        gap = uncovered_input(self.input_sets, self.rules, self.input_range)
        if gap is not None:
            raise ValueError(f"no rule fires at input {gap:g}; the input sets must cover input_range")
        return self


RangingSolution = Literal["lc", "tc", "fatci"]


class RangingParams(Section):
    """`[ranging_fatci]` (paper 002); see pipelines/README.md for each key."""

    # fatci, the paper's filter: lc and tc are its comparison (paper 002 Table 1), on request
    solutions: Annotated[tuple[RangingSolution, ...], Field(min_length=1)] = ("fatci",)
    imu_gap_max_s: Positive = 1.0  # refuse a log with a longer IMU gap: the INS cannot be carried across it
    smoothed: bool = True
    smooth_source: RangingSolution = "fatci"
    smoother: Literal["rts", "two_filter"] = "rts"
    output_rate_hz: Positive = 10.0
    cov_step_s: Positive = 0.1
    calibration_scale: Literal["shared", "per_anchor"] = "shared"
    calibration_reject_sigma: NonNegative = 4.0
    sd_poly_degree: Count = 1
    range_sd_m: Positive = 0.15
    tc_range_sd_m: Positive | None = None
    epoch_window_s: Positive = 0.02
    lc_min_anchors: Annotated[int, Field(ge=3)] = 4  # a horizontal fix needs at least 3
    floor_down_m: float | None = None
    floor_sd_m: Positive = 0.05
    floor_height_sd_m: NonNegative | None = None
    gate_probability: Probability = 0.999
    gate_max_consecutive: Count = 20
    coast_gap_s: Positive = 0.5
    align_distance_m: Positive = 12.0
    align_max_turn_deg: Positive = 5.0
    level_window_s: Positive = 1.0
    zupt: bool = True
    zupt_sd_mps: Positive = 0.02
    zupt_rate_hz: Positive = 10.0
    zupt_max_speed_mps: Positive = 0.05
    zupt_acc_step_mps2: Positive = 0.05
    zupt_min_duration_s: NonNegative = 1.0
    initial_position_sd_m: Positive = 0.3
    initial_velocity_sd_mps: Positive = 0.1
    initial_level_sd_deg: Positive = 1.0
    initial_yaw_sd_deg: Positive = 10.0
    range_bias_sd_m: NonNegative = 0.05
    range_bias_rw_m_per_sqrt_s: NonNegative = 0.002
    gyro_noise_dps: Positive = 0.02
    acc_noise_mg: Positive = 2.0
    gyro_bias_dph: NonNegative = 10.0
    acc_bias_mg: NonNegative = 2.0
    bias_drift_time_s: Positive = 600.0
    fuzzy_exponent_b: NonNegative = 2.0
    fuzzy: FuzzyParams = Field(default_factory=FuzzyParams)

    @model_validator(mode="after")
    def _source_is_run(self) -> RangingParams:
        if self.smoothed and self.smooth_source not in self.solutions:
            raise ValueError(f"smooth_source {self.smooth_source!r} is not among solutions {list(self.solutions)}")
        return self


# --------------------------------------------------------------------------- [target_fkf]
class FaultParams(Section):
    """`[target_fkf.fault]`: fault detection of the local filters (`attitude.faults`)."""

    nis_window_s: Positive = 1.0
    nis_probability: Probability = 0.9999
    consistency_probability: Probability = 0.9999
    recover_s: NonNegative = 2.0


class TargetFkfParams(Section):
    """`[target_fkf]` (papers 000 and 001); see pipelines/README.md for each key."""

    model: Literal["full", "paper8"] = "full"
    beta: Annotated[float, Field(gt=0.0, le=1.0)] = 0.5  # Eq. 24 information share of each local filter
    lr_yaw_form: Literal["exact", "paper"] = "exact"  # paper8 only: Eq. 10 without the cos(pitch) factor
    fault_tolerant: bool = True
    # sensor figures used when session.toml gives none
    gyro_noise_dps: Positive = 0.01
    gyro_bias_dph: NonNegative = 20.0
    gyro_bias_rw_dph_per_rth: NonNegative = 10.0
    gyro_scale_sd_ppm: NonNegative = 300.0
    # SD of each element of the gyro's constant scale/misalignment dM, omega_meas = (I + dM) omega + b: 0.1 %, a
    # consumer MEMS gyro after a one-time calibration (`sim.target`'s mems figure; a log cannot state it). Carried
    # as a consider error (no estimate moves); the white part is gyro_scale_sd_ppm
    gyro_scale_const_ppm: NonNegative = 1000.0
    acc_noise_mg: Positive = 2.0
    acc_bias_mg: NonNegative = 10.0  # SD of the accelerometer bias (prior of the local filters' bias states)
    acc_bias_rw_mg_per_rts: NonNegative = 0.05
    mag_noise_ut: Positive = 0.5
    range_sigma_m: Positive = 0.0015
    # alignment
    static_min_s: Positive = 1.0
    static_max_s: Positive = 30.0
    static_gyro_tol_dps: Positive = 1.5
    static_acc_sd_tol_mps2: Positive = 0.15
    align_mag_step_tol_ut: Positive = 3.0
    noise_from_static: bool = True  # figures session.toml lacks: measured in the alignment window
    gravity_from_static: bool = True  # gravity magnitude = mean |f| in the alignment window
    # LF1/LF2 accelerometer aiding: gravity update while quasi-static, bounded motion otherwise
    acc_static_tol_mps2: Positive = 0.5
    gyro_static_tol_dps: Positive = 30.0
    motion_model: bool = True
    motion_sd_mps: Positive = 0.2
    motion_sd_m: Positive = 0.1
    motion_interval_s: Positive = 1.0
    motion_freq_hz: NonNegative = 0.0  # > 0: correlated (damped-oscillator) hand-motion model
    motion_damping: Positive = 0.7071
    motion_step_s: Positive = 0.05
    motion_fit: bool = True  # fit the oscillator (frequency, damping, displacement) to the log's own acceleration PSD
    motion_fit_band_hz: tuple[NonNegative, Positive] = (0.3, 5.0)
    smooth: bool = True  # forward-backward smoothing of each local filter (post-processing)
    gyro_err_pct: NonNegative = 0.0  # > 0: local filters estimate the gyro scale/misalignment (prior SD, %)
    gyro_err_rw_ppm_rts: NonNegative = 0.0
    # LF1 magnetometer: survey (body-fixed offsets removed, room disturbances masked), gating
    mag_survey: bool = True
    mag_norm_tol_ut: float = 4.0  # without the survey: field-magnitude test (<= 0 disables it and the dip test)
    mag_dip_tol_deg: float = 3.0
    mag_nis_window_s: NonNegative = 1.0  # > 0: reject the field while its mean NIS over this window exceeds ...
    mag_nis_ratio: Positive = 3.0  # ... this many times its expectation (1 dof)
    imu_gap_max_s: Positive = 1.0  # refuse a log with a longer IMU gap: the attitude cannot be carried across it
    mag_lag_from_log: bool = True  # estimate the magnetometer's delay behind the gyro and remove it
    mag_lag_max_s: NonNegative = 0.05
    # LF2 gating
    range_gate_probability: Probability = 0.9999
    # shots detected when shots.csv is absent
    shot_min_s: Positive = 2.0
    shot_gyro_tol_dps: Positive = 0.5
    fault: FaultParams = Field(default_factory=FaultParams)  # the [target_fkf.fault] table

    @model_validator(mode="after")
    def _ordered(self) -> TargetFkfParams:
        if self.static_min_s > self.static_max_s:
            raise ValueError("static_min_s must not exceed static_max_s")
        lo, hi = self.motion_fit_band_hz
        if not lo < hi:
            raise ValueError("motion_fit_band_hz must be [lo, hi] with lo < hi")
        return self


# Chain name -> (its table in a pipeline file, the model of that table). `tpos_cli.pipeline.CHAINS`
# pairs the same names with the chains' `run` functions.
SECTIONS: dict[str, tuple[str, type[Section]]] = {
    "ingest": ("ingest", IngestParams),
    "target_fkf": ("target_fkf", TargetFkfParams),
    "drive_smooth": ("drive_smooth", DriveSmoothParams),
    "ranging_fatci": ("ranging_fatci", RangingParams),
}


# --------------------------------------------------------------------------- files
@dataclass(frozen=True)
class PipelineFile:
    name: str
    description: str
    chain: str
    kinds: tuple[str, ...]
    params: dict
    path: Path
    label: str = ""  # how errors name the file: a user's path as given, a bundled pipeline's file name


@dataclass(frozen=True)
class ResolvedConfig:
    """A pipeline with its chain's table validated and every default filled in."""

    pipeline: PipelineFile
    params: Section  # the validated model the chain runs with
    resolved: dict  # {section: every key, defaults included}: what summary.json records
    sha256: str  # hash of pipeline name, chain and `resolved` (batch recognises finished runs by it)


def pipelines_dir() -> Path:
    """The folder of bundled pipelines: the package data `tpos_cli.pipelines` (the repository's
    `pipelines/`, mapped into the package by setup.py), in an editable install or a wheel; the checkout's
    `pipelines/` when the package is imported from a checkout beside a plain install (pytest run in the
    repository after `pip install .`: the checkout's tpos_cli comes first and has no tpos_cli.pipelines)."""
    try:
        return Path(str(importlib.resources.files("tpos_cli.pipelines")))
    except ModuleNotFoundError:
        return Path(__file__).resolve().parent.parent / "pipelines"


def list_pipelines() -> list[PipelineFile]:
    return [load_pipeline_file(p) for p in sorted(pipelines_dir().glob("*.toml"))]


def resolve_pipeline(name_or_path: str | Path | None, kind: str) -> PipelineFile:
    """A pipeline by bundled name, by path, or (None) the default for a session kind."""
    if name_or_path is None:
        for p in list_pipelines():
            if kind in p.kinds:
                return p
        raise InvalidInputError(f"no pipeline in {pipelines_dir()} is the default for sessions of kind {kind!r}; pass -p")
    cand = Path(name_or_path)
    if cand.suffix == ".toml" or cand.exists():
        if not cand.exists():
            raise InvalidInputError(f"{cand}: pipeline file not found")
        return load_pipeline_file(cand, str(cand))  # the user's file, named as the user gave it
    path = pipelines_dir() / f"{name_or_path}.toml"
    if not path.exists():
        names = ", ".join(p.stem for p in sorted(pipelines_dir().glob("*.toml")))
        raise InvalidInputError(f"unknown pipeline {name_or_path!r} (bundled: {names})")
    return load_pipeline_file(path)


def load_pipeline_file(path: Path, label: str | None = None) -> PipelineFile:
    """Read a pipeline TOML and validate its `[pipeline]` table (the chain's table: `resolve_config`).
    label: how errors name the file (default its name, as for a bundled pipeline)."""
    label = path.name if label is None else label
    raw = read_toml(path, label)  # regular file, size and depth bounded: a FIFO or a deep nest is refused
    head_raw = raw.get("pipeline")
    if not isinstance(head_raw, dict):
        raise InvalidInputError(f"{label}: [pipeline] section with name, description, chain is required")
    head = _validate(PipelineHead, head_raw, label, "pipeline", {})
    if head.chain not in SECTIONS:
        raise InvalidInputError(f"{label} [pipeline] chain: {head.chain!r} is not one of {', '.join(sorted(SECTIONS))}")
    params = {k: v for k, v in raw.items() if k != "pipeline"}
    return PipelineFile(name=head.name, description=head.description, chain=head.chain, kinds=head.kinds,
                        params=params, path=path, label=label)


def apply_overrides(params: dict, overrides: Mapping[str, object]) -> dict:
    """Dotted overrides (`section.key = value`) onto a parameter dict (a copy)."""
    out = json.loads(json.dumps(params))
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise InvalidInputError(f"--set {dotted}: {p!r} is not a table")
        node[parts[-1]] = value
    return out


def resolve_config(pipe: PipelineFile, overrides: Mapping[str, object] | None = None) -> ResolvedConfig:
    """Validate a pipeline's chain table (with dotted `--set` overrides) against its model.

    Unknown tables and keys, wrong types and out-of-range values raise InvalidInputError naming the
    file, the table and the key (and the `--set` that gave the value).
    """
    overrides = dict(overrides or {})
    section, model = SECTIONS[pipe.chain]
    params = apply_overrides(pipe.params, overrides)
    unknown = sorted(set(params) - {section})
    if unknown:
        raise InvalidInputError(f"{pipe.label or pipe.path.name}: unknown table [{unknown[0]}] (chain {pipe.chain} reads [{section}])")
    table = params.get(section, {})
    if not isinstance(table, dict):
        raise InvalidInputError(f"{pipe.label or pipe.path.name}: [{section}] must be a table")
    parsed = _validate(model, table, pipe.label or pipe.path.name, section, overrides)
    resolved = {section: parsed.model_dump(mode="json")}
    # the keys set explicitly count too: a set key outranks the session's figure (`tpos_cli.imu_noise`)
    sha = config_hash({"pipeline": pipe.name, "chain": pipe.chain, "params": resolved, "set": sorted(parsed.model_fields_set)})
    return ResolvedConfig(pipeline=pipe, params=parsed, resolved=resolved, sha256=sha)


def _validate(model: type[Section], table: dict, file: str, section: str, overrides: Mapping[str, object]):
    try:
        return model.model_validate(table)
    except ValidationError as exc:
        raise InvalidInputError(_message(exc, model, file, section, overrides)) from None


def _message(exc: ValidationError, model: type[Section], file: str, section: str, overrides: Mapping[str, object]) -> str:
    """One line per problem: `file [section] key: what` (+ the `--set` that gave the value)."""
    lines = []
    for err in exc.errors():
        loc = [str(x) for x in err["loc"] if not str(x).startswith("function-after")]
        key = ".".join(loc)
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "extra_forbidden":
            known = _known_keys(model, loc[:-1])
            close = difflib.get_close_matches(loc[-1], known, n=1)
            msg = "unknown key" + (f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})")
        # the `--set` overrides that gave this value: the key itself, a table above it or keys below it
        dotted = f"{section}.{key}" if key else section
        sets = [f"--set {k}={v!r}" for k, v in overrides.items()
                if k == dotted or dotted.startswith(k + ".") or k.startswith(dotted + ".")]
        given = f" ({', '.join(sets)})" if sets else ""
        lines.append(f"{file} [{section}]{' ' + key if key else ''}{given}: {msg}")
    return "; ".join(lines)


def _known_keys(model: type[BaseModel], path: list[str]) -> list[str]:
    for name in path:
        field = model.model_fields.get(name)
        ann = getattr(field, "annotation", None)
        if not (isinstance(ann, type) and issubclass(ann, BaseModel)):
            return []
        model = ann
    return sorted(model.model_fields)


def config_hash(config: dict) -> str:
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()
