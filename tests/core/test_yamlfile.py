"""The one YAML loader: UTF-8 text only, no key given twice, every read failure one named error."""

import os

import pytest

from uav_depth.core.errors import ConfigError, FileFormatError
from uav_depth.core.fileio import read_text_file
from uav_depth.core.yamlfile import load_yaml_file, parse_yaml


@pytest.mark.parametrize("text,message", [
    ("a: 1\na: 2\n", r"^f\.yaml: a is given twice \(line 1 and line 2\); keep one, but got '2'$"),
    ("sgbm:\n  p1: 8\n  p2: 32\n  p1: 9\n", r"sgbm\.p1 is given twice \(line 2 and line 4\)"),
    ("source:\n  scene: {seed: 1, seed: 2}\n", r"source\.scene\.seed is given twice \(line 2 and line 2\)"),
    ("items:\n  - {k: 1, k: 2}\n", r"items\[0\]\.k is given twice"),
    ("mavlink:\n  url: x\nmavlink:\n  rate_hz: 5\n", r"mavlink is given twice \(line 1 and line 3\)"),
], ids=["top-level", "nested", "flow-mapping", "inside-a-list", "whole-section"])
def test_a_key_given_twice_is_an_error_naming_the_key_and_both_lines(text, message):
    with pytest.raises(ConfigError, match=message):
        parse_yaml(text, "f.yaml")


def test_distinct_keys_and_repeated_values_are_fine():
    assert parse_yaml("a: 1\nb: 1\nc: {a: 1}\n") == {"a": 1, "b": 1, "c": {"a": 1}}
    assert parse_yaml("") is None and parse_yaml("# only a comment\n") is None


@pytest.mark.parametrize("data,message", [
    (b"a: caf\xe9\n", r"not UTF-8 text \(byte 0xe9 at offset 6, line 1\)"),
    (b"a: 1\nb: \xff\xfe\n", r"not UTF-8 text \(byte 0xff at offset 8, line 2\)"),
    (b"\x7fELF\x02\x01\x01\x00", r"is a binary file, not text \(NUL byte at offset 7\)"),
    (b"a: [1, 2\n", r"thing is not valid YAML at line 2"),
], ids=["latin-1", "second-line", "binary", "syntax"])
def test_unreadable_text_is_one_file_format_error(tmp_path, data, message):
    path = tmp_path / "f.yaml"
    path.write_bytes(data)
    with pytest.raises(FileFormatError, match=message):
        load_yaml_file(path, "thing")


def test_missing_directory_and_unreadable_files_name_what_they_should_be(tmp_path):
    with pytest.raises(FileFormatError, match=r"nope\.yaml: thing not found"):
        read_text_file(tmp_path / "nope.yaml", "thing")
    with pytest.raises(FileFormatError, match=r"thing is a directory, not a file"):
        read_text_file(tmp_path, "thing")
    if os.geteuid() != 0:    # root reads a file whatever its mode
        locked = tmp_path / "locked.yaml"
        locked.write_text("a: 1\n")
        locked.chmod(0)
        with pytest.raises(FileFormatError, match=r"cannot read thing: permission denied for this user"):
            read_text_file(locked, "thing")


def _alias_bomb(levels: int) -> str:
    """The "billion laughs": each level lists the one before nine times (9**levels strings from ~40 bytes a line)."""
    lines = ['l0: &l0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"l{i}: &l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("text,message", [
    (_alias_bomb(5), r"uses a YAML anchor \('l0'\) at line 1; anchors and aliases are not accepted"),
    ("sgbm:\n  p1: 600\nwls:\n  lambda: *x\n", r"uses a YAML alias \('x'\) at line 4"),
    ("base: &b {p1: 600}\nsgbm:\n  <<: *b\n", r"uses a YAML anchor \('b'\) at line 1"),
], ids=["alias-bomb", "alias", "merge-key"])
def test_anchors_and_aliases_are_refused_where_the_parser_meets_the_first(text, message):
    with pytest.raises(FileFormatError, match=message):
        parse_yaml(text, "f.yaml", "parameter file")
    assert parse_yaml("a: '&x *y'\nb: '*z'\n") == {"a": "&x *y", "b": "*z"}   # the characters in a string are fine


def test_a_1kb_alias_bomb_is_refused_before_anything_is_built(tmp_path):
    bomb = tmp_path / "params.yaml"
    bomb.write_text(_alias_bomb(9))     # 9**9 strings once expanded
    assert len(bomb.read_bytes()) < 1024
    with pytest.raises(FileFormatError, match=r"params\.yaml: parameter file uses a YAML anchor \('l0'\) at line 1"):
        load_yaml_file(bomb, "parameter file")


def test_a_yaml_file_over_the_size_cap_is_refused_by_its_size(tmp_path):
    from uav_depth.core.yamlfile import MAX_YAML_BYTES

    big = tmp_path / "big.yaml"
    big.write_text("# padding\n" * (MAX_YAML_BYTES // 10) + "sgbm: {p1: 600}\n")
    with pytest.raises(FileFormatError, match=rf"big\.yaml: config is {big.stat().st_size} bytes, more than the "
                                              rf"64 KiB a config may have"):
        load_yaml_file(big, "config")
    ok = tmp_path / "ok.yaml"
    ok.write_text("# padding\n" * (MAX_YAML_BYTES // 10 - 2) + "sgbm: {p1: 600}\n")
    assert load_yaml_file(ok, "config") == {"sgbm": {"p1": 600}}


def test_a_fifo_or_a_device_is_refused_without_waiting_or_reading(tmp_path):
    fifo = tmp_path / "params.yaml"
    os.mkfifo(fifo)                     # opening it for reading would wait for a writer
    with pytest.raises(FileFormatError, match=r"parameter file is not a regular file \(a device, FIFO or socket\)"):
        load_yaml_file(fifo, "parameter file")
    zero = tmp_path / "zero.yaml"
    zero.symlink_to("/dev/zero")        # reading it would never end
    with pytest.raises(FileFormatError, match=r"zero\.yaml: config is not a regular file"):
        load_yaml_file(zero, "config")
