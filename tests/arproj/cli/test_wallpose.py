"""`arproj wallpose`: unclear input is refused with a line that says what to give."""

import pytest

from arproj.cli.wallpose import _head_angles, run_wallpose
from geometry.errors import InputError


def test_cli_refuses_unclear_input(tmp_path) -> None:
    with pytest.raises(InputError, match="--sim"):
        run_wallpose(False, 2.0, 0.0, 0, None, None, None, None, None, tmp_path / "p.png")
    with pytest.raises(InputError, match="three numbers"):
        _head_angles("0,a,1")
    with pytest.raises(InputError, match="pan, tilt and roll"):
        _head_angles("0,1")
