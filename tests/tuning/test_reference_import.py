"""uav-depth reference import: every format, the SGBM scale check, sizes, resume, provenance, the CLI."""

from __future__ import annotations

import functools
import json
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.core.session import Session, SessionWriter, iter_frames, write_pfm
from uav_depth.core.calibration import Calibration
from uav_depth.tuning.reference import read_provenance, summarize_references
from uav_depth.tuning.reference.check import check_reference_scale, nice_scale
from uav_depth.tuning.reference.importer import ImportConfig, import_references
from uav_depth.tuning.reference.provenance import sha256_file


@functools.lru_cache(maxsize=None)
def _source_session(tmp_root: str) -> str:
    cfg = SceneConfig(width=320, height=240, focal_px=200.0, branch_radius_m=0.04)
    write_session(f"{tmp_root}/src", 3, seed=5, base=cfg)
    return f"{tmp_root}/src"


@pytest.fixture
def session(tmp_path_factory, tmp_path):
    """A 3-frame 320x240 synthetic session whose references were moved away; returns (path, truths)."""
    src = _source_session(str(tmp_path_factory.getbasetemp()))
    dst = tmp_path / "s"
    shutil.copytree(src, dst)
    truths = {}
    for f in iter_frames(dst):
        truths[f.frame_id] = f.load_reference()
        f.ref_path.unlink()
        (f.session.frames_dir / f"{f.frame_id}_ref.json").unlink()
    return dst, truths


def _write_refs(directory, truths, fmt, factor=1.0, name="{id}"):
    directory.mkdir(parents=True, exist_ok=True)
    for fid, ref in truths.items():
        stem = directory / name.format(id=fid, index=int(fid))
        v = ref * factor
        if fmt == "npy":
            np.save(f"{stem}.npy", v)
        elif fmt == "pfm":
            write_pfm(f"{stem}.pfm", np.where(np.isfinite(v), v, np.inf))
        elif fmt == "kitti-png":
            cv2.imwrite(f"{stem}.png", np.where(np.isfinite(v), np.round(v * 256), 0).astype(np.uint16))
        else:
            cv2.imwrite(f"{stem}.png", np.where(np.isfinite(v), np.round(v), 0).clip(0, 255).astype(np.uint8))


# (format, factor the file stores, --scale to give, tolerance of the stored quantisation in px)
CASES = [("npy", 1.0, None, 0.0), ("pfm", 1.0, None, 0.0), ("kitti-png", 1.0, None, 0.5 / 256),
         ("middlebury-png", 4.0, 4.0, 0.5 / 4)]


@pytest.mark.parametrize("fmt,factor,scale,tol", CASES, ids=[c[0] for c in CASES])
def test_import_each_format(session, tmp_path, fmt, factor, scale, tol):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, fmt, factor)
    res = import_references(path, ImportConfig(tmp_path / "refs", format=fmt, scale=scale))
    assert res.written == ("s/000000", "s/000001", "s/000002") and res.check.ok is True
    for f in iter_frames(path):
        got = f.load_reference()
        want = truths[f.frame_id]
        assert f.ref_path.name == f"{f.frame_id}_ref.npy" and got.dtype == np.float32
        both = np.isfinite(want) & np.isfinite(got)
        assert both.mean() > 0.95
        assert np.abs(got[both] - want[both]).max() <= tol + 1e-6
        prov = read_provenance(f)
        assert prov["kind"] == "import" and prov["format"] == fmt
        assert prov["scale"] == (scale or {"kitti-png": 256.0}.get(fmt, 1.0))
        assert prov["source_sha256"] == sha256_file(prov["source"]) and 0.67 < prov["check"]["ratio"] < 1.5


