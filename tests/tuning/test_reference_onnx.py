"""uav-depth reference onnx: small ONNX graphs built here, run for real through onnxruntime.

The graphs have a stereo network's signature (left and right [1,3,H,W] float32 in,
disparity out) and compute something known: a constant disparity, so the
rescaling to the frame's width can be checked exactly, or the left image itself,
so padding and cropping can be checked pixel for pixel.
"""

from __future__ import annotations

import functools
import json
import shutil
import subprocess
import sys

import numpy as np
import onnx
import onnxruntime
import pytest
from onnx import TensorProto, helper

from uav_depth.core.calibration import Calibration
from uav_depth.core.errors import ConfigError, FileFormatError, FrameError
from uav_depth.sim.scene import SceneConfig, write_session
from uav_depth.core.session import SessionWriter, iter_frames
from uav_depth.tuning.reference import read_provenance
from uav_depth.tuning.reference.network import OnnxConfig, StereoNetwork, parse_size, run_onnx_references
from uav_depth.tuning.reference.provenance import sha256_file

F = TensorProto.FLOAT


def _save(path, nodes, inputs, outputs, inits=()):
    graph = helper.make_graph(nodes, "stereo", [helper.make_tensor_value_info(n, t, s) for n, t, s in inputs],
                              [helper.make_tensor_value_info(n, t, s) for n, t, s in outputs],
                              initializer=list(inits))
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8   # old enough for any onnxruntime >= 1.14
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def _scalar(name, value):
    return helper.make_tensor(name, F, [], [float(value)])


def const_model(path, value, size=None, out="nchw", names=("left", "right"), stacked=False):
    """Disparity ``value`` everywhere (computed from the input so onnxruntime cannot fold it away)."""
    h, w = ("H", "W") if size is None else (size[1], size[0])
    if stacked:
        inputs = [("pair", F, [1, 6, h, w])]
        src = "pair"
    else:
        inputs = [(names[0], F, [1, 3, h, w]), (names[1], F, [1, 3, h, w])]
        src = names[0]
    nodes = [helper.make_node("ReduceMean", [src], ["m"], axes=[1], keepdims=1),
             helper.make_node("Mul", ["m", "zero"], ["z"]),
             helper.make_node("Add", ["z", "c"], ["d"])]
    inits = [_scalar("zero", 0.0), _scalar("c", value)]
    if out == "nchw":
        outputs = [("d", F, [1, 1, h, w])]
    elif out == "nhw":
        nodes.append(helper.make_node("Squeeze", ["d", "ax"], ["d3"]))
        inits.append(helper.make_tensor("ax", TensorProto.INT64, [1], [1]))
        outputs = [("d3", F, [1, h, w])]
    elif out == "flow":
        nodes.append(helper.make_node("Concat", ["d", "z"], ["flow"], axis=1))
        outputs = [("flow", F, [1, 2, h, w])]
    elif out == "half":
        nodes.append(helper.make_node("AveragePool", ["d"], ["dh"], kernel_shape=[2, 2], strides=[2, 2]))
        outputs = [("dh", F, [1, 1, None, None])]
    return _save(path, nodes, inputs, outputs, inits)


def image_model(path, names=("left", "right"), read="left"):
    """Disparity = the channel mean of input ``read`` (free H, W): the frame's grey values come back."""
    inputs = [(names[0], F, [1, 3, "H", "W"]), (names[1], F, [1, 3, "H", "W"])]
    nodes = [helper.make_node("ReduceMean", [read], ["d"], axes=[1], keepdims=1)]
    return _save(path, nodes, inputs, [("d", F, [1, 1, "H", "W"])])


@functools.lru_cache(maxsize=None)
def _source_session(root: str) -> str:
    write_session(f"{root}/src", 3, seed=9, base=SceneConfig(width=320, height=240, focal_px=200.0))
    return f"{root}/src"


