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
from mcap.writer import CompressionType, Writer

from contracts.zenoh_link import ZenohOptions
from ground.telemetry.logger import LoggerConfig, SilenceWatch
from ground.telemetry.mcap_file import McapFile, salvage


def test_the_private_mcap_calls_the_flush_relies_on_are_there():
    major_minor = tuple(int(v) for v in version("mcap").split(".")[:2])
    assert major_minor == (1, 6), "the logger's flush was checked against mcap 1.6 only"
    for name in ("_Writer__finalize_chunk", "_Writer__flush"):
        assert callable(getattr(Writer, name, None)), name
    writer = Writer(open("/dev/null", "wb"))  # noqa: SIM115
    writer.start()
    assert isinstance(writer._Writer__chunk_indices, list)  # noqa: SLF001
    for name in ("_Writer__chunk_builder", "_Writer__statistics"):  # McapFile.add's
        assert getattr(writer, name, None) is not None, name
    writer.finish()


@pytest.mark.parametrize("compression", ["zstd", "none"])
def test_the_loggers_own_message_path_writes_the_bytes_of_the_writers_add_message(
        tmp_path, compression):
    """McapFile.add writes into the writer's chunk itself: the file must be the one the
    writer's public add_message makes of the same calls, byte for byte (chunks closing on
    size, log times out of order, sequences past 32 bits, channels first seen mid-chunk)."""
    rng = random.Random(7)
    ours = McapFile(tmp_path / "ours.mcap", 4096, compression)
    theirs_path = tmp_path / "theirs.mcap"
    with open(theirs_path, "wb") as stream:
        theirs = Writer(stream, chunk_size=4096, compression={
            "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}[compression])
        theirs.start(profile="", library="ivfm-sitl ground logger")
        channels = []
        for i in range(2000):
            if i % 400 == 0:  # a new channel, registered in the middle of a chunk
                key = f"mavlink/1/1/M{i}"
                channels.append((ours.channel(key, "mavlink"),
                                 theirs.register_channel(key, "mavlink", 0)))
            ours_id, theirs_id = rng.choice(channels)
            log_time = 10**18 + rng.randrange(-10**6, 10**9)  # wall time, not monotonic
            sim_time, seq = rng.randrange(10**12), rng.randrange(2**40)
            data = rng.randbytes(rng.randrange(0, 300))
            ours.add(ours_id, log_time, sim_time, seq, data)
            theirs.add_message(theirs_id, log_time, data, sim_time, seq & 0xFFFFFFFF)
        theirs.finish()
    ours.finish()
    assert (tmp_path / "ours.mcap").read_bytes() == theirs_path.read_bytes()


def _file_with(tmp_path, flushed: int, open_after: int):
    """A logger file with ``flushed`` records flushed, then ``open_after`` more in the
    open chunk, as a kill would leave it (not finished)."""
    config = LoggerConfig(tmp_path / "out", ZenohOptions(enabled=False))
    config.out_dir.mkdir()
    f = McapFile(config.out_dir / "telemetry-000.mcap", config.chunk_bytes,
                 config.compression)
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


def _limit_file_size() -> None:
    """In the logger's process: files may not grow past 64 KiB, and a write past it fails
    with EFBIG instead of killing the process (SIGXFSZ), as a full disk's ENOSPC does."""
    import resource
    import signal

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64 * 1024, 64 * 1024))


@pytest.mark.process
def test_a_logger_out_of_space_stops_writing_says_so_and_leaves_a_readable_file(tmp_path):
    import json
    import subprocess
    import sys
    import time

    from contracts.telemetry import TIMING, logger_key, vehicle_key
    from contracts.zenoh_link import open_session
    from ground.run.children import free_tcp_port

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    out = tmp_path / "log"
    log = open(tmp_path / "logger.txt", "w")  # noqa: SIM115
    logger = subprocess.Popen(
        [sys.executable, "-m", "ground.cli", "ground", "log", "--out", str(out),
         "--zenoh-listen", endpoint, "--compression", "none", "--chunk-kib", "4",
         "--flush-s", "0.05"], stdout=log, stderr=subprocess.STDOUT,
        preexec_fn=_limit_file_size)
    session = open_session(ZenohOptions(connect=[endpoint]))

    def status() -> dict:
        for reply in session.get(logger_key("logger", "status"), timeout=5.0):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return {}

    try:
        deadline = time.monotonic() + 60.0
        while not status() and time.monotonic() < deadline:
            time.sleep(0.1)
        pub = session.declare_publisher(vehicle_key(1, "autopilot", "timing"))
        record = TIMING.buffer()
        for seq in range(4000):  # about 160 KiB of records
            record["seq"], record["sim_time_us"] = seq, seq * 4000
            pub.put(record.encode())
            if seq % 200 == 0:
                time.sleep(0.02)
        time.sleep(1.0)
        stopped = status()
        alive = logger.poll() is None
    finally:
        session.close()
        logger.send_signal(2)  # SIGINT: the logger's own stop
        code = logger.wait(30)
        log.close()
    text = (tmp_path / "logger.txt").read_text()
    assert alive and code == 0, text
    assert "File too large" in stopped["write_error"]
    assert stopped["last_error"].startswith("logging stopped: File too large")
    assert 0 < stopped["records"] < 4000 and stopped["unwritten"] > 0
    assert stopped["records"] + stopped["unwritten"] == 4000  # every record accounted for
    assert sum(stopped["per_key"].values()) == stopped["records"]  # per key as well
    assert "logging stopped after" in text and "Traceback" not in text
    (active,) = out.glob("*.mcap.active")
    assert active.stat().st_size <= 64 * 1024
    done = salvage(active, log=lambda _text: None)
    with open(done, "rb") as fh:
        seqs = [m.sequence for _s, _c, m in make_reader(fh).iter_messages()]
    assert seqs == list(range(stopped["records"]))  # every record it counted, in order


