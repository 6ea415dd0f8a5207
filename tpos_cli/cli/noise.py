"""`tpos noise`: IMU noise figures from a static log by Allan deviation."""

from __future__ import annotations

from pathlib import Path

import typer

from tpos_cli.cli._common import exit_on_error, parse_window, working


def noise(
    session: Path = typer.Argument(..., help="Session directory (a static IMU log)."),
    static: str = typer.Option(None, "--static", help="T0:T1 on the logger clock; default: the whole log."),
    plot: Path = typer.Option(None, "--plot", help="Allan-deviation PNG to write (default: <session>_allan.png here)."),
) -> None:
    """Allan deviation of a static IMU log per axis: random walk, bias instability, rate random walk,
    printed as the session.toml `[imu]` noise keys. The session is not modified.

    Example: tpos noise static_log --static 100:3700
    """
    import numpy as np

    from tpos_cli.errors import InvalidInputError
    from tpos_cli.importers.session_out import dumps_toml
    from tpos_cli.noise import identify_noise
    from tpos_cli.report.figures import allan_page
    from tpos_cli.session import load_session

    with exit_on_error(), working("tpos noise: Allan deviation"):
        s = load_session(session)
        t = s.imu.t_s + s.t0_s
        sel = np.ones(t.size, bool)
        if static:
            a, b = parse_window(static, "--static")
            sel = (t >= a) & (t <= b)
            if sel.sum() < 2:
                raise InvalidInputError(f"--static {static}: no IMU samples in that window (log spans {t[0]:.2f}-{t[-1]:.2f})")
        from tpos_cli.alignment import static_mask

        still = static_mask(t[sel], s.imu.gyro_b_rps[sel], s.imu.acc_b_mps2[sel])
        if still.mean() < 0.95:
            raise InvalidInputError(f"{session}: only {100 * still.mean():.0f}% of the window is at rest; Allan analysis needs a static log (choose one with --static T0:T1)")
        nf = identify_noise(t[sel], s.imu.gyro_b_rps[sel], s.imu.acc_b_mps2[sel])
        # the session directory's own name, never [session] name: a name holding '../' would write elsewhere
        out = plot or Path(f"{Path(session).resolve().name}_allan.png")
        allan_page(nf).savefig(out, dpi=120)  # the same figure as the report's Allan page
    typer.echo(dumps_toml({"imu": nf.toml_keys()}).rstrip())
    typer.echo(f"# Allan deviation plot: {out}")
