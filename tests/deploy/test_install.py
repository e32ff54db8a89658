"""deploy/: the systemd unit and the install/uninstall scripts, run for real into a temporary root.

install.sh --root DIR creates the user with systemd-sysusers --root and enables the unit with
systemctl --root, so the whole install runs here as it would into an image. The package is
installed from a wheel of this checkout with --no-deps (no network, seconds, not minutes).
Needs the Debian systemd package (.ci/system-deps installs it).
"""

from __future__ import annotations

import hashlib
import os
import pwd
import re
import shutil
import stat
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from uav_depth.cli.exit_codes import EXIT_CONFIG

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
UNIT = DEPLOY / "uav-depth.service"
IS_ROOT = os.geteuid() == 0
VENV = "/opt/uav-depth/venv"


def sh(*args: str, check: bool = True, user: str | None = None) -> subprocess.CompletedProcess:
    cmd = ["bash", *args]
    if user is not None:
        cmd = as_user(user) + cmd
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} -> {proc.returncode}\n{proc.stdout}\n{proc.stderr}")
    return proc


def as_user(user: str) -> list[str]:
    """Prefix that runs a command as ``user`` (only meaningful when we are root)."""
    if not IS_ROOT:
        return []
    if shutil.which("setpriv"):
        pw = pwd.getpwnam(user)
        return ["setpriv", f"--reuid={pw.pw_uid}", f"--regid={pw.pw_gid}", "--clear-groups"]
    return ["runuser", "-u", user, "--"]


def unit_settings(path: Path) -> dict[str, list[str]]:
    """key -> values of a unit file (repeated keys accumulate)."""
    out: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key, []).append(value)
    return out


def snapshot(root: Path, skip_venv_lib: bool = False) -> dict[str, tuple]:
    """path -> (mode, uid, gid, content hash or link target) for everything under ``root``."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        rel_dir = Path(dirpath).relative_to(root)
        if skip_venv_lib and rel_dir.as_posix() in ("opt/uav-depth/venv/lib", "opt/uav-depth/venv/bin"):
            dirnames[:] = []
            continue
        for name in dirnames + filenames:
            p = Path(dirpath) / name
            st = p.lstat()
            if stat.S_ISLNK(st.st_mode):
                what = "->" + os.readlink(p)
            elif stat.S_ISREG(st.st_mode):
                what = hashlib.sha256(p.read_bytes()).hexdigest()
            else:
                what = "dir"
            out[(rel_dir / name).as_posix()] = (stat.S_IMODE(st.st_mode), st.st_uid, st.st_gid, what)
    return out


def clone(root: Path, dest: Path) -> Path:
    """A copy of an installed root that keeps ownership (shutil.copytree does not), with the /usr/bin/env
    every image has (the unit's ExecStart starts through it)."""
    subprocess.run(["cp", "-a", f"{root}/.", str(dest)], check=True, timeout=120)
    (dest / "usr" / "bin").mkdir(parents=True, exist_ok=True)
    shutil.copy2("/usr/bin/env", dest / "usr" / "bin" / "env")
    return dest


def ids(root: Path, db: str, name: str) -> int:
    for line in (root / "etc" / db).read_text().splitlines():
        fields = line.split(":")
        if fields[0] == name:
            return int(fields[2])
    raise AssertionError(f"{name} not in {root}/etc/{db}")


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(out),
                    str(REPO)], check=True, capture_output=True, timeout=300)
    return next(out.glob("uav_depth-*.whl"))


def install_into(root: Path, wheel: Path, *extra: str) -> subprocess.CompletedProcess:
    return sh(str(DEPLOY / "install.sh"), "--root", str(root), "--from", str(wheel), "--no-deps",
              "--python", sys.executable, *extra)


@pytest.fixture(scope="module")
def installed(tmp_path_factory, wheel) -> tuple[Path, subprocess.CompletedProcess]:
    root = tmp_path_factory.mktemp("root")
    proc = install_into(root, wheel)
    return root, proc


