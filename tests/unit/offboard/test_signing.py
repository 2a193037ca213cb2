"""MAVLink 2 signing (offboard/signing.py): the key file, the verdicts, the replay window."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from offboard.signing import (
    NEW_STREAM_WINDOW,
    SignatureCheck,
    SigningKey,
    SigningKeyError,
    SigningSession,
    Verdict,
    load_key,
    save_key,
    signing_timestamp,
)

KEY = bytes(range(1, 33))
OTHER = bytes(range(101, 133))
T0_US = 1_796_000_000_000_000  # a Unix time in 2026, microseconds


def frame(secret: bytes | None, timestamp: int, *, link_id: int = 0, sysid: int = 245, msg=None) -> bytes:
    """A real pymavlink frame, signed with ``secret`` at ``timestamp`` (unsigned if None)."""
    mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=191)
    if secret is not None:
        mav.signing.secret_key, mav.signing.timestamp = secret, timestamp
        mav.signing.link_id, mav.signing.sign_outgoing = link_id, True
    msg = msg or mavlink.MAVLink_heartbeat_message(18, 8, 0, 0, 0, 3)
    return msg.pack(mav)


def check_of(timestamp: int = signing_timestamp(T0_US)) -> SignatureCheck:
    return SignatureCheck(KEY, timestamp=timestamp)


def test_key_files_of_32_bytes_or_px4s_40_bytes(tmp_path):
    (tmp_path / "k32").write_bytes(KEY)
    (tmp_path / "k40").write_bytes(KEY + (123456).to_bytes(8, "little"))
    assert load_key(tmp_path / "k32") == SigningKey(KEY, 0)
    assert load_key(tmp_path / "k40") == SigningKey(KEY, 123456)
    save_key(tmp_path / "saved", SigningKey(KEY, 987))
    assert (tmp_path / "saved").read_bytes() == KEY + (987).to_bytes(8, "little")
    assert (tmp_path / "saved").stat().st_mode & 0o077 == 0  # the owner's only


@pytest.mark.parametrize("content, says", [(b"x" * 31, "31 bytes"), (b"", "0 bytes"), (bytes(32), "all-zero key")])
def test_a_bad_key_file_is_one_line_naming_it(tmp_path, content, says):
    path = tmp_path / "key.bin"
    path.write_bytes(content)
    with pytest.raises(SigningKeyError) as err:
        load_key(path)
    assert str(err.value).startswith(f"--signing-key {path}: ") and says in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(SigningKeyError, match="cannot read the key"):
        load_key(tmp_path / "missing.bin")


def test_signed_frames_of_our_key_are_accepted_and_others_refused():
    t = signing_timestamp(T0_US)
    c = check_of(t)
    assert c.check(frame(KEY, t + 1), 0, 245, 191) is Verdict.SIGNED
    assert c.check(frame(None, 0), 0, 245, 191) is Verdict.UNSIGNED
    assert c.check(frame(OTHER, t + 2), 0, 245, 191) is Verdict.BAD_SIGNATURE
    radio = mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0)
    assert c.check(frame(None, 0, msg=radio), 109, 245, 191) is Verdict.UNSIGNED_ALLOWED
    corrupted = bytearray(frame(KEY, t + 3))
    corrupted[12] ^= 0x40  # one payload bit
    assert c.check(bytes(corrupted), 0, 245, 191) is Verdict.BAD_SIGNATURE
    assert c.counts == {"signed": 1, "unsigned_allowed": 1, "unsigned": 1, "bad_signature": 2, "replayed": 0, "stale_stream": 0}
    assert c.refused == 3


def test_timestamps_must_increase_per_stream():
    t = signing_timestamp(T0_US)
    c = check_of(t)
    first = frame(KEY, t + 10)
    assert c.check(first, 0, 245, 191) is Verdict.SIGNED
    assert c.check(first, 0, 245, 191) is Verdict.REPLAYED  # the same frame again
    assert c.check(frame(KEY, t + 5), 0, 245, 191) is Verdict.REPLAYED  # older
    assert c.check(frame(KEY, t + 11), 0, 245, 191) is Verdict.SIGNED
    # another link id is another stream, with its own timestamps
    assert c.check(frame(KEY, t + 6, link_id=1), 0, 245, 191) is Verdict.SIGNED


def test_a_new_stream_may_start_at_most_a_minute_behind_us():
    t = signing_timestamp(T0_US)
    c = check_of(t)
    assert c.check(frame(KEY, t - NEW_STREAM_WINDOW - 1), 0, 245, 191) is Verdict.STALE_STREAM
    assert c.check(frame(KEY, t - NEW_STREAM_WINDOW + 100, sysid=246), 0, 246, 191) is Verdict.SIGNED


def test_a_forged_frame_with_a_high_timestamp_does_not_lock_the_real_stream_out():
    """pymavlink's check_signature stores the stream's timestamp before checking the hash: a
    forged frame stamped far ahead would make every real frame after it 'old'. Not here."""
    t = signing_timestamp(T0_US)
    c = check_of(t)
    assert c.check(frame(KEY, t + 1), 0, 245, 191) is Verdict.SIGNED
    assert c.check(frame(OTHER, t + 10**9), 0, 245, 191) is Verdict.BAD_SIGNATURE
    assert c.check(frame(KEY, t + 2), 0, 245, 191) is Verdict.SIGNED
    # and pymavlink's own check, for the record, is locked out by the same forgery
    mav = mavlink.MAVLink(None)
    mav.signing.secret_key, mav.signing.timestamp = KEY, t
    mav.parse_buffer(frame(KEY, t + 1))
    with pytest.raises(mavlink.MAVError):
        mav.parse_buffer(frame(OTHER, t + 10**9))
    with pytest.raises(mavlink.MAVError):
        mav.parse_buffer(frame(KEY, t + 3))


def test_a_session_signs_on_its_clock_increasing_and_persists_the_timestamp(tmp_path):
    path = tmp_path / "key.bin"
    save_key(path, SigningKey(KEY, signing_timestamp(T0_US) + 10**8))  # persisted ahead of the clock
    now = [T0_US]
    session = SigningSession(load_key(path), lambda: now[0], key_path=path)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    stamps = []
    for _ in range(3):
        session.stamp(mav)
        f = mavlink.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3).pack(mav)
        stamps.append(int.from_bytes(f[-12:-6], "little"))
    # a restart never signs below what was persisted, and each frame is above the last
    assert stamps[0] > signing_timestamp(T0_US) + 10**8 and stamps[0] < stamps[1] < stamps[2]
    verifier = SignatureCheck(KEY, timestamp=stamps[0])
    assert verifier.check(f, 0, 1, 1) is Verdict.SIGNED
    session.close()
    assert load_key(path).timestamp >= stamps[2]


def test_a_lockstep_session_signs_the_same_bytes_every_time():
    def run() -> list[bytes]:
        clock = iter(range(T0_US, T0_US + 10**6, 50_000))
        session = SigningSession(SigningKey(KEY), lambda: next(clock))  # no key file: nothing persisted
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        out = []
        for i in range(5):
            session.stamp(mav)
            out.append(mavlink.MAVLink_attitude_message(i, 0.1, 0.2, 0.3, 0, 0, 0).pack(mav))
        return out

    assert run() == run()


def test_the_persisted_timestamp_is_a_floor_for_new_streams_unless_in_lockstep(tmp_path):
    """Within the spec's minute, but recorded before the restart: refused with a key file."""
    path = tmp_path / "key.bin"
    persisted = signing_timestamp(T0_US)
    save_key(path, SigningKey(KEY, persisted))
    restarted = SigningSession(load_key(path), lambda: T0_US + 1_000_000, key_path=path)
    assert restarted.check.check(frame(KEY, persisted - 1000), 0, 245, 191) is Verdict.REPLAYED
    assert restarted.check.check(frame(KEY, persisted, sysid=246), 0, 246, 191) is Verdict.REPLAYED
    assert restarted.check.check(frame(KEY, persisted + 1, sysid=247), 0, 247, 191) is Verdict.SIGNED
    lockstep = SigningSession(load_key(path), lambda: T0_US + 1_000_000)  # no key file: the window alone
    assert lockstep.check.check(frame(KEY, persisted - 1000), 0, 245, 191) is Verdict.SIGNED
