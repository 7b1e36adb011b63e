"""The study (fast path): one seed's models against the oracle and the population's prior,
the command's file, the rigs it takes and its interruption."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from microcal.cli import app
from microcal.errors import InputError
from microcal.experiments.study import StudyConfig, run_seed
from microcal.kinematics.families import FAMILIES


def test_one_seed_of_a_study_measures_models_against_the_oracle():
    run = run_seed("population", 5, StudyConfig(poses=80, cycles=1, closed_loop=True))
    val = run.validation_mean_um
    assert val["oracle"] < val["quadratic"]
    assert val["oracle"] < val["matrix"]
    ap = run.ap_truth_mean_um
    assert ap["oracle"] < ap["matrix"] < ap["uncalibrated"]
    assert set(run.coverage_95) == {"quadratic", "smooth", "auto"}
    assert run.failed == {}
    assert run.family in FAMILIES
    # the loop closes on the fast probe: better than the open loop it starts from, and it
    # says how it ended at each target (home and the eight poses of one cycle)
    assert ap["closed_loop"] < ap["auto"]
    loop = run.closed_loop
    assert loop is not None
    assert loop.targets == 9
    assert sum(loop.status.values()) == 9
    assert 1 <= loop.iterations_mean <= 6
    assert list(run.to_json()) == [
        "seed", "uncalibrated_ap_truth_mean_um", "validation_mean_um", "ap_truth_mean_um",
        "ap_truth_max_um", "ap_vision_mean_um", "vap_truth_mean_um", "coverage_95", "family",
        "closed_loop", "failed", "n_poses", "render", "wall_s", "design", "rig_time_s",
        "tip_error_p95_um",
    ]  # fmt: skip
    assert run.rig_time_s > 0
    assert set(run.tip_error_p95_um) >= {"matrix", "quadratic", "smooth", "auto", "oracle"}


@pytest.mark.slow
def test_study_command_writes_and_refuses_a_foreign_file(tmp_path):
    out = tmp_path / "st"
    out.mkdir()
    (out / "study.json").write_text('{"mine": 1}')
    result = CliRunner().invoke(app, ["study", "--preset", "population", "--seeds", "1",
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 2
    assert "microcal did not write" in result.output
    (out / "study.json").unlink()
    result = CliRunner().invoke(app, ["study", "--preset", "population", "--seeds", "1",
                                      "--first-seed", "6", "--workers", "1", "--prior",
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.output
    study = json.loads((out / "study.json").read_text())
    assert study["format"] == "microcal.study/1"
    assert study["seeds"] == [6]
    assert "ap_truth_over_oracle.prior" in study["summary"]
    assert "ap_truth_over_oracle.prior" in result.output
    result = CliRunner().invoke(app, ["study", "--preset", "thesis", "--seeds", "1", "--prior",
                                      "--out", str(tmp_path / "t")])  # fmt: skip
    assert result.exit_code == 2
    assert result.output.count("\n") == 1
    assert "only the population preset" in result.output
    assert not (tmp_path / "t").exists()
    assert (out / "study.html").read_text().startswith("<!-- microcal study page -->")


def test_study_takes_a_simulated_rig_and_refuses_the_rest(tmp_path):
    from microcal.formats.study_file import study_platform

    rig = tmp_path / "rig.toml"
    rig.write_text('driver = "sim"\npreset = "population"\nseed = 9\n'
                   "[overrides.manipulator]\nsensor_noise_um = 0.1\n")  # fmt: skip
    assert study_platform("", rig) == ("population", {"manipulator.sensor_noise_um": 0.1})
    runner = CliRunner()
    both = runner.invoke(app, ["study", "--preset", "thesis", "--rig", str(rig), "--out", "x"])
    assert both.exit_code == 2
    assert "one of them" in both.output
    hardware = Path(__file__).parents[2] / "examples" / "rigs" / "smaract-gige.toml"
    hw = runner.invoke(app, ["study", "--rig", str(hardware), "--out", "x"])
    assert hw.exit_code == 2
    assert "driver = sim" in hw.output
    bad = runner.invoke(app, ["study", "--preset", "population", "--design", "spiral",
                              "--out", str(tmp_path / "o")])  # fmt: skip
    assert bad.exit_code == 2
    assert "design" in bad.output
    assert not (tmp_path / "o").exists()  # nothing written for a bad input


def test_an_interrupted_study_says_so_in_one_line_and_writes_nothing(tmp_path, monkeypatch):
    import microcal.workflows.study as study

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(study, "run_study", interrupted)
    out = tmp_path / "st"
    result = CliRunner().invoke(app, ["study", "--preset", "population", "--seeds", "2",
                                      "--out", str(out)])  # fmt: skip
    assert result.exit_code == 130
    assert result.output.strip().splitlines() == ["microcal: error: interrupted"]
    assert not (out / "study.json").exists()


def test_a_study_seed_reports_the_prior_on_the_population_only():
    config = StudyConfig(poses=80, cycles=1, prior=True)
    run = run_seed("population", 2, config)
    ap = run.ap_truth_mean_um
    assert ap["oracle"] < ap["prior"] < ap["quadratic"]
    assert run.validation_mean_um["prior"] < run.validation_mean_um["quadratic"]
    with pytest.raises(InputError, match="only the population preset"):
        run_seed("thesis", 2, StudyConfig(poses=60, cycles=1, prior=True))
