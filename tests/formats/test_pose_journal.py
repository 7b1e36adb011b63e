"""The pose journal: one JSON line per pose, on disk at once."""

from __future__ import annotations

import json
from pathlib import Path

from microcal.formats.pose_journal import PoseJournal


def test_each_line_is_on_disk_when_append_returns(tmp_path: Path) -> None:
    path = tmp_path / "journal.jsonl"
    path.write_text("old\n", encoding="utf-8")
    journal = PoseJournal(path)
    assert path.read_text(encoding="utf-8") == ""
    journal.append({"pose": 1, "p_um": [0.0, 1.0, 2.0]})
    assert json.loads(path.read_text(encoding="utf-8")) == {"pose": 1, "p_um": [0.0, 1.0, 2.0]}
    journal.append({"pose": 2, "p_um": None})
    lines = path.read_text(encoding="utf-8").splitlines()
    assert [json.loads(x)["pose"] for x in lines] == [1, 2]
    assert journal.lines == 2
