"""bench/faults.py's rows for the link, the scene and the signals: who may take the stream, a stalled TCP peer,
a blank noisy surface, SIGINT/SIGTERM early in start-up, and what goes out after "stopping".

Each case starts the real ``uav-depth run``; the peers are those of the link fault tests
(tests/daemon/test_link_faults.py: bare UDP endpoints with their own parser, pymavlink receivers).
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import yaml

from mavlink_peer import Receiver, free_port
from test_faults_signals import WANTED, _blocked, _caught, unit_exec_prefix
from test_link_faults_udpin import Udp, _heartbeat, _parser, _serve
from wire_rows import GOOD, MAX_AGE_MS, SCENE, Daemon, Row, age_ms, config, expected

from uav_depth.daemon.link.conditions import Condition
from uav_depth.daemon.link.signing import load_signing_key

#: How long the TCP peer stops reading (issue 44 item 4: 10 s).
STALL_S = 10.0


def _daemon(d: Path, url: str, source: dict | None = None, **mavlink) -> Daemon:
    d.mkdir(parents=True, exist_ok=True)
    (d / "params.yaml").write_text(GOOD)
    extra = {"source": source} if source else {}
    return Daemon(d, config(0, d / "params.yaml", mavlink={"url": url, **mavlink}, **extra))


def _close(daemon: Daemon, *peers) -> None:
    daemon.stop()
    daemon.kill()
    for p in peers:
        p.close()


def _readings_again(daemon: Daemon, peer: Udp, frames, n: int = 3) -> int:
    """Send ``frames()`` from ``peer`` until it has ``n`` more readings; how many it got."""
    start = len(peer.of("DISTANCE_SENSOR"))

    def more():
        peer.send(frames())
        time.sleep(0.1)
        return len(peer.of("DISTANCE_SENSOR")) - start >= n
    daemon.wait_for(more, f"{n} readings for the autopilot", timeout=60)
    return len(peer.of("DISTANCE_SENSOR")) - start


def udpin_takeover(d: Path) -> list[Row]:
    """After 3.5 s of autopilot silence, a stranger sends autopilot HEARTBEATs for 3 s."""
    port = free_port()
    daemon = _daemon(d, f"udpin:127.0.0.1:{port}")
    autopilot, stranger, mav = Udp(port), Udp(port), _parser()
    try:
        daemon.wait_for(lambda: "ready:" in daemon.stderr(), "start-up")
        _readings_again(daemon, autopilot, lambda: _heartbeat(mav), 5)
        _serve(port, None, 3.5, autopilot)                                   # the autopilot falls silent
        _serve(port, lambda: _heartbeat(_parser()), 3.0, stranger, autopilot)
        back = _readings_again(daemon, autopilot, lambda: _heartbeat(mav))
    finally:
        _close(daemon, autopilot, stranger)
    return [Row("udpin: a stranger's HEARTBEAT after 3.5 s of autopilot silence",
                "the stranger gets nothing; the autopilot keeps the stream",
                f"stranger got {len(stranger.got)} messages; the autopilot {back} readings on its return",
                not stranger.got and back > 0)]


def _key_file(d: Path) -> Path:
    """The signing key the daemon and the autopilot share (mode 0600, as the daemon requires)."""
    key_file = d / "mavlink.key"
    key_file.write_text("correct horse battery staple\n")
    key_file.chmod(0o600)
    return key_file


def signed_replay(d: Path) -> list[Row]:
    """With signing: the autopilot's own signed HEARTBEATs replayed from another address, then the autopilot moves."""
    key_file = _key_file(d)
    port = free_port()
    daemon = _daemon(d, f"udpin:127.0.0.1:{port}", signing_key_file=str(key_file))
    autopilot, attacker, moved = Udp(port), Udp(port), Udp(port)
    mav, captured = _parser(load_signing_key(key_file)), []
    try:
        daemon.wait_for(lambda: "ready:" in daemon.stderr(), "start-up")
        _readings_again(daemon, autopilot, lambda: captured.append(_heartbeat(mav)) or captured[-1], 5)
        _serve(port, None, 3.5, autopilot)                                   # the autopilot falls silent
        replays = iter(captured * 50)
        _serve(port, lambda: next(replays), 3.0, attacker)
        rebound = _readings_again(daemon, moved, lambda: _heartbeat(mav))
    finally:
        _close(daemon, autopilot, attacker, moved)
    return [Row("udpin, signing: a replayed signed HEARTBEAT",
                "the replaying sender gets nothing; the autopilot's new signed HEARTBEAT re-binds",
                f"replaying sender got {len(attacker.got)} messages; moved autopilot {rebound} readings",
                not attacker.got and rebound > 0)]