def test_unit_passes_systemd_analyze_verify_as_installed(installed, tmp_path):
    root, _ = installed
    # verify --root resolves every unit inside the root: give it systemd's own units (sysinit.target,
    # multi-user.target) as the image would have them. It also checks ExecStart is executable there.
    work = clone(root, tmp_path)
    units = Path("/usr/lib/systemd/system")
    shutil.copytree(units, work / "usr/lib/systemd/system", symlinks=True)
    proc = subprocess.run(["systemd-analyze", "verify", f"--root={work}", "uav-depth.service"],
                          capture_output=True, text=True, timeout=60)
    # Unknown keys and bad values are only warnings for systemd: any output fails the test.
    assert proc.returncode == 0 and proc.stdout.strip() == "" and proc.stderr.strip() == "", proc.stderr
    # ExecStart starts through env (the signals held until the handlers are in): verify checks env; the
    # daemon it runs is checked here.
    words = unit_settings(work / "etc/systemd/system/uav-depth.service")["ExecStart"][0].split()
    daemon = work / next(w for w in words if not w.startswith("-") and w != "/usr/bin/env").lstrip("/")
    assert daemon == work / "opt/uav-depth/venv/bin/uav-depth" and os.access(daemon, os.X_OK)


def test_verify_would_catch_a_broken_unit(installed, tmp_path):
    root, _ = installed
    work = clone(root, tmp_path)
    shutil.copytree("/usr/lib/systemd/system", work / "usr/lib/systemd/system", symlinks=True)
    (work / "usr/bin/env").unlink()
    proc = subprocess.run(["systemd-analyze", "verify", f"--root={work}", "uav-depth.service"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and "/usr/bin/env is not executable" in proc.stderr


def test_unit_exposure_score(capsys):
    proc = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--threshold=20", str(UNIT)],
                          capture_output=True, text=True, timeout=60)
    m = re.search(r"Overall exposure level for uav-depth.service: ([0-9.]+)", proc.stdout)
    assert m, proc.stdout + proc.stderr
    with capsys.disabled():
        print(f"\nsystemd-analyze security exposure of deploy/uav-depth.service: {m.group(1)}")
    # --threshold=20: exit non-zero above exposure 2.0 (the scale is 0 safe .. 10 exposed).
    assert proc.returncode == 0 and float(m.group(1)) <= 2.0


def test_unit_lifecycle_settings_match_the_daemon_and_installer():
    s = unit_settings(UNIT)
    assert s["Type"] == ["notify"] and s["NotifyAccess"] == ["main"]
    assert float(s["WatchdogSec"][0]) > 0
    assert s["Restart"] == ["on-failure"]
    # One definition: the exit code the CLI uses for a bad config is the one that stops restarts.
    assert s["RestartPreventExitStatus"] == [str(EXIT_CONFIG)]
    assert s["ExecStart"] == [f"/usr/bin/env --block-signal=HUP,INT,TERM,USR1 {VENV}/bin/uav-depth run "
                              "--config /etc/uav-depth/config.yaml"]
    assert s["User"] == ["uav-depth"] and s["SupplementaryGroups"] == ["video dialout"]
    sysusers = (DEPLOY / "uav-depth.sysusers").read_text()
    assert re.search(r"^m uav-depth video$", sysusers, re.M) and re.search(r"^m uav-depth dialout$", sysusers, re.M)
    assert s["ProtectSystem"] == ["strict"] and "/var/lib/uav-depth" in s["ReadWritePaths"]
    for key in ("NoNewPrivileges", "ProtectHome", "PrivateTmp", "MemoryDenyWriteExecute"):
        assert s[key] == ["yes"], key


def test_install_lays_down_the_expected_files(installed):
    root, proc = installed
    expected = {
        # path: (mode, owner, group)
        "etc/sysusers.d/uav-depth.conf": (0o644, "root", "root"),
        "etc/systemd/system/uav-depth.service": (0o644, "root", "root"),
        "etc/udev/rules.d/80-uav-depth-oak.rules": (0o644, "root", "root"),
        "etc/uav-depth": (0o750, "root", "uav-depth"),
        "etc/uav-depth/config.yaml": (0o640, "root", "uav-depth"),
        "var/lib/uav-depth": (0o750, "uav-depth", "uav-depth"),
        "var/lib/uav-depth/logs": (0o750, "uav-depth", "uav-depth"),
        "opt/uav-depth/venv/bin/uav-depth": (0o755, "root", "root"),
        "opt/uav-depth/share/README.md": (0o644, "root", "root"),
        "opt/uav-depth/share/examples/zed-mini.yaml": (0o644, "root", "root"),
        "opt/uav-depth/share/examples/oak-d.yaml": (0o644, "root", "root"),
        "opt/uav-depth/share/examples/sitl.yaml": (0o644, "root", "root"),
    }
    for rel, (mode, owner, group) in expected.items():
        st = (root / rel).lstat()
        assert stat.S_IMODE(st.st_mode) == mode, f"{rel}: mode {oct(stat.S_IMODE(st.st_mode))}, want {oct(mode)}"
        if IS_ROOT:   # without privileges install.sh leaves ownership alone (and says so in --help)
            uid = 0 if owner == "root" else ids(root, "passwd", owner)
            gid = 0 if group == "root" else ids(root, "group", group)
            assert (st.st_uid, st.st_gid) == (uid, gid), f"{rel}: owned {st.st_uid}:{st.st_gid}, want {uid}:{gid}"
    assert (root / "etc/systemd/system/uav-depth.service").read_bytes() == UNIT.read_bytes()
    assert (root / "etc/uav-depth/config.yaml").read_bytes() == (DEPLOY / "examples/zed-mini.yaml").read_bytes()
    # The flight parameters, not the 0.6 s-per-frame manual baseline, once the installed package has
    # checked them; this test installs with --no-deps, where the package cannot run and says so.
    params = root / "var/lib/uav-depth/params.yaml"
    if params.exists():
        assert params.read_bytes() == (DEPLOY / "params-flight.yaml").read_bytes()
        assert stat.S_IMODE(params.stat().st_mode) == 0o640
    else:
        assert "not writing" in proc.stdout + proc.stderr and "does not accept it" in proc.stdout + proc.stderr
    link = root / "etc/systemd/system/multi-user.target.wants/uav-depth.service"
    assert os.readlink(link) == "/etc/systemd/system/uav-depth.service"
    # The user: a system account without a login shell, in exactly the groups the unit names.
    pw = next(line for line in (root / "etc/passwd").read_text().splitlines() if line.startswith("uav-depth:"))
    fields = pw.split(":")
    assert int(fields[2]) < 1000 and fields[5] == "/var/lib/uav-depth" and fields[6] == "/usr/sbin/nologin"
    member_of = {line.split(":")[0] for line in (root / "etc/group").read_text().splitlines()
                 if "uav-depth" in line.split(":")[3].split(",")}
    assert member_of == {"video", "dialout"}


def test_installed_venv_runs_from_its_final_path(installed):
    root, _ = installed
    script = root / VENV.lstrip("/") / "bin/uav-depth"
    # Under --root, pip wrote the staging path into shebangs; the target only has /opt/uav-depth/venv.
    assert script.read_text().splitlines()[0] == f"#!{VENV}/bin/python"
    for f in (root / VENV.lstrip("/") / "bin").iterdir():
        if f.is_file() and not f.is_symlink():
            assert str(root) not in f.read_text(errors="replace"), f"{f.name} still names the staging root"
    py = root / VENV.lstrip("/") / "bin/python"
    probe = ("import importlib.metadata as m; "
             "print(m.version('uav-depth')); "
             "print([e.value for e in m.entry_points(group='console_scripts') if e.name == 'uav-depth'])")
    out = subprocess.run([str(py), "-c", probe], capture_output=True, text=True, check=True, timeout=60).stdout
    assert out.split("\n")[:2] == ["0.1.0", "['uav_depth.cli.main:entry']"]


def test_second_install_keeps_the_config_and_changes_nothing_else(installed, wheel, tmp_path):
    root, _ = installed
    work = clone(root, tmp_path)
    cfg = work / "etc/uav-depth/config.yaml"
    cfg.write_text(cfg.read_text() + "# edited by the operator\n")
    (work / "var/lib/uav-depth/params.yaml").write_text("sgbm: {block_size: 7}\n")
    before = snapshot(work, skip_venv_lib=True)
    proc = install_into(work, wheel, "--camera", "sitl")
    assert "keeping existing" in proc.stdout and f"{work}/etc/uav-depth/config.yaml" in proc.stdout
    after = snapshot(work, skip_venv_lib=True)
    assert after == before
    assert cfg.read_text().endswith("# edited by the operator\n")


@pytest.mark.parametrize("text,message", [
    ("", "must set at least one section"),
    ("sgbm:\n  p1: 600\n  p2: 40000\n", "sgbm.p2 must be at most 32767"),
    ("sgbm:\n  p1: 600\n  p1: 900\n", "sgbm.p1 is given twice"),
], ids=["empty", "p2-over-16-bit-costs", "duplicate-key"])
def test_an_invalid_existing_params_file_is_kept_but_not_silently(installed, wheel, tmp_path, text, message):
    root, _ = installed
    work = clone(root, tmp_path)
    params = work / "var/lib/uav-depth/params.yaml"
    params.write_text(text)
    # Installed with --no-deps: give the installed venv this interpreter's dependencies, so that its
    # own `uav-depth params check` runs (on a drone pip installs them).
    site = next((work / VENV.lstrip("/") / "lib").glob("python3*/site-packages"))
    (site / "_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    cmd = ["bash", str(DEPLOY / "install.sh"), "--root", str(work), "--from", str(wheel), "--no-deps",
           "--python", sys.executable, "--camera", "sitl"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0, proc.stdout
    assert f"existing {params} is INVALID and was kept as it is" in proc.stdout and message in proc.stdout
    assert "the kept parameter file" in proc.stderr
    assert params.read_text() == text          # the operator's file is never replaced


def test_dry_run_changes_nothing(installed, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = sh(str(DEPLOY / "install.sh"), "--root", str(empty), "--dry-run", "--python", sys.executable)
    assert list(empty.iterdir()) == []
    for step in ("+ systemd-sysusers", f"-m venv {empty}{VENV}", f"+ systemctl --root={empty} enable uav-depth",
                 f"{empty}/etc/uav-depth/config.yaml"):
        assert step in proc.stdout, step
    root, _ = installed
    before = snapshot(root)
    for script in ("install.sh", "uninstall.sh"):
        sh(str(DEPLOY / script), "--root", str(root), "--dry-run", *(["--purge"] if script == "uninstall.sh" else []))
    assert snapshot(root) == before


@pytest.mark.parametrize("script", ["install.sh", "uninstall.sh"])
def test_not_root_is_refused_clearly(script):
    # As root the test drops to nobody (setpriv, or runuser); otherwise it already is not root.
    proc = sh(str(DEPLOY / script), check=False, user="nobody")
    assert proc.returncode == 77, proc.stderr      # sysexits EX_NOPERM
    assert f"{script}: must run as root" in proc.stderr and "--dry-run or --root DIR" in proc.stderr
    assert proc.stdout == ""
    # ... while a dry run is allowed and only prints.
    proc = sh(str(DEPLOY / script), "--dry-run", check=False, user="nobody")
    assert proc.returncode == 0, proc.stderr
    assert "dry run: nothing is changed" in proc.stdout


@pytest.mark.parametrize("args, message", [
    (["--camera", "gopro"], "--camera must be one of zed-mini, oak-d, sitl, but got 'gopro'"),
    (["--root", "/nonexistent/uav-depth-root"], "--root must be an existing directory"),
    (["--frobnicate"], "unknown argument '--frobnicate'"),
], ids=["camera", "root", "unknown"])
def test_bad_arguments_are_one_line(args, message):
    proc = sh(str(DEPLOY / "install.sh"), *args, "--dry-run", check=False)
    assert proc.returncode == 64 and message in proc.stderr and proc.stderr.count("\n") == 1


def test_uninstall_keeps_the_operators_work_unless_purged(installed, tmp_path):
    root, _ = installed
    work = clone(root, tmp_path)
    sh(str(DEPLOY / "uninstall.sh"), "--root", str(work))
    for gone in ("etc/systemd/system/uav-depth.service", "etc/systemd/system/multi-user.target.wants/uav-depth.service",
                 "opt/uav-depth", "etc/udev/rules.d/80-uav-depth-oak.rules"):
        assert not (work / gone).exists() and not (work / gone).is_symlink(), gone
    for kept in ("etc/uav-depth/config.yaml", "var/lib/uav-depth/logs", "etc/sysusers.d/uav-depth.conf"):
        assert (work / kept).exists(), kept
    again = sh(str(DEPLOY / "uninstall.sh"), "--root", str(work))    # idempotent
    assert "keeping" in again.stdout and "+ " not in again.stdout
    sh(str(DEPLOY / "uninstall.sh"), "--root", str(work), "--purge")
    for gone in ("etc/uav-depth", "var/lib/uav-depth", "etc/sysusers.d/uav-depth.conf"):
        assert not (work / gone).exists(), gone
    if IS_ROOT:
        assert not re.search(r"^uav-depth:", (work / "etc/passwd").read_text(), re.M)
        assert "uav-depth" not in (work / "etc/group").read_text()
