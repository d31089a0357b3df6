"""dome_calib.schema, the one way every input file is read: the one-line message (file, owner, field path, what was
expected, what was found), field paths through lists, objects and pydantic's own tags, the schema's own checks
naming their field, describe_schema (the documentation of a file), and the JSON, TOML and YAML readers."""
from __future__ import annotations

import json
from typing import Annotated, Literal

import numpy as np
import pytest
from pydantic import model_validator

from dome_calib.errors import CaptureError, DomeCalibError
from dome_calib.schema import (INT64_MAX, Field, FieldError, FileSchema, Finite, InputFileError, NonNegInt, OpenSchema,
                               PlainName, Unique, Vec3, describe_schema, field_path, parse_json, read_json, read_toml,
                               read_yaml, show, validate, words)


class Ltc(FileSchema):
    file: str
    vga_channel: NonNegInt = 0


class Camera(FileSchema):
    name: str
    t: Vec3
    kind: Literal["vga", "hd"] = "vga"


class Doc(FileSchema):
    """A made-up file with every shape the real schemas use."""

    seq: PlainName
    ltc: Ltc
    cameras: list[Camera] = []
    streams: dict[str, Ltc] = {}
    version: Finite | str | None = None
    tags: Unique(str) = []
    count: NonNegInt = Field(0, description="how many", **words("a count of things"))

    @model_validator(mode="after")
    def _ltc_not_in_streams(self) -> Doc:
        for name, ltc in self.streams.items():
            if ltc.file == self.ltc.file:
                raise FieldError(("streams", name, "file"), f"{ltc.file} is already the main LTC file")
        return self


GOOD = {"seq": "s1", "ltc": {"file": "ltc.wav", "vga_channel": 0},
        "cameras": [{"name": "01_01", "t": [1, 2, 3]}, {"name": "01_02", "t": [4, 5, 6.5]}],
        "streams": {"hd": {"file": "hd.wav"}}}


def _edit(path, value):
    doc = json.loads(json.dumps(GOOD))
    target = doc
    for key in path[:-1]:
        target = target[key]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return doc


def _line(doc) -> str:
    with pytest.raises(InputFileError) as err:
        parse_json("session.json", json.dumps(doc).encode(), Doc)
    message = str(err.value)
    assert "\n" not in message and message.startswith("session.json: ")
    return message.removeprefix("session.json: ")


@pytest.mark.parametrize("path, value, expected", [
    (("ltc", "vga_channel"), False, "ltc.vga_channel: expected an integer >= 0 and <= 2^63-1, got false"),
    (("ltc", "vga_channel"), -1, "ltc.vga_channel: expected an integer >= 0 and <= 2^63-1, got -1"),
    (("ltc", "vga_channel"), "0", 'ltc.vga_channel: expected an integer >= 0 and <= 2^63-1, got "0"'),
    (("ltc", "vga_channel"), 2**64, "ltc.vga_channel: expected an integer >= 0 and <= 2^63-1, got 18446744073709551616"),
    (("ltc", "file"), None, "ltc.file: expected a string, got null"),
    (("ltc", "file"), KeyError, "ltc.file: missing (expected a string)"),
    (("ltc", "vga_chanel"), 1, "ltc.vga_chanel: unknown field (known fields: file, vga_channel)"),
    (("cameras", 1, "t"), [1, 2], "camera 01_02: cameras[1].t: expected a list of 3 finite numbers, got [1, 2]"),
    (("cameras", 1, "t", 2), float("nan"), "camera 01_02: cameras[1].t[2]: expected a finite number, got NaN"),
    (("cameras", 0, "kind"), "kinect", 'camera 01_01: cameras[0].kind: expected "vga" or "hd", got "kinect"'),
    (("streams", "hd", "file"), "ltc.wav", "streams.hd.file: ltc.wav is already the main LTC file"),
    (("streams", "a b\n"), {"file": 3}, 'streams["a b\\n"].file: expected a string, got 3'),
    (("version",), [1], "version: expected a finite number or a string or null, got [1]"),
    (("tags",), ["x", "y", "x"], 'tags[2]: "x" is listed twice'),
    (("seq",), "../up", 'seq: expected a plain name (no \'/\', not \'.\' or \'..\', printable, at most 50 characters), '
                        'got "../up": it holds a path separator'),
    (("count",), "many", 'count: expected a count of things, got "many"'),
])
def test_one_line_names_the_field_path_what_was_expected_and_what_was_found(path, value, expected):
    assert _line(_edit(path, value)) == expected


def test_every_failure_is_counted_and_the_top_level_is_the_file():
    assert _line([1, 2]) == "the file: expected an object, got [1, 2]"
    assert _line({"seq": 1, "ltc": 2}) == "seq: expected a plain name (no '/'), got 1 (and 1 more)"


