"""configs/schema/scenario.schema.json (editors' completion and checks of a scenario file)
accepts the example plants' scenarios (tests/test_schemas.py validates every file of
configs/) and rejects the shapes softplc test refuses; its expectation keys are the
reader's."""

from __future__ import annotations

import json
import textwrap
from typing import Any

import pytest
from jsonschema import Draft202012Validator

from runtime.language.filekind import EXPECT_KEYS
from runtime.language.yamlsrc import load_yaml
from tests.scenario.kit import ROOT

SCHEMA = json.loads((ROOT / "configs" / "schema" / "scenario.schema.json").read_text(
    encoding="utf-8"))
VALIDATOR = Draft202012Validator(SCHEMA)


def errors(text: str) -> list[str]:
    doc = load_yaml("<text>", textwrap.dedent(text))
    return [e.message for e in VALIDATOR.iter_errors(doc)]


HEAD = "plant: plant_sim.yaml\nduration: 2s\nexpect:\n"

GOOD = [
    "- {at: 500ms, expect: {t1.oA: 1, t1.gsA.X: true, t1.gsA.T: '>= 300ms'}}",
    "- {cycle: 3, expect: {t1.SFCCurrentStep: gsA}}",
    "- {at: 1s, within: 100ms, expect: {t1.oA: 1}, name: reaction}",
    "- {from: 0s, to: 1s, never: {t1.oA: 1, t1.oC: 1}}",
    "- {always: {t1.oP: 1}}",
    "- {on_rise: t1.iA, to: 1s, expect: {t1.gsC.X: 1}}",
    "- {on_fall: t1.iA, expect: {t1.gsC.X: 1}}",
    "- {from: 1s, rises: {t1.oC: 4, t1.oA: '>= 2'}}",
]
BAD = {
    "two kinds": "- {at: 1s, never: {t1.oA: 1}}",
    "within without at": "- {cycle: 3, within: 1s, expect: {t1.oA: 1}}",
    "at without expect": "- {at: 1s}",
    "a window on at": "- {at: 1s, from: 0s, expect: {t1.oA: 1}}",
    "unknown key": "- {at: 1s, expcet: {t1.oA: 1}}",
    "name without instance": "- {at: 1s, expect: {oA: 1}}",
    "a list as a value": "- {at: 1s, expect: {t1.oA: [1]}}",
    "a negative count": "- {rises: {t1.oA: -1}}",
    "bad time": "- {at: soon, expect: {t1.oA: 1}}",
}


@pytest.mark.parametrize("entry", GOOD)
def test_the_schema_accepts_each_kind_of_expectation(entry: str) -> None:
    assert errors(HEAD + "  " + entry + "\n") == []


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_the_schema_rejects(case: str) -> None:
    assert errors(HEAD + "  " + BAD[case] + "\n"), f"accepted: {case}"


@pytest.mark.parametrize("text", [
    "duration: 1s\nexpect: [{always: {t1.oA: 1}}]",  # no plant
    "plant: p.yaml\nexpect: [{always: {t1.oA: 1}}]",  # no length, no script
    "plant: p.yaml\nduration: 1s\nexpect: []",  # no expectation
])
def test_the_schema_rejects_a_scenario_missing_a_part(text: str) -> None:
    assert errors(text)


def test_a_scenario_with_a_script_needs_no_length() -> None:
    assert errors("plant: p.yaml\nscript: story.yaml\nexpect: [{always: {t1.oA: 1}}]") == []


def test_the_schema_knows_the_reader_s_expectation_keys() -> None:
    assert set(SCHEMA["properties"]["expect"]["items"]["properties"]) == set(EXPECT_KEYS)


def test_the_example_scenarios_validate() -> None:
    found = sorted((ROOT / "configs").rglob("*.test.yaml"))
    assert len(found) == 8
    for path in found:
        doc: Any = load_yaml(str(path))
        assert [e.message for e in VALIDATOR.iter_errors(doc)] == [], path