def wrong_key_flood(d: Path) -> list[Row]:
    """Wrongly signed HEARTBEATs, 50 every 5 ms for 3 s, before any autopilot is bound."""
    key_file = _key_file(d)
    port = free_port()
    daemon = _daemon(d, f"udpin:127.0.0.1:{port}", signing_key_file=str(key_file))
    flooder, wrong = Udp(port), _parser(b"\x01" * 32)
    try:
        daemon.wait_for(lambda: "ready:" in daemon.stderr(), "start-up")
        before = len(daemon.stderr().splitlines())
        sent = flooder.flood(lambda: _heartbeat(wrong), 3.0)
        daemon.wait_for(lambda: "status:" in "".join(daemon.stderr().splitlines()[before:]), "a status line")
        lines = [ln for ln in daemon.stderr().splitlines()[before:] if "status:" not in ln]
    finally:
        _close(daemon, flooder)
    return [Row("udpin, signing: a flood of wrongly signed datagrams", "at most 5 log lines, nothing answered",
                f"{len(lines)} log lines for {sent} datagrams; answered {len(flooder.got)}",
                len(lines) <= 5 and not flooder.got)]


def _tcp_peer(daemon: Daemon, port: int, answers: bool) -> Receiver:
    def connect():
        try:
            return Receiver(f"tcp:127.0.0.1:{port}", autopilot=answers)
        except OSError:
            time.sleep(0.2)
            return None
    return daemon.wait_for(connect, "the TCP connection")


def _live_s(peer: Receiver, since: float) -> float:
    beats = [t for t, _ in peer.timed("HEARTBEAT", since)]
    return beats[-1] - beats[0] if beats else 0.0


def tcp_stall(d: Path) -> list[Row]:
    """A tcpin peer stops reading (and answering) for STALL_S; what it reads on resuming."""
    rows = []
    for answers in (True, False):
        port = free_port(socket.SOCK_STREAM)
        daemon = _daemon(d / f"tcp-{answers}", f"tcpin:127.0.0.1:{port}")
        peer = _tcp_peer(daemon, port, answers)
        try:
            daemon.wait_for(lambda: len(peer.of("HEARTBEAT")) >= 3
                            and (not answers or len(peer.of("DISTANCE_SENSOR")) >= 10),
                            "3 HEARTBEAT (and 10 readings, if it answers TIMESYNC)")
            peer.pause()
            time.sleep(STALL_S)                                # the fault itself: a peer that reads nothing
            peer.resume()
            t_resume = time.monotonic()
            # the backlog of HEARTBEAT arrives at once on resuming; 2 s between them is the live stream's
            daemon.wait_for(lambda: _live_s(peer, t_resume) >= 2.0 and (not answers or
                                                                      len(peer.of("DISTANCE_SENSOR", t_resume)) >= 10),
                            "2 s of HEARTBEAT after the resume (and 10 readings, if it answers TIMESYNC)")
        finally:
            _close(daemon, peer)
        ages = [age_ms(t, m) for t, m in peer.timed("DISTANCE_SENSOR", t_resume)]
        told = answers or "answers no TIMESYNC request" in daemon.stderr()     # the operator is told why
        old = [a for a in ages if a > MAX_AGE_MS]
        allowed = 1 if answers else 0           # docs/wire.md: one, if it stopped between answering and reading
        kind = "answers TIMESYNC" if answers else "answers no TIMESYNC"
        rows.append(Row(f"TCP peer ({kind}) stops reading for {STALL_S:g} s",
                        ("readings again, " if answers else "") +
                        f"at most {allowed} older than {MAX_AGE_MS:g} ms after it resumes"
                        + ("" if answers else "; the log says it answers no TIMESYNC"),
                        f"{len(old)} of {len(ages)} older (oldest {max(ages, default=0):.0f} ms)"
                        + ("" if answers else f"; logged why: {told}"),
                        len(old) <= allowed and bool(ages or not answers) and told))
    return rows


