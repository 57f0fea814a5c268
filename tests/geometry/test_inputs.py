"""geometry.inputs: documents bounded before they are expanded, values checked, npz headers read before data."""

from __future__ import annotations

import io
import math
import time
import zipfile

import numpy as np
import pytest

from arproj.bench.inputs import npy_with_shape
from geometry import inputs
from geometry.errors import InputError


def test_an_alias_bomb_is_refused_from_its_few_lines_without_expanding_it() -> None:
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]  # 10^9 values
    start = time.perf_counter()
    with pytest.raises(InputError, match="more than 100,000 values"):
        inputs.parse_yaml("\n".join(lines), "bomb.yaml")
    assert time.perf_counter() - start < 1.0
    # a few aliases of a small anchor are fine (PyYAML's safe_dump writes them for shared lists)
    assert inputs.parse_yaml("a: &p [1, 2]\nb: *p\n", "ok.yaml") == {"a": [1, 2], "b": [1, 2]}


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, "{a: " * 100_000 + "1" + "}" * 100_000])
def test_deep_nesting_is_refused(text: str) -> None:
    with pytest.raises(InputError, match="nested deeper than 64"):
        inputs.parse_yaml(text, "deep.yaml")
    with pytest.raises(InputError, match="nested deeper than 64"):
        inputs.parse_json("[" * 100_000 + "]" * 100_000, "deep.json")


def test_numbers_too_long_or_not_finite_are_refused_by_name() -> None:
    with pytest.raises(InputError, match="more than 4,300 digits"):
        inputs.parse_yaml("x: " + "9" * 5000, "f.yaml")
    with pytest.raises(InputError, match="NaN is not a number JSON allows"):
        inputs.parse_json('{"x": NaN}', "f.json")
    assert math.isnan(inputs.parse_json('{"x": NaN}', "f.json", constants=True)["x"])
    with pytest.raises(InputError, match=r"f: k = <an integer of 401 digits>: must be a finite number"):
        inputs.number("f", "k", 10**400, 0, 1)
    for bad in (math.inf, math.nan, "1.5", True, None, [1]):
        with pytest.raises(InputError, match="f: k = "):
            inputs.number("f", "k", bad, 0, 1)
    with pytest.raises(InputError, match="must be between 0 and 1"):
        inputs.number("f", "k", -1, 0, 1)


@pytest.mark.parametrize("value", [[[1, True]], [[1, "2"]], [[1, None]], [[1, 2], [3]], [[1, 10**400]], "12",
                                   [[1, math.inf]]])
def test_float_array_takes_numbers_only(value: object) -> None:
    with pytest.raises(InputError, match="f: p = "):
        inputs.float_array("f", "p", value, (None, 2))


def test_binary_and_oversized_files_are_refused_before_parsing(tmp_path) -> None:
    binary = tmp_path / "x.yaml"
    binary.write_bytes(b"width_m: 1\n\x00\x01")
    with pytest.raises(InputError, match="binary data"):
        inputs.load_document(binary, "wall file")
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * (inputs.MAX_DOCUMENT_BYTES + 1))
    with pytest.raises(InputError, match="too large for a wall file"):
        inputs.load_document(big, "wall file")


def test_npz_headers_are_checked_before_the_data_are_read(tmp_path) -> None:
    path = tmp_path / "a.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("huge.npy", npy_with_shape((100_000, 100_000, 8)))
        z.writestr("obj.npy", npy_with_shape((2,), "|O"))
        buffer = io.BytesIO()
        np.lib.format.write_array(buffer, np.array([1.0, np.nan]))
        z.writestr("nan.npy", buffer.getvalue())
    with inputs.NpzFile(path, "test file") as npz:
        with pytest.raises(InputError, match="more than"):
            npz.array("huge")
        with pytest.raises(InputError, match="holds object values"):
            npz.array("obj")
        with pytest.raises(InputError, match="not finite"):
            npz.floats("nan", (2,))
        assert np.isnan(npz.floats("nan", (None,), finite=False)[1])
        with pytest.raises(InputError, match="missing"):
            npz.array("other")
    path.write_bytes(path.read_bytes()[:-30])
    with pytest.raises(InputError, match=r"not an \.npz test file"):
        inputs.NpzFile(path, "test file")


@pytest.mark.parametrize("broken", [b"(3, 75, 88l, }", b"(3, 75, 88}, }", b"(3, 75 88), }"])
def test_a_damaged_npy_header_is_refused_by_name(tmp_path, broken: bytes) -> None:
    # one flipped byte in a shape makes numpy's header parser raise SyntaxError or tokenize's TokenError
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.zeros((3, 75, 88), np.uint8))
    data = buffer.getvalue().replace(b"(3, 75, 88), }", broken)
    path = tmp_path / "coverage.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("covered.npy", data)
    with inputs.NpzFile(path, "coverage layer") as npz, pytest.raises(InputError, match="'covered' cannot be read"):
        npz.array("covered", kinds="ub")
