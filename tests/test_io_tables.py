"""io.read_table: TOML/JSON configuration files, errors naming the file."""

import pytest

from seed2gs_inverse.errors import FormatError
from seed2gs_inverse.io.tables import read_table


def test_reads_toml_and_json(tmp_path):
    (tmp_path / "a.toml").write_text('[sam2]\nencoder = "e.onnx"\nk = 3\n')
    (tmp_path / "a.json").write_text('{"sam2": {"encoder": "e.onnx", "k": 3}}')
    want = {"sam2": {"encoder": "e.onnx", "k": 3}}
    assert read_table(tmp_path / "a.toml") == want == read_table(tmp_path / "a.json")


@pytest.mark.parametrize("name,text,match", [
    ("bad.json", "{oops", "not valid JSON"),
    ("bad.toml", "[sam2\n", "not valid TOML"),
    ("huge.json", '{"n": ' + "9" * 5000 + "}", "not valid JSON"),
    ("deep.json", "[" * 100_000 + "]" * 100_000, "nested too deeply"),
    ("list.json", "[1, 2]", "table at the top level"),
    ("binary.toml", b"\xff\xfe\x00", "not valid TOML"),
])
def test_bad_files_name_the_file(tmp_path, name, text, match):
    p = tmp_path / name
    p.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(FormatError, match=match) as info:
        read_table(p, "jobs file")
    assert str(p) in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError) as info:
        read_table(tmp_path / "nope.toml", "jobs file")
    assert info.value.filename == str(tmp_path / "nope.toml")