@pytest.fixture
def session(tmp_path_factory, tmp_path):
    """A 3-frame 320x240 grey session without references."""
    dst = tmp_path / "s"
    shutil.copytree(_source_session(str(tmp_path_factory.getbasetemp())), dst)
    for f in iter_frames(dst):
        f.ref_path.unlink()
        (f.session.frames_dir / f"{f.frame_id}_ref.json").unlink()
    return dst


def _refs(path):
    return {f.frame_id: f.load_reference() for f in iter_frames(path)}


# (model size, fit, expected factor frame px / model px) for a 320x240 frame
GEOMETRIES = [
    ((160, 120), None, 2.0),              # half size: letterbox = exact x2
    ((200, 100), None, 320 / 133),        # other aspect: 133x100 image + 67 px replicate padding
    ((160, 160), "stretch", 2.0),         # stretch: x-scale 320/160
    ((640, 480), None, 0.5),              # a larger model input: upscaled, disparity halves back
    (None, None, 1.0),                    # free size: padded to 320x256, no scaling
]


@pytest.mark.parametrize("size,fit,factor", GEOMETRIES, ids=["160x120", "200x100", "stretch", "640x480", "free"])
def test_constant_disparity_rescaled_to_frame_width(session, tmp_path, size, fit, factor):
    model = const_model(tmp_path / "m.onnx", 7.0, size)
    res = run_onnx_references(session, OnnxConfig(model, fit=fit))
    assert len(res.written) == 3
    for d in _refs(session).values():
        assert d.shape == (240, 320)
        np.testing.assert_allclose(d, 7.0 * factor, rtol=1e-6)


@pytest.mark.parametrize("pad_multiple", [32, 48, 7])
def test_padding_is_cropped_back_exactly(session, tmp_path, pad_multiple):
    model = image_model(tmp_path / "m.onnx")
    run_onnx_references(session, OnnxConfig(model, pad_multiple=pad_multiple))
    for f in iter_frames(session):
        left, _ = f.load_pair()
        assert left.ndim == 2   # grey frames: all three model channels carry the same value
        np.testing.assert_array_equal(f.load_reference(), left.astype(np.float32))
        prov = read_provenance(f)
        w, h = prov["input_size"]
        assert w % pad_multiple == 0 and h % pad_multiple == 0 and prov["fit"] == "pad"


def test_inputs_named_right_then_left_are_fed_by_name(session, tmp_path):
    model = image_model(tmp_path / "m.onnx", names=("right_image", "left_image"), read="left_image")
    run_onnx_references(session, OnnxConfig(model))
    for f in iter_frames(session):
        left, right = f.load_pair()
        assert not np.array_equal(left, right)
        np.testing.assert_array_equal(f.load_reference(), left.astype(np.float32))


@pytest.mark.parametrize("out", ["nhw", "flow"])
def test_other_output_layouts(session, tmp_path, out):
    run_onnx_references(session, OnnxConfig(const_model(tmp_path / "m.onnx", 3.0, (160, 120), out=out)))
    for d in _refs(session).values():
        np.testing.assert_allclose(d, 6.0, rtol=1e-6)


def test_stacked_single_input(session, tmp_path):
    run_onnx_references(session, OnnxConfig(const_model(tmp_path / "m.onnx", 4.0, (160, 120), stacked=True)))
    for d in _refs(session).values():
        np.testing.assert_allclose(d, 8.0, rtol=1e-6)


@pytest.mark.parametrize("sign,expected,negated", [("auto", 10.0, True), ("negative", 10.0, True),
                                                   ("positive", -10.0, False)])
def test_flow_style_negative_output(session, tmp_path, sign, expected, negated):
    run_onnx_references(session, OnnxConfig(const_model(tmp_path / "m.onnx", -5.0, (160, 120)), sign=sign))
    for f in iter_frames(session):
        np.testing.assert_allclose(f.load_reference(), expected, rtol=1e-6)
        assert read_provenance(f)["negated"] is negated


