"""Two writers of one file at once: both updates land, or one is refused in one line.

``fit`` adds a device to calibration.json, ``check`` appends to the calibration's history and
``evaluate`` (and the demo) merge parts into results.json: each reads the file, changes it
and writes it whole. Two processes doing so at once take turns (the file lock); none may
exit having lost the other's update.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from microcal.errors import InputError
from microcal.formats import file_lock
from microcal.formats.calibration_file import load_calibration
from microcal.formats.check_file import append_history
from microcal.formats.hashing import sha256_file
from microcal.formats.measurements import write_measurements
from microcal.formats.results_file import load_results, update_results
from microcal.sim.synthetic_run import synthetic_run
from microcal.workflows.check import check_calibration
from microcal.workflows.fit import FitRequest, fit
from support.cli import invoke_microcal
from support.locks import held_elsewhere

#: The one line a writer that waited too long for the other gets.
IN_USE = re.compile(r"^\S+: in use by microcal \((PID \d+|another process)\); ")


def run_together(jobs: list[Callable[[], Any]]) -> list[str]:
    """Run each job in its own (forked) process, all released at once; what each ended with:
    ``ok``, or the message of the user error it raised."""
    ctx = multiprocessing.get_context("fork")
    barrier = ctx.Barrier(len(jobs))
    queue = ctx.SimpleQueue()

    def child(k: int, job: Callable[[], Any]) -> None:
        barrier.wait()
        try:
            job()
            queue.put((k, "ok"))
        except InputError as exc:
            queue.put((k, str(exc)))
        except BaseException as exc:  # not a user error: the test fails on it
            queue.put((k, f"raised {type(exc).__name__}: {exc}"))

    procs = [ctx.Process(target=child, args=(k, job)) for k, job in enumerate(jobs)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    outcomes = dict(queue.get() for _ in procs)
    return [outcomes[k] for k in range(len(jobs))]


def _refusals(outcomes: list[str]) -> list[str]:
    refused = [o for o in outcomes if o != "ok"]
    for o in refused:
        assert IN_USE.match(o), o
    return refused


@pytest.fixture(scope="module")
def measurements(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run = synthetic_run(30, seed=3)
    path = tmp_path_factory.mktemp("run") / "measurements.csv"
    write_measurements(path, run.d_um, run.measured_um)
    return path


def test_two_fits_into_one_calibration_keep_both_devices(measurements: Path, tmp_path: Path):
    trials, lost = 20, []
    names = ("m1", "m2")
    for trial in range(trials):
        out = tmp_path / f"calibration-{trial}.json"
        requests = [FitRequest(measurements, out=out, manipulator=n, model="matrix")
                    for n in names]  # fmt: skip
        jobs = [lambda r=r: fit(r) for r in requests]
        outcomes = run_together(jobs)
        _refusals(outcomes)
        done = {n for n, o in zip(names, outcomes, strict=True) if o == "ok"}
        if set(load_calibration(out).manipulators) != done:
            lost.append(trial)
    assert not lost, f"{len(lost)} of {trials} trials lost a device: {lost}"
    assert not list(tmp_path.glob(".*.lock"))  # each lock file went with its holder


def test_two_checks_appending_to_one_history_lose_no_line(tmp_path: Path):
    history, rounds = tmp_path / "calibration.checks.jsonl", 60

    def appends(writer: int) -> None:
        for n in range(rounds):
            append_history(history, {"writer": writer, "n": n})

    outcomes = run_together([lambda: appends(0), lambda: appends(1)])
    assert outcomes == ["ok", "ok"]
    lines = [json.loads(line) for line in history.read_text(encoding="utf-8").splitlines()]
    lost = 2 * rounds - len(lines)
    assert lost == 0, f"{lost} of {2 * rounds} lines lost"
    for writer in (0, 1):  # each writer's lines in its order
        assert [e["n"] for e in lines if e["writer"] == writer] == list(range(rounds))


def test_two_evaluations_merging_into_one_results_keep_both_parts(tmp_path: Path):
    results, rounds = tmp_path / "results.json", 40

    def merges(writer: str) -> None:
        for n in range(rounds):
            update_results(results, {"timing": {writer: {f"round_{n}": float(n)}}})

    outcomes = run_together([lambda: merges("open"), lambda: merges("closed")])
    assert outcomes == ["ok", "ok"]
    timing = load_results(results)["timing"]
    lost = {w: rounds - len(timing.get(w, {})) for w in ("open", "closed")}
    assert lost == {"open": 0, "closed": 0}, f"rounds lost: {lost}"


# --- a lock held too long -------------------------------------------------------------------
def test_a_fit_into_a_calibration_held_too_long_is_refused_in_one_line(
    measurements: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    out = tmp_path / "calibration.json"
    fit(FitRequest(measurements, out=out, manipulator="m1"))
    before = sha256_file(out)
    monkeypatch.setattr(file_lock, "WAIT_S", 0.3)
    with held_elsewhere(out) as pid:
        ran = invoke_microcal("fit", measurements, "--out", out, "--manipulator", "m2")
    assert ran.returncode == 2, ran.stdout
    assert ran.stderr.strip() == (f"microcal: error: {out}: in use by microcal (PID {pid}) for "
                                  "more than 0.3 s; wait for it to end or stop it, then run again")  # fmt: skip
    assert sha256_file(out) == before
    assert sorted(os.listdir(tmp_path)) == ["calibration.json"]


# --- one file named twice ------------------------------------------------------------------
@pytest.fixture
def calibration(measurements: Path, tmp_path: Path) -> Path:
    out = tmp_path / "calibration.json"
    fit(FitRequest(measurements, out=out))
    return out


@pytest.mark.parametrize(
    ("out", "update", "message"),
    [
        ("new.json", "new.json", "--update new.json: is --out too; give the updated calibration its own name"),
        ("new.json", "./new.json", "--update ./new.json: is --out too; give the updated calibration its own name"),
        # an output that is a symbolic link is refused as such (microcal never writes through one)
        ("new.json", "alias.json", "--update alias.json: is a symbolic link, not a regular file; microcal writes only a regular file or a new path: give a file name such as calibration-updated.json"),
        ("check.json", "calibration.checks.jsonl",
         "--update calibration.checks.jsonl: is the calibration's history; give the updated calibration its own name"),
        ("calibration.checks.jsonl", None,
         "--out calibration.checks.jsonl: is the calibration's history; give check.json its own name"),
    ],
)  # fmt: skip
def test_a_check_writing_one_file_twice_is_refused_before_it_runs(
    calibration: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, out, update, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "alias.json").symlink_to(tmp_path / "new.json")  # a link not yet live
    before = {p.name: sha256_file(p) for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(InputError, match=f"^{re.escape(message)}$"):
        check_calibration("sim", "calibration.json", out, update=update, seed=0)
    assert {p.name: sha256_file(p) for p in tmp_path.iterdir() if p.is_file()} == before
    assert sorted(os.listdir(tmp_path)) == ["alias.json", "calibration.json"]


def test_the_command_line_refuses_a_check_writing_one_file_twice(calibration: Path, tmp_path: Path):
    ran = invoke_microcal("check", "--calibration", calibration, "--out", tmp_path / "new.json",
                          "--update", tmp_path / "." / "new.json", cwd=tmp_path)  # fmt: skip
    assert ran.returncode == 2, ran.stdout
    assert ran.stderr.strip() == (f"microcal: error: --update {tmp_path / 'new.json'}: is --out too; "
                                  "give the updated calibration its own name")  # fmt: skip
    assert sorted(os.listdir(tmp_path)) == ["calibration.json"]