def test_files_that_are_no_json(tmp_path):
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputFileError, match=r"bin.json: not a UTF-8 text file$"):
        read_json(tmp_path / "bin.json", Doc)
    (tmp_path / "cut.json").write_text('{"seq": "s1", "ltc": {')
    with pytest.raises(InputFileError, match=r"cut.json: not valid JSON \(EOF while parsing"):
        read_json(tmp_path / "cut.json", Doc)
    (tmp_path / "deep.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputFileError, match=r"deep.json: not valid JSON \(recursion limit"):
        read_json(tmp_path / "deep.json", Doc)
    with pytest.raises(InputFileError, match=r"absent.json: file not found"):
        read_json(tmp_path / "absent.json", Doc)
    with pytest.raises(InputFileError, match=r": is a folder, expected a file"):
        read_json(tmp_path, Doc)


def test_the_error_class_is_the_callers_and_a_user_error():
    with pytest.raises(CaptureError) as err:
        parse_json("x.json", b"{}", Doc, error=CaptureError)
    assert isinstance(err.value, DomeCalibError) and str(err.value) == (
        "x.json: seq: missing (expected a plain name (no '/')) (and 1 more)")  # ltc is missing too
    assert issubclass(InputFileError, DomeCalibError)


def test_values_are_shown_as_in_the_file_cut_and_on_one_line():
    assert show(False) == "false" and show(None) == "null" and show("a\nb") == '"a\\nb"'
    assert show(float("inf")) == "Infinity" and show(float("nan")) == "NaN"
    assert len(show("x" * 1000)) == 40 and show("<script>") == '"<script>"'  # plain text: the page escapes it


def test_field_path():
    assert field_path(("ltc", "vga_channel")) == "ltc.vga_channel"
    assert field_path(("cameras", 3, "K", 0, 1)) == "cameras[3].K[0][1]"
    assert field_path((0, "x")) == "[0].x"
    assert field_path(("kinect", "color", "node one")) == 'kinect.color["node one"]'


def test_open_schemas_ignore_what_they_do_not_know_and_validate_checks_parsed_data():
    class Other(OpenSchema):
        a: int

    assert validate({"a": 1, "zzz": [1]}, Other, source="o.toml").a == 1
    with pytest.raises(InputFileError, match=r"^o.toml: a: expected an integer, got 1.5$"):
        validate({"a": 1.5}, Other, source="o.toml")


def test_describe_schema_walks_objects_lists_and_maps():
    rows = {path: (accepts, required, text) for path, accepts, required, text in describe_schema(Doc)}
    assert rows["seq"] == ("a plain name (no '/')", True, "")
    assert rows["ltc.vga_channel"] == ("an integer >= 0 and <= 2^63-1", False, "")
    assert rows["cameras[].t"] == ("a list of 3 finite numbers", True, "")
    assert rows["cameras[].kind"][0] == '"vga" or "hd"'
    assert rows["streams.<name>.file"][:2] == ("a string", True)
    assert rows["count"] == ("a count of things", False, "how many")
    assert list(rows)[:3] == ["seq", "ltc", "ltc.file"]


class Lens(FileSchema):
    name: str
    matrix: Annotated[list[list[Finite]], Field(min_length=3, max_length=3)]
    size: list[NonNegInt]


def test_toml_files_name_the_table_and_field(tmp_path):
    path = tmp_path / "calibration.toml"
    path.write_text('name = "cam_0"\nmatrix = [[1.0, 0, 2], [0, 1, 3], [0, 0, 1]]\nsize = [640, 480]\n')
    assert read_toml(path, Lens).size == [640, 480]
    path.write_text('name = "cam_0"\nmatrix = [[1.0, 0, 2], [0, 1, 3], [0, 0, "x"]]\nsize = [640, 480]\n')
    with pytest.raises(InputFileError, match=r'^\S+calibration.toml: matrix\[2\]\[2\]: expected a finite number, got "x"$'):
        read_toml(path, Lens)
    path.write_text("name = \n")
    with pytest.raises(InputFileError, match=r"calibration.toml: not valid TOML"):
        read_toml(path, Lens)


def test_yaml_files_read_with_opencv_matrices_as_lists(tmp_path):
    import cv2

    path = tmp_path / "intri.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("name", "cam_0")
    fs.write("matrix", np.array([[1.0, 0, 2], [0, 1, 3], [0, 0, 1]]))
    fs.write("size", 0)
    fs.release()
    with pytest.raises(InputFileError, match=r"intri.yml: size: expected a list of integers >= 0 and <= 2\^63-1, got 0"):
        read_yaml(path, Lens)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("name", "cam_0")
    fs.write("matrix", np.array([[1.0, 0, 2], [0, 1, 3], [0, 0, 1]]))
    fs.startWriteStruct("size", cv2.FileNode_SEQ)
    for v in (640, 480):
        fs.write("", v)
    fs.endWriteStruct()
    fs.release()
    lens = read_yaml(path, Lens)
    assert lens.matrix[1] == [0.0, 1.0, 3.0] and lens.size == [640, 480]
    (tmp_path / "not.yml").write_text("%YAML:1.0\n: [\n")
    with pytest.raises(InputFileError, match=r"not.yml: not a YAML file OpenCV can read"):
        read_yaml(tmp_path / "not.yml", Lens)


def test_int64_bound_is_the_numpy_one():
    assert INT64_MAX == np.iinfo(np.int64).max
