"""Files written whole or not at all (contracts/atomic_file.py), on real files."""

from __future__ import annotations

import os
import stat
import threading

import pytest

from contracts.atomic_file import atomic_writer, write_atomic


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_text_and_bytes_land_whole_readable_by_all_or_private(tmp_path):
    write_atomic(tmp_path / "a.json", '{"x": 1}\n')
    write_atomic(tmp_path / "b.bin", b"\x00\x01")
    write_atomic(tmp_path / "key.pem", b"secret", private=True)
    assert (tmp_path / "a.json").read_text() == '{"x": 1}\n'
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    assert _mode(tmp_path / "a.json") == 0o644 and _mode(tmp_path / "key.pem") == 0o600
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.bin", "key.pem"]


def test_an_error_while_writing_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "rows.csv"
    write_atomic(path, "old\n")
    with pytest.raises(RuntimeError), atomic_writer(path, text=True) as f:
        f.write("new, half")
        raise RuntimeError("the disk filled")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["rows.csv"]


def test_text_is_written_without_newline_translation(tmp_path):
    write_atomic(tmp_path / "t.csv", "a\r\nb\n")
    assert (tmp_path / "t.csv").read_bytes() == b"a\r\nb\n"


def test_writers_of_one_path_at_once_each_leave_a_whole_file(tmp_path):
    """A campaign's client and its workers may write one row file at the same moment."""
    path = tmp_path / "row.json"
    texts = [f"{i:03d}" * 20_000 for i in range(8)]
    threads = [threading.Thread(target=write_atomic, args=(path, t)) for t in texts]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert path.read_text() in texts
    assert [p.name for p in tmp_path.iterdir()] == ["row.json"]