@pytest.mark.parametrize("fmt,factor,scale,suggest", [
    ("middlebury-png", 4.0, None, "try --scale 4"),        # Middlebury's x4 PNG read as px
    ("middlebury-png", 8.0, 4.0, "try --scale 8"),         # x8 map with a x4 scale
    ("npy", 0.5, None, "try --scale 0.5"),                 # a half-resolution network's px
], ids=["x4-as-1", "x8-as-4", "half"])
def test_wrong_scale_is_flagged_and_nothing_written(session, tmp_path, fmt, factor, scale, suggest):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, fmt, factor)
    with pytest.raises(ConfigError, match="--scale must make the reference agree with SGBM") as err:
        import_references(path, ImportConfig(tmp_path / "refs", format=fmt, scale=scale))
    assert suggest in str(err.value)
    assert all(f.ref_path is None for f in iter_frames(path))


def test_check_can_be_skipped(session, tmp_path):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "middlebury-png", 4.0)
    res = import_references(path, ImportConfig(tmp_path / "refs", format="middlebury-png", check=False))
    assert len(res.written) == 3 and res.check is None
    assert read_provenance(next(iter_frames(path)))["check"] is None


@pytest.mark.parametrize("factor,ok", [(1.0, True), (4.0, False), (1 / 256, False)], ids=["right", "x4", "x1/256"])
def test_scale_check_on_the_motorcycle(motorcycle, factor, ok):
    left, right, gt = motorcycle
    check = check_reference_scale([("moto", left, right, gt * factor)])
    assert check.ok is ok
    assert check.ratio == pytest.approx(factor, rel=0.05)
    if not ok:
        assert check.suggested_scale == pytest.approx(factor)


def test_scale_check_negative_reference_flagged(small_frame):
    _, frame = small_frame
    check = check_reference_scale([("f", frame.left, frame.right, -frame.disparity)])
    assert check.ok is False and "negative" in check.reason


def test_nice_scale():
    assert nice_scale(3.9) == 4 and nice_scale(255.0) == 256 and nice_scale(0.26) == 0.25 and nice_scale(6.5) == 6.5


def test_size_mismatch_is_clear(session, tmp_path):
    path, truths = session
    small = {k: cv2.resize(v, (160, 120), interpolation=cv2.INTER_NEAREST) for k, v in truths.items()}
    _write_refs(tmp_path / "refs", small, "npy")
    with pytest.raises(FileFormatError, match=r"reference is 160x120 but frame s/000000 is 320x240"):
        import_references(path, ImportConfig(tmp_path / "refs"))


def test_8bit_png_as_kitti_is_clear(session, tmp_path):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "middlebury-png", 4.0)
    with pytest.raises(FileFormatError, match="KITTI disparity PNGs are 16-bit.*--format middlebury-png"):
        import_references(path, ImportConfig(tmp_path / "refs", format="kitti-png"))


@pytest.mark.parametrize("kwargs,match", [
    ({"format": "tiff"}, "--format must be one of npy, pfm, kitti-png, middlebury-png, but got 'tiff'"),
    ({"pattern": "{id}.png"}, "--format must be given for .png files"),
    ({"format": "npy", "scale": 0.0}, "--scale must be a positive number"),
    ({"format": "npy", "pattern": "{frame}.npy"}, "--pattern may only use the fields"),
], ids=["unknown-format", "ambiguous-png", "zero-scale", "bad-field"])
def test_bad_options(session, tmp_path, kwargs, match):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "npy")
    with pytest.raises(ConfigError, match=match):
        import_references(path, ImportConfig(tmp_path / "refs", **kwargs))


def test_pattern_index_and_missing_files(session, tmp_path):
    path, truths = session
    del truths["000001"]
    _write_refs(tmp_path / "refs", truths, "npy", name="disp_{index:04d}")
    res = import_references(path, ImportConfig(tmp_path / "refs", pattern="disp_{index:04d}.npy"))
    assert res.written == ("s/000000", "s/000002") and res.missing == ("s/000001",)


def test_no_matching_file_is_clear(session, tmp_path):
    path, _ = session
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileFormatError, match="no reference file matches a frame"):
        import_references(path, ImportConfig(tmp_path / "empty", format="npy"))


