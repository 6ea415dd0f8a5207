"""Every bundled pipeline file is valid data naming a registered chain; each kind has one default."""

import pytest

from tpos_cli import schema
from tpos_cli.config import SECTIONS, list_pipelines, load_pipeline_file, pipelines_dir, resolve_config, resolve_pipeline
from tpos_cli.errors import InvalidInputError
from tpos_cli.pipeline import CHAINS

PIPELINE_FILES = sorted(pipelines_dir().glob("*.toml"))


@pytest.mark.parametrize("path", PIPELINE_FILES, ids=[p.stem for p in PIPELINE_FILES])
def test_pipeline_file_is_valid(path):
    p = load_pipeline_file(path)
    assert p.name == path.stem
    assert p.chain in CHAINS
    assert p.description
    assert set(p.kinds) <= set(schema.SESSION_KINDS)


def test_at_most_one_default_per_kind():
    for kind in schema.SESSION_KINDS:
        assert sum(kind in p.kinds for p in list_pipelines()) <= 1


def test_unknown_chain_is_refused(tmp_path):
    f = tmp_path / "x.toml"
    f.write_text('[pipeline]\nname = "x"\ndescription = "d"\nchain = "os.system"\n')
    with pytest.raises(InvalidInputError, match="not one of"):
        load_pipeline_file(f)
    with pytest.raises(InvalidInputError):
        resolve_pipeline("no-such-pipeline", "drive")


@pytest.mark.parametrize("path", PIPELINE_FILES, ids=[p.stem for p in PIPELINE_FILES])
def test_pipeline_resolves_before_any_data_is_read(path):
    cfg = resolve_config(load_pipeline_file(path))
    (section,) = cfg.resolved
    assert section == SECTIONS[cfg.pipeline.chain][0]
    assert isinstance(cfg.params, SECTIONS[cfg.pipeline.chain][1])
    assert set(load_pipeline_file(path).params.get(section, {})) <= set(cfg.resolved[section])  # defaults fill the rest
    assert len(cfg.sha256) == 64


def test_every_chain_has_a_model():
    assert set(CHAINS) == set(SECTIONS)


def test_a_session_kind_the_contract_does_not_know_is_named_by_the_loader(tmp_path):
    """`[session] kind = "boat"`: the loader's message with the valid kinds, not "no default pipeline ... pass -p"."""
    import shutil
    from pathlib import Path

    from tpos_cli.pipeline import process_session

    src = Path(__file__).resolve().parents[1] / "sample_logs" / "drive_outage"
    s = tmp_path / "boat"
    shutil.copytree(src, s)
    toml = (s / "session.toml").read_text()
    assert 'kind = "drive"' in toml
    (s / "session.toml").write_text(toml.replace('kind = "drive"', 'kind = "boat"'))
    with pytest.raises(InvalidInputError, match=r"kind must be one of target, drive, ranging, got 'boat'"):
        process_session(s, run_dir=tmp_path / "run")


@pytest.mark.parametrize("spare", [False, True])
def test_beside_returns_both_results_and_raises_either_failure(monkeypatch, spare):
    """`pipeline._beside` (the conventions' checks beside the chain's import): the same results with
    or without a helper thread, and an exception from either side reaches the caller."""
    import tpos_cli.pipeline as pl

    monkeypatch.setattr(pl, "spare_cpu", lambda: spare)
    assert pl._beside(lambda: "chain", lambda x: x + 1, 41) == ("chain", 42)

    def fails(_):
        raise InvalidInputError("refused")

    with pytest.raises(InvalidInputError, match="refused"):
        pl._beside(lambda: "chain", fails, 0)
    with pytest.raises(KeyError):
        pl._beside(lambda: {}["nope"], lambda x: x, 0)


def test_a_pipeline_made_for_another_kind_runs_with_a_warning_naming_both(tmp_path):
    """`-p` with a pipeline of another kind (target-fkf on a drive log, say) is allowed, but the run says so: its
    verdict would otherwise read the mismatch as a bad log. A pipeline for every kind (`kinds = []`) never warns."""
    import json

    from tests.helpers.sessions import write_minimal_session
    from tpos_cli.pipeline import process_session

    s = write_minimal_session(tmp_path / "s")  # kind "drive"
    text = (pipelines_dir() / "ingest.toml").read_text()
    assert "kinds = []" in text
    f = tmp_path / "target-ingest.toml"
    f.write_text(text.replace('name = "ingest"', 'name = "target-ingest"').replace("kinds = []", 'kinds = ["target"]'))
    warned = json.loads((process_session(s, f, tmp_path / "r1").run_dir / "summary.json").read_text())["warnings"]
    assert any("made for sessions of kind target; this session is of kind 'drive'" in w for w in warned), warned
    plain = json.loads((process_session(s, "ingest", tmp_path / "r2").run_dir / "summary.json").read_text())["warnings"]
    assert not any("made for sessions of kind" in w for w in plain), plain
