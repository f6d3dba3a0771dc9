"""The logger's crash safety in process, on real files: what a flush writes survives a
kill at any later byte, and salvage reads every flushed record back. The flush uses the
mcap writer's private end-of-chunk call (the package has no public one): pyproject.toml
pins mcap to the 1.6 series, and the first test fails the moment the call changes."""

from __future__ import annotations

import random
import shutil
from importlib.metadata import version

import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from contracts.zenoh_link import ZenohOptions
from ground.logger import LoggerConfig, McapFile, salvage


def test_the_private_mcap_calls_the_flush_relies_on_are_there():
    major_minor = tuple(int(v) for v in version("mcap").split(".")[:2])
    assert major_minor == (1, 6), "the logger's flush was checked against mcap 1.6 only"
    for name in ("_Writer__finalize_chunk", "_Writer__flush"):
        assert callable(getattr(Writer, name, None)), name
    writer = Writer(open("/dev/null", "wb"))  # noqa: SIM115
    writer.start()
    assert isinstance(writer._Writer__chunk_indices, list)  # noqa: SLF001
    writer.finish()


def _file_with(tmp_path, flushed: int, open_after: int):
    """A logger file with ``flushed`` records flushed, then ``open_after`` more in the
    open chunk, as a kill would leave it (not finished)."""
    config = LoggerConfig(tmp_path / "out", ZenohOptions(enabled=False))
    config.out_dir.mkdir()
    f = McapFile(config.out_dir / "telemetry-000.mcap", config)
    channel = f.channel("mavlink/1/1/HEARTBEAT", "mavlink")
    for i in range(flushed):
        f.add(channel, i, i, i, b"\xfd" + bytes(20))
    f.flush()
    size_at_flush = f.size
    for i in range(open_after):
        f.add(channel, flushed + i, 0, 0, b"\xfd" + bytes(20))
    f.stream.flush()  # what the OS holds when the process dies
    return f, size_at_flush


def test_a_kill_after_a_flush_keeps_every_flushed_record(tmp_path):
    f, _ = _file_with(tmp_path, 500, 200)
    copy = tmp_path / "killed.mcap.active"
    shutil.copy(f.active_path, copy)
    done = salvage(copy, log=lambda text: None)
    with open(done, "rb") as fh:
        count = sum(1 for _ in make_reader(fh).iter_messages())
    assert count == 500  # the open chunk is not on disk yet: only the flushed records


@pytest.mark.parametrize("seed", range(5))
def test_a_file_torn_anywhere_after_the_flush_salvages_without_error(tmp_path, seed):
    f, at_flush = _file_with(tmp_path, 300, 0)
    for _ in range(3):  # three more flushed chunks after the first
        channel = f.channel("ivfm/vehicle/1/sitl/status", "json")
        for i in range(100):
            f.add(channel, i, i, i, b'{"seq": 0, "sim_time_us": 0}')
        f.flush()
    data = f.active_path.read_bytes()
    cut = random.Random(seed).randint(at_flush, len(data))
    torn = tmp_path / f"torn-{seed}.mcap.active"
    torn.write_bytes(data[:cut])
    said: list[str] = []
    done = salvage(torn, log=said.append)
    with open(done, "rb") as fh:
        count = sum(1 for _ in make_reader(fh).iter_messages())
    assert 300 <= count <= 600  # every record flushed before the cut's chunk
    assert said[-1].startswith("salvaged ")
