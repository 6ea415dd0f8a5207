"""`tpos simulate`: write a synthetic session with exact truth."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, show_progress
from tpos_cli.io.bounded import MAX_TABLE_ROWS

_ONLY = {
    "drive": ("outage", "trajectory_seed", "gps_sigma_h", "gps_sigma_v", "gps_sigma_vel", "shots", "shot_range", "gps_clock_offset",
              "mounting", "lever_arm", "vibration_mg", "odometry", "gps_rtk"),
    "target": ("motion", "wall_distance", "mag_disturbance_ut", "mag_disturbance_start", "mag_disturbance_end"),
    "ranging": ("dropout", "nlos_prob"),
}


def _floats(text: str, n: int, option: str) -> list[float]:
    parts = text.split(":")
    try:
        if len(parts) != n:
            raise ValueError
        values = [float(p) for p in parts]
        if not all(math.isfinite(v) for v in values):
            raise ValueError
        return values
    except ValueError:
        raise typer.BadParameter(f"expected {n} numbers separated by ':', got {text!r}", param_hint=option) from None


# (lowest, highest) of the numeric options: beyond them a simulation is no log (a duration of 1e9 s
# asked for 894 GiB; NaN and negative seeds ended in internal errors).
_RANGES = {
    "--seed": (0, 2**32 - 1), "--trajectory-seed": (0, 2**32 - 1), "--duration": (1.0, 86_400.0), "--rate": (1.0, 10_000.0),
    "--t0": (-1e10, 1e10), "--gps-sigma-h": (0.0, 1_000.0), "--gps-sigma-v": (0.0, 1_000.0), "--gps-sigma-vel": (0.0, 100.0),
    "--shots": (0, 10_000), "--shot-range": (0.1, 10_000.0), "--wall-distance": (0.1, 1_000.0),
    "--mag-disturbance-ut": (0.0, 10_000.0), "--mag-disturbance-start": (0.0, 86_400.0),
    "--mag-disturbance-end": (0.0, 86_400.0), "--nlos-prob": (0.0, 1.0), "--gps-clock-offset": (-10.0, 10.0),
    "--vibration-mg": (0.0, 10_000.0),
}
MAX_SAMPLES = MAX_TABLE_ROWS


def _check_ranges(values: dict) -> None:
    """Each given numeric option finite and within _RANGES, else a usage error (exit 2)."""
    for option, v in values.items():
        lo, hi = _RANGES[option]
        if v is not None and not (math.isfinite(v) and lo <= v <= hi):
            raise typer.BadParameter(f"{v!r} is outside {lo:g} to {hi:g}", param_hint=option)


def simulate(
    scenario: str = typer.Argument(..., help="drive | target | ranging"),
    out: Path = typer.Argument(..., help="Session directory to write (must not exist, or use --force)."),
    seed: int = typer.Option(0, "--seed", help="Seed of the sensor noise (and of the drive manoeuvres)."),
    duration: float = typer.Option(None, "--duration", help="Seconds; default drive 120, target 90, ranging 60."),
    grade: str = typer.Option(None, "--grade", help="Sensor errors: paper | mems | tactical | perfect; default mems (drive), paper (target, ranging)."),
    rate: float = typer.Option(100.0, "--rate", help="IMU rate, Hz."),
    fmt: str = typer.Option("parquet", "--format", help="Time-stamped tables as parquet or csv."),
    name: str = typer.Option(None, "--name", help="[session] name; default the directory name."),
    t0: float = typer.Option(0.0, "--t0", help="Logger-clock time of the first IMU sample, s."),
    force: bool = typer.Option(False, "--force", help="Replace OUT if it exists."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress output, only the final line."),
    outage: list[str] = typer.Option(None, "--outage", help="drive: GPS outage START:LEN (s from the start); repeatable; 'none' for no outage. Default 40:30."),
    trajectory_seed: int = typer.Option(None, "--trajectory-seed", help="drive: seed of the manoeuvres (default --seed)."),
    gps_sigma_h: float = typer.Option(None, "--gps-sigma-h", help="drive: GPS horizontal noise SD per axis, m (default 1.5)."),
    gps_sigma_v: float = typer.Option(None, "--gps-sigma-v", help="drive: GPS vertical noise SD, m (default 2.5)."),
    gps_sigma_vel: float = typer.Option(None, "--gps-sigma-vel", help="drive: GPS velocity noise SD per axis, m/s (default 0.05)."),
    shots: int = typer.Option(None, "--shots", help="drive: laser shots (LR1 along the body x axis) on targets ahead, spread over the drive (default 0)."),
    shot_range: float = typer.Option(None, "--shot-range", help="drive: distance to the shot targets, m (default 40)."),
    gps_clock_offset: float = typer.Option(None, "--gps-clock-offset", help="drive: GPS records taken at IMU time t are stamped t - D, s (default 0)."),
    mounting: str = typer.Option(None, "--mounting", help="drive: the IMU's roll:pitch:yaw on the car, deg (not written to session.toml; default 0:0:0)."),
    lever_arm: str = typer.Option(None, "--lever-arm", help="drive: GPS antenna x:y:z in the car's axes, m (session.toml gets it in the IMU's; default 0:0:0)."),
    vibration_mg: float = typer.Option(None, "--vibration-mg", help="drive: engine and road vibration on the accelerometers, RMS mg per axis (default 0)."),
    odometry: str = typer.Option(None, "--odometry", help="drive: an odometer table RATE_HZ:SCALE_ERROR (e.g. 20:0.02; default none)."),
    gps_rtk: bool = typer.Option(None, "--gps-rtk", show_default=False,
                                 help="drive: RTK-like fixes: white at a 1 cm floor, float stretches (stated SD raised 1.2-2.6x, "
                                      "error 5-25 cm) and multipath steps at the floor SD (sim/rtk.py; the real RTK log's figures). "
                                      "Replaces --gps-sigma-h/-v."),
    motion: str = typer.Option(None, "--motion", help="target: shots (aim at each target in turn) or sine (paper 000 sec. 6.1)."),
    wall_distance: float = typer.Option(None, "--wall-distance", help="target: distance to the wall, m (default 12)."),
    mag_disturbance_ut: float = typer.Option(None, "--mag-disturbance-ut", help="target: add a magnetic disturbance of this magnitude, uT (paper 000: 50)."),
    mag_disturbance_start: float = typer.Option(None, "--mag-disturbance-start", help="target: disturbance start, s (default 4)."),
    mag_disturbance_end: float = typer.Option(None, "--mag-disturbance-end", help="target: disturbance end, s (default: the end)."),
    dropout: list[str] = typer.Option(None, "--dropout", help="ranging: anchor dropout ID:START:LEN; repeatable; 'none' for none. Default A2:18:5 and A2:40:5."),
    nlos_prob: float = typer.Option(None, "--nlos-prob", help="ranging: fraction of ranges with an NLOS spike (default 0.03)."),
) -> None:
    """Simulate SCENARIO and write it to OUT as a session (docs/log-format.md) with exact truth.

    Scenarios follow the papers: `target` (paper 000: static observer, three rangefinders on a
    wall, shots, reference point), `drive` (paper 003: land vehicle, 100 Hz IMU, 1 Hz GPS with
    outages), `ranging` (paper 002: corridor with four anchors, range error model, calibration).

    Example: tpos simulate drive runs/drive_sim --seed 7 --duration 300 --outage 40:30 --outage 150:20

    Example with RTK-like fixes: tpos simulate drive runs/drive_rtk --gps-rtk --outage none
    """
    from tpos_cli.sim import SCENARIOS

    if scenario not in SCENARIOS:
        raise typer.BadParameter(f"{scenario!r} is not one of {', '.join(SCENARIOS)}", param_hint="SCENARIO")
    given = {k: v for k, v in locals().items() if k in sum(_ONLY.values(), ()) and v not in (None, [])}
    for k in given:
        if k not in _ONLY[scenario]:
            raise typer.BadParameter(f"does not apply to scenario {scenario!r}", param_hint="--" + k.replace("_", "-"))
    _check_ranges({"--seed": seed, "--trajectory-seed": trajectory_seed, "--duration": duration, "--rate": rate, "--t0": t0,
                   "--gps-sigma-h": gps_sigma_h, "--gps-sigma-v": gps_sigma_v, "--gps-sigma-vel": gps_sigma_vel,
                   "--shots": shots, "--shot-range": shot_range, "--wall-distance": wall_distance,
                   "--mag-disturbance-ut": mag_disturbance_ut, "--mag-disturbance-start": mag_disturbance_start,
                   "--mag-disturbance-end": mag_disturbance_end, "--nlos-prob": nlos_prob, "--gps-clock-offset": gps_clock_offset,
                   "--vibration-mg": vibration_mg})
    if duration is not None and duration * rate > MAX_SAMPLES:
        raise typer.BadParameter(f"{duration:g} s at {rate:g} Hz is more than {MAX_SAMPLES} IMU samples, the row limit of a "
                                 "session table", param_hint="--duration")
    kw: dict = {"seed": seed, "rate_hz": rate, "t0_s": t0, "name": name or out.name}
    if duration is not None:
        kw["duration_s"] = duration
    if grade is not None:
        kw["grade"] = grade
    if outage:
        kw["outages"] = [] if outage == ["none"] else [_floats(o, 2, "--outage") for o in outage]
    if gps_rtk:
        if gps_sigma_h is not None or gps_sigma_v is not None:
            raise typer.BadParameter("the RTK floor replaces --gps-sigma-h/--gps-sigma-v: give one or the other", param_hint="--gps-rtk")
        kw["gps_rtk"] = True
    if mounting:
        kw["mounting_rpy_deg"] = _floats(mounting, 3, "--mounting")
        if max(abs(v) for v in kw["mounting_rpy_deg"]) > 180.0:
            raise typer.BadParameter(f"angles within +-180 deg, got {mounting!r}", param_hint="--mounting")
    if lever_arm:
        kw["lever_arm_m"] = _floats(lever_arm, 3, "--lever-arm")
        if max(abs(v) for v in kw["lever_arm_m"]) > 50.0:
            raise typer.BadParameter(f"each component within +-50 m, got {lever_arm!r}", param_hint="--lever-arm")
    if odometry:
        rate_hz, scale = _floats(odometry, 2, "--odometry")
        if not (0.0 < rate_hz <= rate and -0.5 < scale < 0.5):
            raise typer.BadParameter(f"rate in (0, {rate:g}] Hz and scale error in (-0.5, 0.5), got {odometry!r}", param_hint="--odometry")
        kw["odometry_rate_hz"], kw["odometry_scale_error"] = rate_hz, scale
    if dropout:
        kw["dropouts"] = [] if dropout == ["none"] else [(d.split(":")[0], *_floats(d.split(":", 1)[-1], 2, "--dropout")) for d in dropout]
    for key, arg in (("trajectory_seed", trajectory_seed), ("gps_sigma_h_m", gps_sigma_h), ("gps_sigma_v_m", gps_sigma_v),
                     ("gps_sigma_vel_mps", gps_sigma_vel), ("motion", motion), ("wall_distance_m", wall_distance),
                     ("mag_disturbance_ut", mag_disturbance_ut), ("mag_disturbance_start_s", mag_disturbance_start),
                     ("mag_disturbance_end_s", mag_disturbance_end), ("nlos_prob", nlos_prob),
                     ("shots", shots), ("shot_range_m", shot_range), ("gps_clock_offset_s", gps_clock_offset),
                     ("vibration_mg", vibration_mg)):
        if arg is not None:
            kw[key] = arg
    with exit_on_error():
        from tpos_cli.io.run_dir import check_session_out

        check_session_out(out, force=force)  # before the simulation: --force replaces a session, nothing else
        path = _run(scenario, kw, out, fmt, force, show_progress(quiet))
    typer.echo(f"{scenario}: wrote {path} (seed {seed})")


def _run(scenario: str, kw: dict, out: Path, fmt: str, force: bool, progress: bool) -> Path:
    from tpos_cli.sim import SCENARIOS
    from tpos_cli.sim.writer import write_session

    if not progress:
        return write_session(SCENARIOS[scenario](**kw), out, fmt=fmt, overwrite=force)
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(), transient=True) as bar:
        task = bar.add_task(f"simulating {scenario}", total=2)
        sim = SCENARIOS[scenario](**kw)
        bar.update(task, advance=1, description=f"writing {out}")
        path = write_session(sim, out, fmt=fmt, overwrite=force)
        bar.update(task, advance=1)
    return path