def test_the_logger_says_once_when_records_stop_and_once_when_they_come_again():
    said: list[str] = []
    watch = SilenceWatch(said.append, silence_s=2.0)  # the default is 1 s
    watch.update(0.0, 0)
    watch.update(10.0, 0)
    assert said == []  # nothing heard yet: a logger waiting for its vehicles is quiet
    watch.update(10.5, 3)
    watch.update(12.4, 0)
    assert said == []
    watch.update(12.5, 0)
    watch.update(20.0, 0)
    assert len(said) == 1 and said[0].startswith("no records for 2 s")
    watch.update(21.0, 1)
    watch.update(21.1, 1)
    assert said[1:] == ["records again after 10.5 s of silence"]


def _three_channel_log(tmp_path, finished: bool = True):
    """A log of three channels over many chunks, interleaved as a flight's are."""
    f = McapFile(tmp_path / "telemetry-000.mcap", 2048, "zstd")
    channels = [f.channel("mavlink/1/1/HEARTBEAT", "mavlink"),
                f.channel("ivfm/vehicle/1/sitl/status", "json"),
                f.channel("ivfm/vehicle/1/autopilot/timing", None)]
    rng = random.Random(7)
    for i in range(900):
        channel = channels[rng.randrange(3)]
        f.add(channel, 1000 + i, 10 * i, i, rng.randbytes(rng.randrange(1, 120)))
    if finished:
        return f.finish()
    f.flush()
    f.stream.flush()
    return f.active_path


def _fields(messages) -> list[tuple]:
    return [(topic, m.channel_id, m.log_time, m.publish_time, m.sequence, bytes(data))
            for topic, m, data in messages]


@pytest.mark.parametrize("prefixes", [("mavlink/",), ("ivfm/vehicle/1/sitl/", "mavlink/"),
                                      ("ivfm/",), ("nothing/",)])
def test_a_reports_records_read_through_the_index_are_the_whole_reads(tmp_path, prefixes):
    """LogRecords reads a finished log's messages on its topics through the message
    indexes (only those records parsed): the same messages, in the same order, with the
    same fields as the MCAP library's own pass over every record."""
    from ground.record.run_files import LogRecords, _indexed_messages, iter_messages

    path = _three_channel_log(tmp_path)
    whole = [m for m in iter_messages(path) if m[0].startswith(prefixes)]
    assert _indexed_messages(path, prefixes) is not None  # the index was used
    assert _fields(LogRecords(path, prefixes).messages) == _fields(whole)
    assert len(whole) > 0 or prefixes == ("nothing/",)


def test_a_log_whose_index_cannot_be_used_is_read_whole(tmp_path):
    """Unfinished (no summary) or with a message index that does not match its chunk:
    read whole, to the same messages."""
    from ground.record.run_files import LogRecords, _indexed_messages, iter_messages

    prefixes = ("mavlink/",)
    finished = _three_channel_log(tmp_path)
    whole = _fields(m for m in iter_messages(finished) if m[0].startswith(prefixes))
    (tmp_path / "killed").mkdir()
    unfinished = _three_channel_log(tmp_path / "killed", finished=False)
    assert _indexed_messages(unfinished, prefixes) is None
    salvaged = salvage(unfinished, log=lambda _text: None)
    assert _fields(LogRecords(salvaged, prefixes).messages) == whole
    with open(finished, "rb") as fh:
        summary = make_reader(fh).get_summary()
    heartbeat = next(cid for cid, channel in summary.channels.items()
                     if channel.topic.startswith("mavlink/"))
    index_at = summary.chunk_indexes[0].message_index_offsets[heartbeat]
    data = bytearray(finished.read_bytes())
    data[index_at + 9] ^= 0xFF  # the index's channel id
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(bytes(data))
    assert _indexed_messages(broken, prefixes) is None
    assert _fields(LogRecords(broken, prefixes).messages) == whole


def test_a_chunk_that_does_not_decompress_is_refused_as_damaged(tmp_path):
    """Found by the log fuzz target: a zeroed byte in a chunk's compressed data failed in
    the decompressor, inside the indexed read, with the decompressor's own error. Now the
    log is read whole and refused as damaged, as before the index was used."""
    from ground.record.run_files import LogRecords

    finished = _three_channel_log(tmp_path)
    with open(finished, "rb") as fh:
        summary = make_reader(fh).get_summary()
    chunk = summary.chunk_indexes[0]
    data = bytearray(finished.read_bytes())
    frame = chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len("zstd") + 8
    assert data[frame:frame + 4] == b"\x28\xb5\x2f\xfd"  # zstd's magic: the frame
    data[frame + 5] = 0  # its content size, 0: it does not decompress in full
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    with pytest.raises(ValueError, match="damaged"):
        LogRecords(damaged, ("mavlink/",))
