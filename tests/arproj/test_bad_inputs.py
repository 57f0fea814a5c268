"""Bad input of every kind, generated (issue 24 item 7): Hypothesis draws the choices of arproj.bench.inputs'
generators (wrong types, non-finite and huge numbers, deep nesting, truncation, binary garbage, alias bombs,
damaged archives and databases) and each malformed file goes to the CLI that reads it, in-process. The contract:
exit status 2, one `arproj: error:` line naming the file, no traceback, no earlier output changed.

11 kinds x 91 examples: 1,001 bad inputs per run. Refusal times are the benchmark's (`arproj bench inputs`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from arproj.bench import inputs as bad

EXAMPLES_PER_KIND = 91


class DrawPicker:
    """The generators' choices drawn by Hypothesis (so that a failure shrinks to the simplest bad file)."""

    def __init__(self, data: st.DataObject) -> None:
        self.data = data

    def integer(self, lo: int, hi: int) -> int:
        return self.data.draw(st.integers(lo, hi))


@pytest.fixture(scope="module")
def fixture(tmp_path_factory: pytest.TempPathFactory) -> bad.Fixture:
    return bad.build_fixture(tmp_path_factory.mktemp("bad-inputs"))


@pytest.mark.parametrize("kind", list(bad.KINDS))
def test_every_malformed_file_is_refused_with_one_line_and_nothing_lost(fixture: bad.Fixture, kind: str) -> None:
    @settings(max_examples=EXAMPLES_PER_KIND, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(data=st.data())
    def check(data: st.DataObject) -> None:
        case = bad.KINDS[kind](fixture, DrawPicker(data))
        outcome = bad.run_case(case, fixture.outputs)
        assert not outcome.traceback, f"{case.kind}, {case.what}: traceback\n{outcome.traceback}"
        assert not outcome.destroyed, f"{case.kind}, {case.what}: earlier outputs changed: {outcome.destroyed}"
        assert outcome.exit_code == 2, f"{case.kind}, {case.what}: exit status {outcome.exit_code}: {outcome.line}"
        assert outcome.clean, f"{case.kind}, {case.what}: not one line naming {case.bad_file.name}: {outcome.line}"

    check()


def test_the_contract_check_fails_on_an_accepted_file(fixture: bad.Fixture, tmp_path: Path) -> None:
    """A valid objects.json is read and answered (exit 0): the check above would count it as a failure."""
    folder = tmp_path / "map"
    shutil.copytree(fixture.map_dir, folder)
    case = bad.Case("objects.json", "valid", folder / "objects.json", ["drill", str(folder), "--at", "0.1,0.1"])
    outcome = bad.run_case(case, fixture.outputs)
    assert outcome.exit_code == 0 and not outcome.clean


def test_the_contract_check_sees_a_destroyed_output(fixture: bad.Fixture, tmp_path: Path) -> None:
    earlier = tmp_path / "earlier.json"
    earlier.write_text("{}")
    case = bad.Case("objects.json", "writes its output over an earlier one", tmp_path / "objects.json",
                    ["drill", str(fixture.map_dir), "--at", "0.1,0.1", "--json"])
    before = bad.snapshot([earlier])
    earlier.write_text(json.dumps({"changed": True}))
    assert bad.snapshot([earlier]) != before
    assert not bad.run_case(case, [fixture.map_dir]).destroyed  # reading a map changes nothing of it
