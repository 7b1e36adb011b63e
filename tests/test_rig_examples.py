"""The documented rig files parse, and the simulator's can be checked with --dry-run."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.formats.rig_file import load_rig

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "rigs"


@pytest.mark.parametrize("name", ["smaract-gige.toml", "micromanager.toml", "sim-faults.toml"])
def test_example_rig_files_parse(name):
    rig = load_rig(str(EXAMPLES / name))
    if rig["driver"] == "hardware":
        assert set(rig["cameras"]) == {"top", "side"}
        assert set(rig["manipulator"]["limits_um"]) == {"x", "y", "z"}
    else:
        assert rig["overrides"]["top.faults.drop_rate"] == 0.05


def test_micromanager_config_path_is_relative_to_the_rig_file():
    rig = load_rig(str(EXAMPLES / "micromanager.toml"))
    assert rig["micromanager"]["config"] == str(EXAMPLES / "MMConfig_rig.cfg")


def test_sim_example_dry_run(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "acquire",
            "--rig",
            str(EXAMPLES / "sim-faults.toml"),
            "--out",
            str(tmp_path / "r"),
            "--poses",
            "40",
            "--dry-run",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "dry run: nothing moved, nothing written" in result.output
    assert not (tmp_path / "r").exists()
