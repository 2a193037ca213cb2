"""The plant's link with signing and an allow-list: real UDP sockets, real pymavlink frames."""

from __future__ import annotations

import socket
import time

from pymavlink.dialects.v20 import common as mavlink

from offboard.signing import SigningKey, SigningSession, load_key, save_key
from sitl_plant.autopilot import Autopilot
from sitl_plant.link import Endpoint, Link
from sitl_plant.params import plant_params
from sitl_plant.server import API, Plant, PlantConfig, _dispatch, _Driver, run_lockstep
from offboard.model.vehicle import PAPER_VEHICLE_FILE, load_vehicle

KEY = bytes(range(1, 33))
NEW_KEY = bytes(range(50, 82))
EPOCH_US = 1_796_000_000_000_000


def make_plant(*, signing: bool = True) -> Plant:
    vehicle = load_vehicle(PAPER_VEHICLE_FILE)
    params = plant_params(vehicle)
    return Plant(PlantConfig(lockstep=True, start_epoch_s=EPOCH_US / 1e6, signing=signing), vehicle, params, Autopilot(params))


class Client:
    """A MAVLink client on its own socket: signs with ``secret`` (or not), reads what comes back."""

    def __init__(self, plant_address, *, sysid: int = 245, secret: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.5)
        self.plant_address = plant_address
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=191)
        if secret is not None:
            self.mav.signing.secret_key, self.mav.signing.sign_outgoing = secret, True
            self.mav.signing.timestamp = (EPOCH_US // 10) - 1_420_070_400 * 100_000 + 1

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.plant_address)

    def close(self) -> None:
        self.sock.close()


def serve(plant: Plant, link: Link, seconds: float = 0.1) -> None:
    """Receive and handle what arrived (the loops' dispatch), then send the replies."""
    driver = _Driver(plant, link, time.monotonic, None)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if link.wait(0.01):
            _dispatch(driver, link.receive())
    driver.flush_outbox()


def arm(target: int = 1) -> mavlink.MAVLink_message:
    return mavlink.MAVLink_command_long_message(target, 1, 400, 0, 1, 21196, 0, 0, 0, 0, 0)


def test_with_a_key_only_signed_frames_are_handled_and_answered():
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, signing=SigningSession(SigningKey(KEY), plant.epoch_us))
    link = Link([endpoint], None, plant.epoch_us)
    intruder = Client(endpoint.local_address, sysid=200)
    forger = Client(endpoint.local_address, sysid=245, secret=bytes(32 * [7]))
    owner = Client(endpoint.local_address, sysid=245, secret=KEY)
    try:
        intruder.send(arm())
        forger.send(arm())
        serve(plant, link)
        assert not plant.autopilot.armed and endpoint.remote is None  # neither armed it nor became the remote
        assert endpoint.counters.refused == {"unsigned": 1, "bad_signature": 1}
        owner.send(arm())
        serve(plant, link)
        assert plant.autopilot.armed and endpoint.remote == owner.sock.getsockname()
        reply = owner.sock.recv(65535)
        assert reply[2] & 1  # the ack is signed
        parser = mavlink.MAVLink(None)
        parser.signing.secret_key = KEY
        assert "COMMAND_ACK" in [m.get_type() for m in parser.parse_buffer(reply)]  # pymavlink verifies them
    finally:
        link.close()
        for c in (intruder, forger, owner):
            c.close()


def test_an_allow_list_refuses_other_systems():
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, allowed_senders=frozenset({245}))
    link = Link([endpoint], None, plant.epoch_us)
    other, owner = Client(endpoint.local_address, sysid=200), Client(endpoint.local_address, sysid=245)
    try:
        other.send(arm())
        serve(plant, link)
        assert not plant.autopilot.armed and endpoint.counters.refused_senders == {200: 1}
        owner.send(arm())
        serve(plant, link)
        assert plant.autopilot.armed
    finally:
        link.close()
        other.close()
        owner.close()


def test_setup_signing_is_refused_armed_and_rekeys_every_link_disarmed(tmp_path):
    path = tmp_path / "key.bin"
    save_key(path, SigningKey(KEY))
    plant = make_plant()
    sessions = [SigningSession(load_key(path), plant.epoch_us, link_id=i, key_path=path) for i in range(2)]
    endpoints = [Endpoint(n, ("127.0.0.1", 0), None, 1, 1, signing=s) for n, s in zip(("api", "gcs"), sessions)]
    link = Link(endpoints, None, plant.epoch_us)
    owner = Client(endpoints[API].local_address, secret=KEY)
    setup = mavlink.MAVLink_setup_signing_message(1, 1, list(NEW_KEY), 0)
    try:
        owner.send(arm())
        serve(plant, link)
        owner.send(setup)
        serve(plant, link)
        assert plant.autopilot.armed and endpoints[API].signing.key.secret == KEY  # refused while armed
        assert plant.counters.refusals.get("SETUP_SIGNING") == 1
        owner.send(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))  # disarm
        owner.send(setup)
        serve(plant, link)
        assert not plant.autopilot.armed
        assert all(e.signing.key.secret == NEW_KEY for e in endpoints)
        assert load_key(path).secret == NEW_KEY  # persisted in PX4's layout
        owner.send(arm())  # still signed with the old key: refused now
        serve(plant, link)
        assert not plant.autopilot.armed and endpoints[API].counters.refused.get("bad_signature") == 1
    finally:
        link.close()
        owner.close()