def blank_noisy_scene(d: Path) -> list[Row]:
    """A featureless surface with sensor noise (synthetic contrast 0): nothing confident, never "too close"."""
    rows = []
    for noise in (2.0, 4.0):
        rx = Receiver()
        scene = {**SCENE, "contrast": 0.0, "noise_std": noise, "n_branches": 0}
        daemon = _daemon(d / f"noise-{noise:g}", f"udpout:127.0.0.1:{rx.port}",
                         source={"kind": "synthetic", "fps": 10, "scene": scene})
        try:
            t_ready = daemon.wait_for(lambda: "ready:" in daemon.stderr() and time.monotonic(), "start-up")
            daemon.wait_for(lambda: len(rx.of("HEARTBEAT", t_ready)) >= 5, "5 HEARTBEAT after start-up")
        finally:
            _close(daemon, rx)
        got = [m.current_distance for m in rx.of("DISTANCE_SENSOR")]
        texts = ", ".join(f'"{t}"' for t in dict.fromkeys(rx.texts()))
        shown = f"{len(got)} DISTANCE_SENSOR" + (f" ({min(got)}..{max(got)} cm)" if got else "")
        rows.append(Row(f"blank noisy scene (contrast 0, noise std {noise:g})",
                        f'no DISTANCE_SENSOR; "{expected(Condition.NOTHING_CONFIDENT).texts[0]}"', f"{shown}; {texts}",
                        not got and expected(Condition.NOTHING_CONFIDENT).texts[0] in rx.texts()))
    return rows


def stops(d: Path, runs: int = 3) -> list[Row]:
    """SIGTERM while readings flow: nothing but the POWEROFF HEARTBEAT after "stopping"."""
    seen, ok = [], True
    stopping = expected(Condition.SHUTTING_DOWN).texts[0]
    for i in range(runs):
        rx = Receiver()
        daemon = _daemon(d / f"stop-{i}", f"udpout:127.0.0.1:{rx.port}")
        try:
            daemon.wait_for(lambda: len(rx.of("DISTANCE_SENSOR")) >= 10, "10 readings")
            code = daemon.stop()
            t_stop = daemon.wait_for(lambda: next((t for t, m in rx.timed("STATUSTEXT") if m.text == stopping), None),
                                     f'"{stopping}"', timeout=10)
            rx.wait(lambda: rx.of("HEARTBEAT", t_stop), 5)
        finally:
            _close(daemon, rx)
        after = [m.get_type() for t, m in rx.msgs if t > t_stop and m.get_type() != "HEARTBEAT"]
        ok &= code == 0 and not after
        seen.append(f"exit {code}, {len(after)} after")
    return [Row(f'SIGTERM while measuring ({runs} stops): after "stopping"', "nothing but HEARTBEAT POWEROFF; exit 0",
                "; ".join(seen), ok)]


def _signal_once(d: Path, sig: signal.Signals, at_exec: bool) -> tuple[bool, str]:
    rx = Receiver()
    (d / "params.yaml").write_text(GOOD)
    path = d / "run.yaml"
    path.write_text(yaml.safe_dump(config(rx.port, d / "params.yaml")))
    err_path = d / f"stderr-{sig.name}-{at_exec}.txt"
    prefix = unit_exec_prefix() if at_exec else []
    t0 = time.monotonic()
    with open(err_path, "w") as err:
        proc = subprocess.Popen([*prefix, sys.executable, "-m", "uav_depth.cli.main", "run", "--config", str(path)],
                                stdout=subprocess.DEVNULL, stderr=err)
    ready = _blocked if at_exec else _caught
    try:
        while ready(proc.pid) & WANTED != WANTED and proc.poll() is None:
            time.sleep(0.0005)
        t_sig = time.monotonic() - t0
        proc.send_signal(sig)
        code = proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        rx.close()
    text = err_path.read_text()
    said = f"stopped before start-up finished ({sig.name})" in text or "shutdown complete" in text
    clean = "Traceback" not in text and "KeyboardInterrupt" not in text
    return code == 0 and said and clean, f"{sig.name} at {1000 * t_sig:.0f} ms: exit {code}, said {said}, clean {clean}"


def early_signals(d: Path) -> list[Row]:
    """SIGINT and SIGTERM as soon as the handlers are in, and at exec under the unit's blocked start."""
    rows = []
    for at_exec, when in ((False, "as soon as its handlers are in"), (True, "at exec, under the unit's start")):
        results = [_signal_once(d, sig, at_exec) for sig in (signal.SIGINT, signal.SIGTERM)]
        rows.append(Row(f"SIGINT / SIGTERM {when}", "exit 0, one line, no traceback",
                        "; ".join(r[1] for r in results), all(r[0] for r in results)))
    return rows


CASES = [udpin_takeover, signed_replay, wrong_key_flood, tcp_stall, blank_noisy_scene, stops, early_signals]
