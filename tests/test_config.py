"""Pipeline configuration (`tpos_cli.config`): pydantic models refuse every bad key, type and value
with a one-line message naming the file, table and key, before any session data is read."""

import re
import shutil
import subprocess
import sys

import pytest
from pydantic import BaseModel
from typer.testing import CliRunner

from tests.helpers.paths import REPO
from tpos_cli.cli import app
from tpos_cli.config import (
    SECTIONS,
    DriveSmoothParams,
    load_pipeline_file,
    pipelines_dir,
    resolve_config,
    resolve_pipeline,
)
from tpos_cli.errors import InvalidInputError

SAMPLE_LOGS = REPO / "sample_logs"

DRIVE = pipelines_dir() / "drive-smooth.toml"
RANGING = pipelines_dir() / "ranging-fatci.toml"
TARGET = pipelines_dir() / "target-fkf.toml"

BAD = [
    # (pipeline, override, the message's end)
    (DRIVE, {"drive_smooth.gate_probability": 2},
     "[drive_smooth] gate_probability (--set drive_smooth.gate_probability=2): Input should be less than 1"),
    (DRIVE, {"drive_smooth.output_rate_hz": float("nan")},
     "[drive_smooth] output_rate_hz (--set drive_smooth.output_rate_hz=nan): Input should be a finite number"),
    (DRIVE, {"drive_smooth.init_sigma_pos_m": -1.0},
     "init_sigma_pos_m (--set drive_smooth.init_sigma_pos_m=-1.0): Input should be greater than 0"),
    (DRIVE, {"drive_smooth.gyro_bias_dph": -0.5},
     "gyro_bias_dph (--set drive_smooth.gyro_bias_dph=-0.5): Input should be greater than or equal to 0"),
    (DRIVE, {"drive_smooth.smoother": "kalman"},
     "smoother (--set drive_smooth.smoother='kalman'): Input should be 'rts', 'two_filter' or 'simplified'"),
    (DRIVE, {"drive_smooth.cov_step_s": "0.1"}, "cov_step_s (--set drive_smooth.cov_step_s='0.1'): Input should be a valid number"),
    (DRIVE, {"drive_smooth.heading_hypotheses": True},
     "heading_hypotheses (--set drive_smooth.heading_hypotheses=True): Input should be a valid integer"),
    (DRIVE, {"drive_smooth.heading_hypotheses": 100_000_000},  # a typo of 12: one filter pass each
     "heading_hypotheses (--set drive_smooth.heading_hypotheses=100000000): Input should be less than or equal to 360"),
    (DRIVE, {"drive_smooth.gate_probabilty": 0.9},
     "gate_probabilty (--set drive_smooth.gate_probabilty=0.9): unknown key (did you mean 'gate_probability'?)"),
    (RANGING, {"ranging_fatci.smooth_source": "lc", "ranging_fatci.solutions": ["tc"]}, "smooth_source 'lc' is not among solutions ['tc']"),
    (RANGING, {"ranging_fatci.solutions": ["lc", "ekf"]},
     "[ranging_fatci] solutions.1 (--set ranging_fatci.solutions=['lc', 'ekf']): Input should be 'lc', 'tc' or 'fatci'"),
    (RANGING, {"ranging_fatci.fuzzy.input_sets": {"LE": [0.0, 0.5, 1.0]}}, "[ranging_fatci] fuzzy (--set ranging_fatci.fuzzy.input_sets="),
    (RANGING, {"ranging_fatci.lc_min_anchors": 2},
     "lc_min_anchors (--set ranging_fatci.lc_min_anchors=2): Input should be greater than or equal to 3"),
    (TARGET, {"target_fkf.beta": 0.0}, "[target_fkf] beta (--set target_fkf.beta=0.0): Input should be greater than 0"),
    (TARGET, {"target_fkf.fault.nis_probability": 1.5},
     "[target_fkf] fault.nis_probability (--set target_fkf.fault.nis_probability=1.5): Input should be less than 1"),
    (TARGET, {"target_fkf.fault.no_such": 1},
     "[target_fkf] fault.no_such (--set target_fkf.fault.no_such=1): unknown key (known: consistency_probability, "),
]


@pytest.mark.parametrize(("path", "override", "message"), BAD, ids=[next(iter(o)) for _, o, _ in BAD])
def test_bad_value_is_refused_naming_file_and_key(path, override, message):
    with pytest.raises(InvalidInputError) as exc:
        resolve_config(load_pipeline_file(path), override)
    text = str(exc.value)
    assert text.startswith(path.name + " [")
    assert message in text
    assert "\n" not in text


