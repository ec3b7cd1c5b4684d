"""tlog writing and reading: round trip, logs written by pymavlink in another process, errors."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from companion.mavlink import messages as M
from companion.mavlink.tlog import TlogError, TlogWriter, read_tlog

T0 = 1_700_000_000.0


def packets(n):
    mav = mavlink2.MAVLink(None, 1, 1)
    out = []
    for i in range(n):
        msg = mavlink2.MAVLink_local_position_ned_message(100 * i, float(i), 0.0, -5.0, 1.0, 0.0, 0.0)
        out.append(bytes(msg.pack(mav)))
        mav.seq = (mav.seq + 1) % 256
    return out


def test_that_records_round_trip_through_pymavlinks_own_reader(tmp_path):
    path = tmp_path / "a.tlog"
    pkts = packets(5)
    with TlogWriter(path) as log:
        for i, p in enumerate(pkts):
            log.write(T0 + 0.1 * i, p)
    conn = mavutil.mavlink_connection(str(path))
    seen = []
    while (m := conn.recv_msg()) is not None:
        seen.append((m._timestamp, bytes(m.get_msgbuf())))
    assert [p for _, p in seen] == pkts
    assert [t for t, _ in seen] == pytest.approx([T0 + 0.1 * i for i in range(5)], abs=1e-6)
    ours = list(read_tlog(path))
    assert [t for t, _ in ours] == [t for t, _ in seen]
    assert [m.x for _, m in ours] == [0.0, 1.0, 2.0, 3.0, 4.0]


def test_that_record_layout_is_big_endian_microseconds_then_packet(tmp_path):
    path = tmp_path / "b.tlog"
    (pkt,) = packets(1)
    with TlogWriter(path) as log:
        log.write(1.5, pkt)
    assert path.read_bytes() == (1_500_000).to_bytes(8, "big") + pkt


def test_that_records_are_flushed_within_the_flush_period_of_log_time(tmp_path):
    path = tmp_path / "c.tlog"
    (pkt,) = packets(1)
    log = TlogWriter(path, flush_period_s=0.2)
    log.write(T0, pkt)
    log.write(T0 + 0.1, pkt)
    log.write(T0 + 0.25, pkt)  # 0.25 s after the last flush: flushed now, before close
    assert path.stat().st_size == 3 * (8 + len(pkt))
    log.close()
    with pytest.raises(TlogError, match="closed"):
        log.write(T0 + 1, pkt)


def test_that_a_killed_writer_loses_at_most_the_last_flush_period(tmp_path):
    path = tmp_path / "killed.tlog"
    script = textwrap.dedent(f"""
        import os
        from pymavlink.dialects.v20 import common as m
        from companion.mavlink.tlog import TlogWriter
        mav = m.MAVLink(None, 1, 1)
        pkt = bytes(m.MAVLink_heartbeat_message(2, 12, 1, 0, 3, 3).pack(mav))
        log = TlogWriter({str(path)!r}, flush_period_s=0.2)
        for i in range(100):
            log.write({T0} + 0.05 * i, pkt)
        os._exit(9)  # no close, no interpreter cleanup
    """)
    proc = subprocess.run([sys.executable, "-c", script], timeout=60)
    assert proc.returncode == 9
    times = [t for t, _ in read_tlog(path)]
    assert times[-1] >= T0 + 0.05 * 99 - 0.2 - 1e-6


def test_that_a_tlog_written_by_pymavlink_in_another_process_with_signing_and_a_cut_tail_is_read(tmp_path):
    path = tmp_path / "mavproxy.tlog"
    script = textwrap.dedent(f"""
        import os, struct
        os.environ["MAVLINK20"] = "1"
        from pymavlink import mavutil
        from pymavlink.dialects.v20 import common as m
        log = mavutil.mavlogfile({str(path)!r}, write=True)  # pymavlink's tlog writer
        mav = m.MAVLink(None, 1, 1)
        def record(t, buf, link=0):
            usec = (int(t * 1e6) & ~3) | link  # MAVProxy: low 2 bits hold the link number
            log.write(struct.pack(">Q", usec) + bytes(buf))
        record({T0}, m.MAVLink_heartbeat_message(2, 12, 145, 393216, 4, 3).pack(mav))
        mav.seq += 1
        mav.signing.secret_key = bytes(range(32))
        mav.signing.sign_outgoing = True
        mav.signing.link_id = 1
        mav.signing.timestamp = 300_000_000_000
        signed = m.MAVLink_local_position_ned_message(2000, 1.0, 2.0, -3.0, 0, 0, 0).pack(mav)
        assert signed[2] & 1
        record({T0} + 0.5, signed, link=1)
        mav.seq += 1
        mav.signing.sign_outgoing = False
        last = m.MAVLink_statustext_message(6, b"cut here", 0, 0).pack(mav)
        record({T0} + 1.0, last[: len(last) // 2])  # killed mid-record
        log.close()
    """)
    subprocess.run([sys.executable, "-c", script], check=True, timeout=60)
    got = list(read_tlog(path))
    assert [m.get_type() for _, m in got] == ["HEARTBEAT", "LOCAL_POSITION_NED"]
    assert got[0][0] == pytest.approx(T0, abs=1e-5)
    assert got[1][0] == pytest.approx(T0 + 0.5, abs=1e-5)
    assert (got[1][1].x, got[1][1].z) == (1.0, -3.0)
    buf = bytes(got[1][1].get_msgbuf())
    assert buf[2] & 0x01 and len(buf) == 10 + buf[1] + 2 + 13  # signed: 13-byte trailer kept
    obs = M.decode(got[1][1])
    assert obs.t_s == pytest.approx(2.0)


def test_that_a_missing_file_is_a_tlog_error_naming_it(tmp_path):
    with pytest.raises(TlogError, match="nope.tlog does not exist"):
        list(read_tlog(tmp_path / "nope.tlog"))


def test_that_an_empty_file_is_a_tlog_error(tmp_path):
    (tmp_path / "empty.tlog").write_bytes(b"")
    with pytest.raises(TlogError, match="empty.tlog is empty"):
        list(read_tlog(tmp_path / "empty.tlog"))


def test_that_a_non_tlog_file_is_a_tlog_error(tmp_path):
    path = tmp_path / "notes.tlog"
    path.write_text("this is a text file, not telemetry\n" * 4)
    with pytest.raises(TlogError, match="not a tlog"):
        list(read_tlog(path))


def test_that_a_log_without_valid_messages_is_a_tlog_error(tmp_path):
    path = tmp_path / "junk.tlog"
    path.write_bytes(int(T0 * 1e6).to_bytes(8, "big") + b"\xfe\x05" + b"\x00" * 3)
    with pytest.raises(TlogError, match="no valid MAVLink message"):
        list(read_tlog(path))


def test_that_invalid_times_are_refused(tmp_path):
    with TlogWriter(tmp_path / "d.tlog") as log:
        with pytest.raises(TlogError, match="finite"):
            log.write(float("nan"), b"\xfe")
    with pytest.raises(TlogError):
        TlogWriter(tmp_path / "e.tlog", flush_period_s=-1)


def test_that_reading_a_large_corrupted_tlog_allocates_little_and_names_the_offset(tmp_path):
    import tracemalloc

    enc = mavlink2.MAVLink(None, 1, 1)
    hb = bytes(mavlink2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3).pack(enc))
    path = tmp_path / "big.tlog"
    stamp = 1_704_067_200_000_000
    with open(path, "wb") as f:
        for i in range(100):
            f.write((stamp + i * 1000).to_bytes(8, "big") + hb)
        f.write(np.random.default_rng(5).integers(0, 256, 5_000_000, dtype=np.uint8).tobytes())
    tracemalloc.start()
    try:
        with pytest.raises(TlogError, match=rf"big\.tlog: .* byte offset {100 * (8 + len(hb))}"):
            list(read_tlog(path))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000


def test_that_a_bounded_tlog_keeps_the_first_and_latest_segments_within_its_bound(tmp_path):
    from companion.mavlink.tlog import TLOG_SEGMENTS, segment_path
    path = tmp_path / "flight.tlog"
    (tmp_path / "flight.0042.tlog").write_bytes(b"an earlier flight's segment")
    pkts = packets(256)
    record = 8 + len(pkts[0])
    bound = TLOG_SEGMENTS * 280 * 16                              # the smallest bound allowed
    n = 40 * bound // record                                      # five times the bound's worth
    with TlogWriter(path, max_bytes=bound) as log:
        for i in range(n):
            log.write(T0 + 0.01 * i, pkts[i % 256])
    files = sorted(tmp_path.iterdir())
    assert sum(f.stat().st_size for f in files) <= bound
    assert log.bytes_written == n * record and log.segments_deleted == log.segment - (TLOG_SEGMENTS - 1) > 0
    assert files == sorted([path] + [segment_path(path, k) for k in range(log.segment - TLOG_SEGMENTS + 2, log.segment + 1)])
    first = list(read_tlog(path))                                 # the start, whole records, readable alone
    assert first[0][0] == pytest.approx(T0) and len(first) == (bound // TLOG_SEGMENTS) // record
    joined = tmp_path / "joined.tlog"                             # the latest segments join with cat
    joined.write_bytes(b"".join(segment_path(path, k).read_bytes() for k in range(log.segment - 5, log.segment + 1)))
    times = [t for t, _ in read_tlog(joined)]
    assert times == sorted(times) and times[-1] == pytest.approx(T0 + 0.01 * (n - 1))
    assert np.allclose(np.diff(times), 0.01, atol=1e-5)           # nothing lost between the latest segments


def test_that_an_unbounded_tlog_is_one_file_and_a_tiny_bound_is_refused(tmp_path):
    with TlogWriter(tmp_path / "a.tlog") as log:
        for i, p in enumerate(packets(300)):
            log.write(T0 + i, p)
    assert [f.name for f in tmp_path.iterdir()] == ["a.tlog"] and log.segment == 0
    with pytest.raises(TlogError, match="max_bytes 1000 is too small"):
        TlogWriter(tmp_path / "b.tlog", max_bytes=1000)


def test_that_a_tlogs_segments_are_found_by_their_names_alone(tmp_path):
    """``segment_files``: ``STEM.NNNN.SUFFIX`` beside the tlog, in writing order; not the tlog,
    not another flight's log that shares the stem's start, not a directory."""
    from companion.mavlink.tlog import segment_files, segment_path

    path = tmp_path / "flight.tlog"
    for p in (path, segment_path(path, 12), segment_path(path, 3), tmp_path / "flight2.tlog",
              tmp_path / "flight.0007.tlog.bak", tmp_path / "flight.12.tlog"):
        p.write_bytes(b"")
    segment_path(path, 5).mkdir()
    assert segment_files(path) == [segment_path(path, 3), segment_path(path, 12)]
    assert segment_files(tmp_path / "nowhere" / "flight.tlog") == []
