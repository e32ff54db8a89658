"""The link's transports against real pymavlink endpoints on loopback: subscriptions, signing, reconnects, deadlines."""

import os
import socket
import time

import pytest

from uav_depth.core.errors import ConfigError
from uav_depth.daemon.config import MavlinkConfig
from uav_depth.daemon.link.endpoint import MavlinkLink
from uav_depth.daemon.link.signing import load_signing_key
from uav_depth.daemon.link.vocabulary import mavutil

from mavlink_peer import Receiver, free_port


def test_subscribe_and_message_interval_over_the_same_connection():
    port = free_port()
    autopilot = Receiver(f"udpin:127.0.0.1:{port}", sysid=1, compid=1)
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}")).start()
    got = []
    link.subscribe("LOCAL_POSITION_NED", got.append)
    link.request_message_interval("LOCAL_POSITION_NED", 20)      # before the autopilot is known
    try:
        link.wait_connected(2)
        link.heartbeat()                                          # the autopilot learns our address
        autopilot.wait_for("HEARTBEAT")
        mav = autopilot.conn.mav
        deadline = time.monotonic() + 5
        while not got and time.monotonic() < deadline:
            mav.heartbeat_send(2, 3, 0, 0, 4)                     # quadrotor, ArduPilot
            mav.local_position_ned_send(1234, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3)
            time.sleep(0.05)
        assert got and (got[0].x, got[0].y, got[0].z) == (1.0, 2.0, -3.0)
        assert link.autopilot == (1, 1)
        cmds = autopilot.wait_for("COMMAND_LONG", pred=lambda m: m.command == 511)
        assert cmds[-1].param1 == 32 and cmds[-1].param2 == pytest.approx(50000)
        assert (cmds[-1].target_system, cmds[-1].target_component) == (1, 1)
    finally:
        link.close()
        autopilot.close()


def test_signing_key_file_permissions_and_signed_messages(tmp_path):
    key_file = tmp_path / "mavlink.key"
    key_file.write_text("correct horse battery staple\n")
    key_file.chmod(0o644)
    with pytest.raises(ConfigError, match="must not be accessible by group or others"):
        load_signing_key(key_file)
    key_file.chmod(0o600)
    key = load_signing_key(key_file)
    assert len(key) == 32
    big = tmp_path / "big.key"
    big.write_bytes(b"x" * 5000)
    big.chmod(0o600)
    with pytest.raises(ConfigError, match=r"must be a regular file of at most 4096 bytes, but got '.*big\.key \(5000 bytes\)'"):
        load_signing_key(big)
    fifo = tmp_path / "fifo.key"
    os.mkfifo(fifo, 0o600)              # reading it would wait for a writer
    with pytest.raises(ConfigError, match=r"must be a regular file of at most 4096 bytes"):
        load_signing_key(fifo)
    hex_file = tmp_path / "hex.key"
    hex_file.write_text(key.hex())
    hex_file.chmod(0o600)
    assert load_signing_key(hex_file) == key
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=255, compid=190)
    peer.conn.setup_signing(key, sign_outgoing=False)             # rejects anything not signed with the key
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}", signing_key_file=key_file)).start()
    try:
        link.wait_connected(2)
        deadline = time.monotonic() + 5
        while not peer.of("STATUSTEXT") and time.monotonic() < deadline:
            link.statustext("uav-depth: signed hello")
            time.sleep(0.05)
        msg = peer.wait_for("STATUSTEXT")[0]
        assert msg.text == "uav-depth: signed hello" and msg._signed
    finally:
        link.close()
        peer.close()


def test_tcp_link_without_peer_never_blocks_and_reconnects():
    port = free_port(socket.SOCK_STREAM)
    link = MavlinkLink(MavlinkConfig(url=f"tcp:127.0.0.1:{port}"), reconnect_min_s=0.05,
                       reconnect_max_s=0.2).start()
    try:
        start = time.monotonic()
        assert not link.send(lambda mav: mav.heartbeat_encode(18, 8, 0, 0, 4))   # nobody there: dropped
        assert time.monotonic() - start < 0.1 and link.count.dropped == 1
        server = Receiver(f"tcpin:127.0.0.1:{port}", sysid=255, compid=190)
        assert link.wait_connected(5)
        deadline = time.monotonic() + 5
        while not server.of("HEARTBEAT") and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
        server.wait_for("HEARTBEAT")
        server.close()                                               # the autopilot goes away
        deadline = time.monotonic() + 5
        while link.connected and time.monotonic() < deadline:        # noticed, and retrying quietly
            link.heartbeat()
            time.sleep(0.05)
        assert not link.connected
        server = Receiver(f"tcpin:127.0.0.1:{port}", sysid=255, compid=190)   # and comes back
        deadline = time.monotonic() + 5
        while not server.of("HEARTBEAT") and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
        server.wait_for("HEARTBEAT")
        server.close()
    finally:
        assert link.close()