def test_bad_value_in_the_file_names_the_file(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text('[pipeline]\nname = "mine"\nchain = "drive_smooth"\n\n[drive_smooth]\ngate_probability = 1.0\n')
    with pytest.raises(InvalidInputError, match=r"^mine\.toml \[drive_smooth\] gate_probability: Input should be less than 1$"):
        resolve_config(load_pipeline_file(f))


def test_a_users_pipeline_is_named_by_the_path_given(tmp_path):
    """A bundled pipeline is named by its file name; one the user passes by the path as given
    (`-p /dev/zero` said "zero: is a device")."""
    f = tmp_path / "mine.toml"
    f.write_text('[pipeline]\nname = "mine"\nchain = "drive_smooth"\n\n[drive_smooth]\ngate_probability = 1.0\n')
    with pytest.raises(InvalidInputError, match=rf"^{re.escape(str(f))} \[drive_smooth\] gate_probability: Input should be less"):
        resolve_config(resolve_pipeline(str(f), "drive"))
    with pytest.raises(InvalidInputError, match=r"^/dev/zero: is a device"):
        resolve_pipeline("/dev/zero", "drive")
    with pytest.raises(InvalidInputError, match=r"^drive-smooth\.toml \[drive_smooth\] gate_probability"):
        resolve_config(resolve_pipeline("drive-smooth", "drive"), {"drive_smooth.gate_probability": 2})


def test_unknown_table_and_header_key_are_refused(tmp_path):
    with pytest.raises(InvalidInputError, match=r"unknown table \[no_such\]"):
        resolve_config(load_pipeline_file(DRIVE), {"no_such.x": 1})
    f = tmp_path / "x.toml"
    f.write_text('[pipeline]\nname = "x"\nchain = "drive_smooth"\nkinds = ["drive"]\nmode = 1\n')
    with pytest.raises(InvalidInputError, match=r"^x\.toml \[pipeline\] mode: unknown key"):
        load_pipeline_file(f)


def test_defaults_live_in_the_models_and_are_recorded():
    cfg = resolve_config(load_pipeline_file(DRIVE))
    assert cfg.params == DriveSmoothParams(**load_pipeline_file(DRIVE).params["drive_smooth"])
    assert cfg.resolved["drive_smooth"] == cfg.params.model_dump(mode="json")
    assert cfg.resolved["drive_smooth"]["bias_tau_s"] == DriveSmoothParams.model_fields["bias_tau_s"].default
    # the hash follows the resolved values, not their spelling, and which keys were set (a set IMU
    # figure outranks the session's: tpos_cli.imu_noise)
    int_tau = resolve_config(load_pipeline_file(DRIVE), {"drive_smooth.bias_tau_s": 300})
    float_tau = resolve_config(load_pipeline_file(DRIVE), {"drive_smooth.bias_tau_s": 300.0})
    assert int_tau.sha256 == float_tau.sha256 != cfg.sha256
    other = resolve_config(load_pipeline_file(DRIVE), {"drive_smooth.bias_tau_s": 301.0})
    assert other.sha256 != float_tau.sha256
    with pytest.raises(Exception, match="frozen"):
        cfg.params.bias_tau_s = 1.0  # type: ignore[misc]


def _keys(model: type[BaseModel], prefix: str = ""):
    for name, field in model.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            yield from _keys(ann, f"{prefix}{name}.")
        else:
            yield prefix, name


@pytest.mark.parametrize("chain", sorted(SECTIONS))
def test_every_key_is_documented(chain):
    section, model = SECTIONS[chain]
    readme = (pipelines_dir() / "README.md").read_text(encoding="utf-8")
    # the chain's part of the README: from its heading (`[section]`) to the next `## ` heading
    part = re.search(rf"^## [^\n]*`\[{section}\]`.*?(?=^## |\Z)", readme, re.S | re.M)
    assert part is not None, f"pipelines/README.md has no section for [{section}]"
    missing = [f"{prefix}{name}" for prefix, name in _keys(model)
               if f"`{prefix}{name}`" not in part.group(0) and f"`{name}`" not in part.group(0)]
    assert not missing, f"[{section}] keys not documented in pipelines/README.md: {missing}"


def test_cli_refuses_a_bad_override_before_reading_data(tmp_path):
    # a session whose data files are missing: only the config can be checked, and it is, first
    s = tmp_path / "s"
    s.mkdir()
    shutil.copy(SAMPLE_LOGS / "drive_outage" / "session.toml", s / "session.toml")
    r = CliRunner().invoke(app, ["process", str(s), "-o", str(tmp_path / "run"), "-q",
                                 "--set", "drive_smooth.output_rate_hz=nan"])
    assert r.exit_code == 2, r.output
    assert "drive-smooth.toml [drive_smooth] output_rate_hz" in r.output
    assert "finite number" in r.output
    assert not (tmp_path / "run").exists()
    # the same session with good parameters fails on its missing IMU file instead
    r = CliRunner().invoke(app, ["process", str(s), "-o", str(tmp_path / "run"), "-q"])
    assert r.exit_code == 2 and "imu" in r.output.lower()


def test_a_run_builds_only_its_own_models():
    """`Section`'s defer_build: a model's validator is built at its first validation; resolving the drive's
    pipeline builds [pipeline] and [drive_smooth] only. In a fresh interpreter (this one built them all)."""
    code = ("from tpos_cli import config\n"
            "config.resolve_config(config.resolve_pipeline(None, 'drive'))\n"
            "print(*(m.__name__ for m in (config.PipelineHead, config.DriveSmoothParams, config.IngestParams,\n"
            "      config.RangingParams, config.FuzzyParams, config.TargetFkfParams, config.FaultParams)\n"
            "      if m.__pydantic_complete__))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=REPO).stdout
    assert out.split() == ["PipelineHead", "DriveSmoothParams"], out
