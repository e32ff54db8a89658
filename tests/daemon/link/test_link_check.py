"""``uav-depth run --check`` opens the MAVLink link once: one that ``run`` would retry for ever is exit 69, one line.

Issue 44 item 9: a missing serial port or a port another program holds passed ``run --check`` while ``run``
retried for ever and sent nothing.
"""

import socket
import subprocess
import sys
from pathlib import Path

import pytest

from uav_depth.cli.exit_codes import EXIT_UNAVAILABLE

from mavlink_peer import free_port

CONFIG = Path(__file__).resolve().parents[3] / "deploy" / "examples" / "sitl.yaml"


def check(url):
    out = subprocess.run([sys.executable, "-m", "uav_depth.cli.main", "run", "--check", "--config", str(CONFIG),
                          "--mavlink-url", url], capture_output=True, text=True, timeout=120)
    return out.returncode, out.stdout, [line for line in out.stderr.splitlines() if "error" in line]


@pytest.mark.parametrize("kind", ["serial missing", "udpin in use", "tcpin in use"])
def test_a_link_run_cannot_open_fails_the_check_with_one_line(kind):
    holder = None
    if kind == "serial missing":
        url, why = "/dev/ttyUAVDEPTH9", "does not exist (is the flight controller connected?)"
    else:
        stream = kind.startswith("tcpin")
        holder = socket.socket(socket.AF_INET, socket.SOCK_STREAM if stream else socket.SOCK_DGRAM)
        holder.bind(("127.0.0.1", 0))
        if stream:
            holder.listen(1)
        url = f"{kind.split()[0]}:127.0.0.1:{holder.getsockname()[1]}"
        why = "is in use by another program (another uav-depth, MAVProxy?)"
    try:
        code, stdout, errors = check(url)
    finally:
        if holder is not None:
            holder.close()
    assert code == EXIT_UNAVAILABLE, (code, stdout, errors)
    assert errors == [f"uav-depth run --check: error: mavlink.url {url} {why}: run would retry every 0.25 s and "
                      "send nothing"]


def test_a_link_that_opens_is_checked():
    url = f"udpin:127.0.0.1:{free_port()}"
    code, stdout, errors = check(url)
    assert code == 0 and errors == [], (stdout, errors)
    assert f"checked: link {url} opens" in stdout
