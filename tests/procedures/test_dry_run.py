"""The dry run of an acquisition: every device checked before anything moves."""

from __future__ import annotations

import pytest

from microcal import DeviceError, sim


def test_a_camera_with_the_wrong_frame_size_is_a_device_error():
    from microcal.procedures.dry_run import dry_run
    from microcal.procedures.planning import plan_run

    plat = sim.platform("thesis", seed=0)
    cam = plat.cameras["top"]
    grab = cam._grab
    cam._grab = lambda: grab()[:-2]  # type: ignore[method-assign]
    plan = plan_run("random", 20, 0, plat.manipulator.limits_um)
    with pytest.raises(DeviceError, match=r"camera top: frame is 1600 x 1198 px but the camera"):
        dry_run(plat.manipulator, plat.cameras, plat.scene.board, plan)


def test_a_tool_on_the_manipulator_is_looked_for_as_a_tip():
    from microcal.procedures.dry_run import dry_run
    from microcal.procedures.planning import plan_run

    plat = sim.platform("thesis-tip", seed=0, overrides={"board": "tip:needle:20:5"})
    plan = plan_run("random", 20, 0, plat.manipulator.limits_um)
    lines = dry_run(plat.manipulator, plat.cameras, plat.scene.board, plan)
    cameras = [line for line in lines if line.startswith("camera ")]
    assert len(cameras) == 2
    assert all(line.endswith("; tip found") for line in cameras), cameras


def test_a_dry_run_refuses_an_out_that_the_run_would_refuse(tmp_path):
    """The dry run checks --out as the run would: a directory that holds a run is one line
    before anything opens (it used to pass the dry run and be refused by the run)."""
    from microcal.errors import InputError
    from microcal.formats.run_directory import MANIFEST
    from microcal.workflows.acquire import check_out

    check_out(tmp_path / "new", resume=False, dry_run=True)  # a new directory: fine
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / MANIFEST).write_text("{}")
    for dry_run in (True, False):
        with pytest.raises(InputError, match=r"a: already holds a run; use --resume"):
            check_out(tmp_path / "a", resume=False, dry_run=dry_run)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "notes.txt").write_text("mine")
    with pytest.raises(InputError, match=r"holds other files \(notes.txt\)"):
        check_out(tmp_path / "b", resume=False, dry_run=True)