def test_a_plant_without_signing_ignores_setup_signing_as_px4_v1_16():
    """Issue 14's audit: an unsigned SETUP_SIGNING switched signing on with the sender's key and
    locked the owner out. PX4 v1.16 has no signing and ignores it (its outgoing frames stay
    unsigned, unsigned commands are still taken: tests/e2e/test_px4_parity_signing.py); so
    does the plant, counting it."""
    plant = make_plant(signing=False)
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1)
    link = Link([endpoint], None, plant.epoch_us)
    stranger, owner = Client(endpoint.local_address, sysid=200), Client(endpoint.local_address, sysid=245)
    try:
        stranger.send(mavlink.MAVLink_setup_signing_message(1, 1, list(NEW_KEY), 10**12))
        serve(plant, link)
        assert endpoint.signing is None and not plant.signing and plant.signing_change is None
        assert plant.counters.ignored == {"SETUP_SIGNING": 1}
        owner.send(arm())  # unsigned, as before
        serve(plant, link)
        assert plant.autopilot.armed
        reply = owner.sock.recv(65535)
        assert not reply[2] & 1  # what the plant sends is still unsigned
    finally:
        link.close()
        stranger.close()
        owner.close()


def test_setup_signing_switches_signing_off_and_then_is_ignored():
    """An all-zero key switches signing off; from then on the plant is one that does not sign,
    and ignores SETUP_SIGNING (as PX4 v1.16), so nobody can switch it on again unsigned."""
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, signing=SigningSession(SigningKey(KEY), plant.epoch_us))
    link = Link([endpoint], None, plant.epoch_us)
    owner = Client(endpoint.local_address, secret=KEY)
    stranger = Client(endpoint.local_address, sysid=200)
    try:
        owner.send(mavlink.MAVLink_setup_signing_message(1, 1, [0] * 32, 0))
        serve(plant, link)
        assert endpoint.signing is None and not plant.signing
        stranger.send(mavlink.MAVLink_setup_signing_message(1, 1, list(NEW_KEY), 10**12))
        serve(plant, link)
        assert endpoint.signing is None and plant.counters.ignored == {"SETUP_SIGNING": 1}
    finally:
        link.close()
        owner.close()
        stranger.close()


def test_the_lockstep_loop_applies_a_setup_signing_too():
    """run_lockstep handled SETUP_SIGNING (and announced the new key) but never gave the key to the
    links: only the real-time loop did."""
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, signing=SigningSession(SigningKey(KEY), plant.epoch_us, lockstep=True))
    link = Link([endpoint], None, plant.epoch_us, lockstep=True)
    owner = Client(endpoint.local_address, secret=KEY)
    try:
        owner.send(mavlink.MAVLink_setup_signing_message(1, 1, list(NEW_KEY), 0))
        end = time.monotonic() + 0.3
        run_lockstep(plant, link, stop=lambda: time.monotonic() > end)
        assert endpoint.signing is not None and endpoint.signing.key.secret == NEW_KEY
    finally:
        link.close()
        owner.close()


def heartbeat() -> mavlink.MAVLink_message:
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)


def received_types(client: Client) -> list[str]:
    """What reached ``client`` (nothing: [])."""
    parser = mavlink.MAVLink(None)
    out = []
    client.sock.settimeout(0.05)
    while True:
        try:
            data = client.sock.recv(65535)
        except (TimeoutError, socket.timeout):
            return out
        out += [m.get_type() for m in parser.parse_buffer(data) or []]


def test_a_frame_accepted_unsigned_is_handled_but_does_not_take_the_telemetry():
    """Issue 14: PX4 takes RADIO_STATUS, ADSB_VEHICLE and COLLISION unsigned; one from a stranger
    made the plant answer the stranger. Only a verified signed frame moves the remote."""
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, signing=SigningSession(SigningKey(KEY), plant.epoch_us))
    link = Link([endpoint], None, plant.epoch_us)
    owner = Client(endpoint.local_address, sysid=245, secret=KEY)
    stranger = Client(endpoint.local_address, sysid=200)
    try:
        owner.send(heartbeat())
        serve(plant, link)
        assert endpoint.remote == owner.sock.getsockname()
        received_types(owner)
        stranger.send(mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0))
        stranger.send(mavlink.MAVLink_adsb_vehicle_message(1234, 0, 0, 0, 1000, 0, 0, 0, b"INTRUDE", 0, 1, 0, 0))
        stranger.send(mavlink.MAVLink_collision_message(0, 1234, 1, 0, 0, 10, 10))
        serve(plant, link)
        # handled (counted as received, none refused) ...
        assert {k: endpoint.counters.by_type_in.get(k) for k in ("RADIO_STATUS", "ADSB_VEHICLE", "COLLISION")} == \
            {"RADIO_STATUS": 1, "ADSB_VEHICLE": 1, "COLLISION": 1}
        assert endpoint.counters.refused == {}
        # ... but the plant still answers the owner, and the stranger hears nothing
        assert endpoint.remote == owner.sock.getsockname()
        owner.send(arm())
        serve(plant, link)
        assert plant.autopilot.armed
        assert "COMMAND_ACK" in received_types(owner)
        assert received_types(stranger) == []
    finally:
        link.close()
        owner.close()
        stranger.close()


