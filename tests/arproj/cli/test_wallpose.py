"""`arproj wallpose`: unclear input is refused with a line that says what to give."""

import pytest

from arproj.run.wallpose import WallposeSettings, parse_head_angles, run_wallpose
from geometry.errors import InputError


def test_cli_refuses_unclear_input(tmp_path) -> None:
    with pytest.raises(InputError, match="--sim"):
        run_wallpose(WallposeSettings(picture=tmp_path / "p.png"))
    with pytest.raises(InputError, match="three numbers"):
        parse_head_angles("0,a,1")
    with pytest.raises(InputError, match="pan, tilt and roll"):
        parse_head_angles("0,1")