def test_several_sessions_need_session_in_pattern(session, tmp_path):
    path, truths = session
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copytree(path, logs / "a")
    shutil.copytree(path, logs / "b")
    for name in ("a", "b"):
        _write_refs(tmp_path / "refs" / name, truths, "npy")
    with pytest.raises(ConfigError, match=r"--pattern must contain \{session\}"):
        import_references(logs, ImportConfig(tmp_path / "refs", format="npy"))
    res = import_references(logs, ImportConfig(tmp_path / "refs", pattern="{session}/{id}.npy"))
    assert len(res.written) == 6


def test_resume_skips_existing_and_replace_by_kind(session, tmp_path):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "npy")
    first = next(iter_frames(path))
    # A device reference on frame 0, as the OAK-D source logs it.
    writer = SessionWriter(path, Calibration(200.0, 0.063, 320, 240))
    left, right = first.load_pair()
    writer.write(0, left, right, reference=truths["000000"] * 0 + 5.0,
                 reference_source={"kind": "device", "device": "oak-d", "note": "stereo depth"})
    assert read_provenance(first)["kind"] == "device"

    res = import_references(path, ImportConfig(tmp_path / "refs"))
    assert res.skipped == ("s/000000",) and res.written == ("s/000001", "s/000002")
    stamp = {f.key: f.ref_path.stat().st_mtime_ns for f in iter_frames(path)}
    again = import_references(path, ImportConfig(tmp_path / "refs"))
    assert again.written == () and len(again.skipped) == 3
    assert stamp == {f.key: f.ref_path.stat().st_mtime_ns for f in iter_frames(path)}

    res = import_references(path, ImportConfig(tmp_path / "refs", replace_kinds=("device",)))
    assert res.written == ("s/000000",)
    assert read_provenance(first)["kind"] == "import"
    res = import_references(path, ImportConfig(tmp_path / "refs", overwrite=True))
    assert len(res.written) == 3


def test_summary_for_reports(session, tmp_path):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "npy")
    import_references(path, ImportConfig(tmp_path / "refs"))
    frames = Session(path).frames()
    (path / "frames" / "000001_ref.json").unlink()          # a reference nobody described
    frames[2].ref_path.unlink()                              # and a frame without one
    s = summarize_references(frames)
    assert s["frames"] == 3 and s["by_kind"] == {"import": 1, "unknown": 1, "none": 1}
    assert {src["kind"] for src in s["sources"]} == {"import", "unknown", "none"}


def cli(*args):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def test_cli_import_flags_then_imports_then_evaluates(session, tmp_path):
    path, truths = session
    _write_refs(tmp_path / "refs", truths, "middlebury-png", 4.0)
    bad = cli("reference", "import", path, "--from", tmp_path / "refs", "--format", "middlebury-png")
    assert bad.returncode == 78 and bad.stderr.count("\n") == 1 and "try --scale 4" in bad.stderr
    ok = cli("reference", "import", path, "--from", tmp_path / "refs", "--format", "middlebury-png", "--scale", "4")
    assert ok.returncode == 0, ok.stderr
    assert "imported 3 references" in ok.stdout and "scale check ok" in ok.stdout
    show = json.loads(cli("reference", "show", path, "--json").stdout)
    assert show["by_kind"] == {"import": 3} and show["sources"][0]["scale"] == 4.0
    ev = json.loads(cli("evaluate", path, "--json").stdout)
    assert len(ev["frames"]) == 3 and ev["mean"]["density"] > 0.3 and ev["convention"] == "bench"


def test_show_names_device_references_as_lower_quality(session, tmp_path):
    path, truths = session
    f0 = next(iter_frames(path))
    left, right = f0.load_pair()
    SessionWriter(path, Calibration(200.0, 0.063, 320, 240)).write(
        0, left, right, reference=truths["000000"],
        reference_source={"kind": "device", "device": "oak", "note": "OAK StereoDepth depth"})
    out = cli("reference", "show", path, "--frames")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0] == "3 frames: 1 device, 2 none"
    assert "s/000000" in lines[-3] and "device oak (camera depth: lower quality than a network)" in lines[-3]
    assert lines[-1].startswith("s/000002") and "none (only the reference-free selfsup metric applies)" in lines[-1]