def test_without_signing_any_accepted_frame_moves_the_remote_as_px4_does():
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1)
    link = Link([endpoint], None, plant.epoch_us)
    first, second = Client(endpoint.local_address, sysid=245), Client(endpoint.local_address, sysid=200)
    try:
        first.send(heartbeat())
        serve(plant, link)
        assert endpoint.remote == first.sock.getsockname()
        second.send(mavlink.MAVLink_radio_status_message(200, 180, 50, 40, 30, 0, 0))
        serve(plant, link)
        assert endpoint.remote == second.sock.getsockname()
    finally:
        link.close()
        first.close()
        second.close()


def test_an_owners_signed_frame_sent_again_is_refused_as_replayed():
    plant = make_plant()
    endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1, signing=SigningSession(SigningKey(KEY), plant.epoch_us))
    link = Link([endpoint], None, plant.epoch_us)
    owner = Client(endpoint.local_address, sysid=245, secret=KEY)
    replayer = Client(endpoint.local_address, sysid=200)
    try:
        armed_bytes = arm().pack(owner.mav)  # recorded off the link by someone listening
        owner.sock.sendto(armed_bytes, endpoint.local_address)
        serve(plant, link)
        assert plant.autopilot.armed
        owner.send(mavlink.MAVLink_command_long_message(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))  # disarm
        serve(plant, link)
        assert not plant.autopilot.armed
        received_types(owner)
        replayer.sock.sendto(armed_bytes, endpoint.local_address)  # the same bytes, from elsewhere
        owner.sock.sendto(armed_bytes, endpoint.local_address)  # and from the owner's own address
        serve(plant, link)
        assert not plant.autopilot.armed
        assert endpoint.counters.refused == {"replayed": 2} and endpoint.counters.refused_senders == {245: 2}
        assert endpoint.remote == owner.sock.getsockname() and received_types(replayer) == []
    finally:
        link.close()
        owner.close()
        replayer.close()


def test_the_links_persist_the_highest_timestamp_once(tmp_path, monkeypatch):
    """Each link's session wrote the key file as it closed: the last closed won, not the highest."""
    import offboard.signing

    path = tmp_path / "key.bin"
    save_key(path, SigningKey(KEY))
    plant = make_plant()
    sessions = [SigningSession(load_key(path), plant.epoch_us, link_id=i, key_path=path) for i in range(2)]
    endpoints = [Endpoint(n, ("127.0.0.1", 0), None, 1, 1, signing=s) for n, s in zip(("api", "gcs"), sessions)]
    link = Link(endpoints, None, plant.epoch_us)
    owner = Client(endpoints[API].local_address, secret=KEY)
    owner.mav.signing.timestamp += 10**7  # the owner's clock is 100 s ahead: the API link follows it
    writes = []
    monkeypatch.setattr(offboard.signing, "save_key", lambda p, k: writes.append(k) or save_key(p, k))
    try:
        owner.send(heartbeat())
        serve(plant, link)
        assert endpoints[API].counters.by_type_in == {"HEARTBEAT": 1}
    finally:
        link.close()
        owner.close()
    assert len(writes) == 1
    assert load_key(path).timestamp == sessions[API].newest > sessions[1].newest


def test_frames_recorded_before_a_restart_cannot_be_replayed_into_it(tmp_path):
    """The spec's one-minute window for a new stream would take them (PX4 keeps only that): the
    timestamp persisted at exit is a floor for every stream after the restart."""
    path = tmp_path / "key.bin"
    save_key(path, SigningKey(KEY))

    def start() -> tuple[Plant, Endpoint, Link]:
        plant = make_plant()
        endpoint = Endpoint("api", ("127.0.0.1", 0), None, 1, 1,
                            signing=SigningSession(load_key(path), plant.epoch_us, key_path=path))  # fmt: skip
        return plant, endpoint, Link([endpoint], None, plant.epoch_us)

    plant, endpoint, link = start()
    owner = Client(endpoint.local_address, secret=KEY)
    try:
        recorded = arm().pack(owner.mav)  # a second before the restart
        owner.sock.sendto(recorded, endpoint.local_address)
        serve(plant, link)
        assert plant.autopilot.armed
    finally:
        link.close()  # a clean exit: the newest timestamp persisted
    plant, endpoint, link = start()
    owner.plant_address = endpoint.local_address
    try:
        owner.sock.sendto(recorded, endpoint.local_address)
        serve(plant, link)
        assert not plant.autopilot.armed and endpoint.counters.refused == {"replayed": 1}
        owner.mav.signing.timestamp += 100_000  # the owner, a second later on its clock
        owner.send(arm())
        serve(plant, link)
        assert plant.autopilot.armed
    finally:
        link.close()
        owner.close()