def test_provenance_records_model_and_hash(session, tmp_path):
    model = const_model(tmp_path / "m.onnx", 7.0, (160, 120))
    run_onnx_references(session, OnnxConfig(model, normalize="unit"))
    prov = read_provenance(next(iter_frames(session)))
    assert prov["kind"] == "onnx" and prov["model"] == str(model.resolve())
    assert prov["model_sha256"] == sha256_file(model) and len(prov["model_sha256"]) == 64
    assert prov["provider"] == "CPUExecutionProvider" and prov["onnxruntime"] == onnxruntime.__version__
    assert prov["input_size"] == [160, 120] and prov["scaled_size"] == [160, 120] and prov["normalize"] == "unit"


def test_resume_skips_existing_references(session, tmp_path):
    model = const_model(tmp_path / "m.onnx", 7.0, (160, 120))
    seen = []

    def progress(it, total):
        seen.append(total)
        return it

    first = run_onnx_references(session, OnnxConfig(model), progress=progress)
    assert len(first.written) == 3 and seen == [3]
    frames = list(iter_frames(session))
    stamps = {f.key: f.ref_path.stat().st_mtime_ns for f in frames}
    frames[1].ref_path.unlink()    # as if the run had been killed before frame 1 finished
    again = run_onnx_references(session, OnnxConfig(model), progress=progress)
    assert again.written == ("s/000001",) and again.skipped == ("s/000000", "s/000002") and seen[-1] == 1
    for f in (frames[0], frames[2]):
        assert f.ref_path.stat().st_mtime_ns == stamps[f.key]
    assert len(run_onnx_references(session, OnnxConfig(model, overwrite=True)).written) == 3


def test_device_references_kept_unless_replaced(session, tmp_path):
    f0 = next(iter_frames(session))
    left, right = f0.load_pair()
    SessionWriter(session, Calibration(200.0, 0.063, 320, 240)).write(
        0, left, right, reference=np.full(left.shape[:2], 9.0, np.float32),
        reference_source={"kind": "device", "device": "oak-d"})
    model = const_model(tmp_path / "m.onnx", 7.0, (160, 120))
    res = run_onnx_references(session, OnnxConfig(model))
    assert res.skipped == ("s/000000",) and read_provenance(f0)["kind"] == "device"
    res = run_onnx_references(session, OnnxConfig(model, replace_kinds=("device",)))
    assert res.written == ("s/000000",) and read_provenance(f0)["kind"] == "onnx"


def _three_inputs(path):
    ins = [(n, F, [1, 3, 8, 8]) for n in ("a", "b", "c")]
    return _save(path, [helper.make_node("ReduceMean", ["a"], ["d"], axes=[1], keepdims=1)], ins,
                 [("d", F, [1, 1, 8, 8])])


def _rank3_inputs(path):
    ins = [("left", F, [1, 8, 8]), ("right", F, [1, 8, 8])]
    return _save(path, [helper.make_node("Identity", ["left"], ["d"])], ins, [("d", F, [1, 8, 8])])


def _four_channels(path):
    ins = [("left", F, [1, 4, 8, 8]), ("right", F, [1, 4, 8, 8])]
    return _save(path, [helper.make_node("ReduceMean", ["left"], ["d"], axes=[1], keepdims=1)], ins,
                 [("d", F, [1, 1, 8, 8])])


def _rank2_output(path):
    ins = [("left", F, [1, 3, 8, 8]), ("right", F, [1, 3, 8, 8])]
    nodes = [helper.make_node("ReduceMean", ["left"], ["d"], axes=[0, 1], keepdims=0)]
    return _save(path, nodes, ins, [("d", F, [8, 8])])


def _int_inputs(path):
    ins = [("left", TensorProto.INT64, [1, 3, 8, 8]), ("right", TensorProto.INT64, [1, 3, 8, 8])]
    nodes = [helper.make_node("Cast", ["left"], ["lf"], to=F),
             helper.make_node("ReduceMean", ["lf"], ["d"], axes=[1], keepdims=1)]
    return _save(path, nodes, ins, [("d", F, [1, 1, 8, 8])])


