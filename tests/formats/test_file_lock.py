"""One writer at a time of a shared file: writers take turns, a long holder is named in one
line, the lock file is never followed through a link and does not outlive its holder."""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

import pytest

from microcal.errors import InputError
from microcal.formats.atomic import write_text_atomic
from microcal.formats.file_lock import lock_path, locked_update
from support.locks import held_elsewhere

fork = multiprocessing.get_context("fork")


def test_the_lock_file_lies_beside_the_file_a_path_leads_to(tmp_path: Path):
    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    expected = tmp_path / "real" / ".calibration.json.lock"
    assert lock_path(tmp_path / "real" / "calibration.json") == expected
    assert lock_path(tmp_path / "link" / "." / "calibration.json") == expected
    (tmp_path / "real" / "calibration.json").write_text("{}")
    (tmp_path / "alias.json").symlink_to(tmp_path / "real" / "calibration.json")
    assert lock_path(tmp_path / "alias.json") == expected


def test_writers_take_turns_and_every_increment_lands(tmp_path: Path):
    counter, rounds = tmp_path / "counter.txt", 50

    def increments() -> None:
        for _ in range(rounds):
            with locked_update(counter):
                n = int(counter.read_text()) if counter.exists() else 0
                write_text_atomic(counter, f"{n + 1}\n")

    procs = [fork.Process(target=increments) for _ in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert [p.exitcode for p in procs] == [0, 0]
    assert int(counter.read_text()) == 2 * rounds
    assert sorted(os.listdir(tmp_path)) == ["counter.txt"]  # the lock file went with its holder


def test_a_holder_beyond_the_wait_is_named_in_one_line_and_nothing_is_written(tmp_path: Path):
    target = tmp_path / "results.json"
    target.write_text("old\n")
    with held_elsewhere(target) as pid:
        t0 = time.monotonic()
        with pytest.raises(InputError) as refused, locked_update(target, wait_s=0.3):
            target.write_text("new\n")  # pragma: no cover - never reached
        waited = time.monotonic() - t0
    message = str(refused.value)
    assert message == (f"{target}: in use by microcal (PID {pid}) for more than 0.3 s; "
                       f"wait for it to end or stop it, then run again")  # fmt: skip
    assert "\n" not in message
    assert 0.3 <= waited < 3.0
    assert target.read_text() == "old\n"
    with locked_update(target, wait_s=0.3):  # the holder is gone: the lock is free again
        pass
    assert sorted(os.listdir(tmp_path)) == ["results.json"]


def test_a_writer_waits_for_a_short_holder(tmp_path: Path):
    target = tmp_path / "calibration.json"
    taken, wrote = fork.Event(), fork.Event()

    def hold_briefly() -> None:
        with locked_update(target):
            taken.set()
            time.sleep(0.3)
            write_text_atomic(target, "first\n")
            wrote.set()

    proc = fork.Process(target=hold_briefly)
    proc.start()
    assert taken.wait(10)
    with locked_update(target, wait_s=5.0):
        assert wrote.is_set()  # the lock came only after the holder had written
        assert target.read_text() == "first\n"
    proc.join(10)


def test_a_lock_file_left_by_a_killed_process_does_not_block(tmp_path: Path):
    target = tmp_path / "calibration.json"
    lock = lock_path(target)
    lock.write_text("999999\n")  # its holder died without removing it
    with locked_update(target, wait_s=0.0):
        assert lock.read_text() == f"{os.getpid()}\n"
    assert not lock.exists()


def test_a_lock_file_that_is_a_link_is_refused_and_not_followed(tmp_path: Path):
    target = tmp_path / "calibration.json"
    elsewhere = tmp_path / "elsewhere.txt"
    elsewhere.write_text("keep\n")
    lock_path(target).symlink_to(elsewhere)
    link = r"\.calibration\.json\.lock: is a symbolic link"
    with pytest.raises(InputError, match=link), locked_update(target):
        pass  # pragma: no cover - never reached
    assert elsewhere.read_text() == "keep\n"
    assert lock_path(target).is_symlink()
    lock_path(target).unlink()
    lock_path(target).mkdir()
    not_a_file = r"\.calibration\.json\.lock: is not a file"
    with pytest.raises(InputError, match=not_a_file), locked_update(target):
        pass  # pragma: no cover - never reached


def test_the_folder_of_a_new_file_is_made(tmp_path: Path):
    target = tmp_path / "new" / "results.json"
    with locked_update(target) as path:
        write_text_atomic(path, "{}\n")
    assert sorted(os.listdir(target.parent)) == ["results.json"]