def test_udpout_is_bound_to_loopback_and_hears_only_the_autopilot():
    port = free_port()
    peer = Receiver(f"udpin:127.0.0.1:{port}", sysid=1, compid=1, autopilot=True)
    link = MavlinkLink(MavlinkConfig(url=f"udpout:127.0.0.1:{port}")).start()
    got = []
    link.subscribe("HEARTBEAT", got.append)
    stranger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert link.wait_connected(2)
        local = link._pump.t.local
        assert local[0] == "127.0.0.1"                              # never 0.0.0.0
        link.heartbeat()
        assert peer.wait(lambda: got, 5)                            # the autopilot is heard
        enc = mavutil().mavlink.MAVLink(None, 42, 1)                # a stranger's valid HEARTBEAT to our port
        n = len(got)
        for _ in range(5):
            stranger.sendto(enc.heartbeat_encode(2, 3, 0, 0, 4).pack(enc), local)
            time.sleep(0.05)
        time.sleep(0.3)
        assert all(m.get_srcSystem() == 1 for m in got[n:])         # the kernel drops the stranger's datagrams
    finally:
        stranger.close()
        link.close()
        peer.close()


def test_serial_link_through_a_pseudo_terminal():
    master, slave = os.openpty()
    link = MavlinkLink(MavlinkConfig(url=os.ttyname(slave), baud=57600)).start()
    parser = mavutil().mavlink.MAVLink(None, 255, 0)
    parser.robust_parsing = True
    got = []
    try:
        assert link.wait_connected(2)
        deadline = time.monotonic() + 5
        os.set_blocking(master, False)
        while not got and time.monotonic() < deadline:
            link.heartbeat()
            time.sleep(0.05)
            try:
                data = os.read(master, 4096)
            except BlockingIOError:
                continue
            got += [m for m in parser.parse_buffer(data) or () if m.get_type() == "HEARTBEAT"]
        assert got and (got[0].get_srcSystem(), got[0].get_srcComponent()) == (1, 191)
    finally:
        link.close()
        os.close(master)
        os.close(slave)


def _stalled_tcp_pair(port):
    """A TcpServer whose one peer has a tiny receive buffer and does not read (yet)."""
    from uav_depth.daemon.link.streams import TcpServer

    server = TcpServer("127.0.0.1", port)
    peer = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    peer.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
    peer.connect(("127.0.0.1", port))
    deadline = time.monotonic() + 5
    while server.conn is None and time.monotonic() < deadline:
        server.poll()
        time.sleep(0.01)
    assert server.conn is not None
    return server, peer


def _drain(peer, timeout_s=0.5) -> bytes:
    peer.settimeout(timeout_s)
    got = b""
    try:
        while chunk := peer.recv(65536):
            got += chunk
    except (socket.timeout, BlockingIOError):
        pass
    return got


def test_bytes_the_kernel_holds_past_their_deadline_are_discarded_with_a_reset():
    # a TCP peer whose window is closed: what waits in our kernel would arrive old, so the connection is
    # reset instead (the link then reconnects)
    server, peer = _stalled_tcp_pair(free_port(socket.SOCK_STREAM))
    try:
        now = time.monotonic()
        deadline = now + 0.2
        while server.write(b"\xfd" + bytes(199), deadline, now):      # until the kernel holds no more
            pass
        assert not server.overdue(now)
        assert server.overdue(deadline + 0.01)
        server.discard()
        peer.settimeout(2)
        with pytest.raises(ConnectionResetError):       # after what its buffer held: the reset
            while peer.recv(65536):
                pass
    finally:
        server.close()
        peer.close()


def test_the_tail_of_a_frame_is_never_written_past_its_deadline():
    # issue 44 item 4: a frame the kernel took only in part had its tail written whenever the stream took
    # bytes again, however old the frame was by then: the peer got a whole old reading
    server, peer = _stalled_tcp_pair(free_port(socket.SOCK_STREAM))
    frame = b"\xfd" + bytes(998) + b"\x01"                           # one frame, 1000 bytes
    try:
        now = time.monotonic()
        deadline = now + 0.2
        for _ in range(10_000):                                      # until the kernel takes a frame in part
            assert server.write(frame, deadline, now), "the kernel filled up exactly at a frame's end; rerun"
            if server.tail_expired(deadline + 1):
                break
        got = _drain(peer)                                           # the peer reads again: room in the pipe
        late = deadline + 0.01
        assert not server.write(b"\xfd" + bytes(99), late + 1, late)  # the old frame's tail is not finished
        assert server.overdue(late)                                  # so the link discards the stream
        got += _drain(peer)
        assert len(got) % len(frame) != 0                            # the old frame arrived cut, never whole
    finally:
        server.close()
        peer.close()