BAD_MODELS = [
    (_three_inputs, "it has 3 inputs, expected 2 (left, right) or 1 stacked"),
    (_rank3_inputs, "input 'left' has rank 3, expected rank 4"),
    (_four_channels, "input 'left' has 4 channels, expected 3"),
    (_rank2_output, "no output looks like a disparity map"),
    (_int_inputs, "input 'left' is tensor(int64), expected float32"),
]


@pytest.mark.parametrize("build,why", BAD_MODELS, ids=[b[0].__name__.strip("_") for b in BAD_MODELS])
def test_bad_model_rejected_clearly(tmp_path, build, why):
    model = build(tmp_path / "bad.onnx")
    with pytest.raises(ConfigError) as err:
        StereoNetwork(OnnxConfig(model))
    msg = str(err.value)
    assert msg.startswith("--model must be a stereo network: inputs left and right [1,3,H,W]")
    assert why in msg and str(model) in msg and "\n" not in msg


def test_not_an_onnx_file(tmp_path):
    (tmp_path / "x.onnx").write_bytes(b"this is not a protobuf")
    with pytest.raises(FileFormatError, match="onnxruntime cannot load this model"):
        StereoNetwork(OnnxConfig(tmp_path / "x.onnx"))
    with pytest.raises(FileFormatError, match="model file not found"):
        OnnxConfig(tmp_path / "missing.onnx")


def test_input_size_must_match_fixed_model(tmp_path):
    model = const_model(tmp_path / "m.onnx", 1.0, (160, 120))
    with pytest.raises(ConfigError, match="--input-size must match the model's fixed input size 160x120, but got "
                                          "'320x240'"):
        StereoNetwork(OnnxConfig(model, input_size=(320, 240)))
    with pytest.raises(ConfigError, match="--input-size must be WxH"):
        parse_size("320*240")


def test_low_resolution_output_is_clear(session, tmp_path):
    with pytest.raises(FrameError, match="expected a full-resolution disparity"):
        run_onnx_references(session, OnnxConfig(const_model(tmp_path / "m.onnx", 1.0, (160, 120), out="half")))
    assert all(f.ref_path is None for f in iter_frames(session))


def test_cuda_provider_available_or_clear(tmp_path):
    model = const_model(tmp_path / "m.onnx", 1.0, (160, 120))
    if "CUDAExecutionProvider" in onnxruntime.get_available_providers():
        assert StereoNetwork(OnnxConfig(model, provider="cuda")).provider == "CUDAExecutionProvider"
    else:
        with pytest.raises(ConfigError, match="cuda needs the onnxruntime-gpu package"):
            StereoNetwork(OnnxConfig(model, provider="cuda"))


def cli(*args):
    return subprocess.run([sys.executable, "-m", "uav_depth.cli.main", *map(str, args)], capture_output=True,
                          text=True, timeout=300)


def test_cli_end_to_end(session, tmp_path):
    model = const_model(tmp_path / "m.onnx", 7.0, (160, 120))
    run = cli("reference", "onnx", session, "--model", model)
    assert run.returncode == 0, run.stderr
    assert "wrote 3 references" in run.stdout and "inputs left, right" in run.stdout
    again = cli("reference", "onnx", session, "--model", model)
    assert "wrote 0 references; skipped 3" in again.stdout
    show = json.loads(cli("reference", "show", session, "--json").stdout)
    assert show["by_kind"] == {"onnx": 3} and show["sources"][0]["model_sha256"] == sha256_file(model)
    ev = json.loads(cli("evaluate", session, "--json").stdout)
    assert len(ev["frames"]) == 3
    bad = cli("reference", "onnx", session, "--model", _three_inputs(tmp_path / "bad.onnx"), "--overwrite")
    assert bad.returncode == 78 and "it has 3 inputs" in bad.stderr and bad.stderr.count("\n") == 1
