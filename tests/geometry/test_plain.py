"""numpy values as plain Python for the JSON and YAML files (rig files, state files, benchmark results)."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from geometry.plain import plain


def test_numpy_inside_dicts_lists_and_tuples_becomes_plain_python() -> None:
    value = {"rms": np.float32(0.25), 3: [np.int64(7), (np.bool_(True), np.arange(3))], "name": "left", "x": None}
    out = plain(value)
    assert out == {"rms": 0.25, "3": [7, [True, [0, 1, 2]]], "name": "left", "x": None}
    assert type(out["rms"]) is float and type(out["3"][0]) is int and type(out["3"][1][0]) is bool
    assert yaml.safe_load(yaml.safe_dump(out)) == out  # safe YAML takes it as it is


def test_as_the_json_default_it_writes_numpy_and_refuses_anything_else() -> None:
    text = json.dumps({"a": np.int32(4), "b": np.eye(2)}, default=plain)
    assert json.loads(text) == {"a": 4, "b": [[1.0, 0.0], [0.0, 1.0]]}
    with pytest.raises(TypeError, match="PosixPath"):
        json.dumps({"path": Path("/tmp")}, default=plain)  # not written as another type (a string)
