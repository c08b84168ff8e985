"""Parameters are declared once; the CLI, docs and viewer schema all come from PARAMS."""
from __future__ import annotations

import argparse

import pytest

from igi.common.params import (PARAM_BY_NAME, PARAMS, add_arguments, make_params, parameters_doc, params_from_args,
                               values_in_use, viewer_schema)

from tests.support.paths import ROOT


def test_docs_page_is_generated_from_the_declarations():
    assert (ROOT / "docs" / "parameters.md").read_text() == parameters_doc()


def test_every_parameter_has_a_cli_flag_with_its_default():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args([])
    assert params_from_args(args) == make_params()
    flags = {a for action in parser._actions for a in action.option_strings}
    assert all(p.flag in flags for p in PARAMS)


def test_flags_override_and_are_validated():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    p = params_from_args(parser.parse_args(["--indirect-vpls", "7", "--no-accumulate"]))
    assert p.indirect_vpls == 7 and p.accumulate is False
    with pytest.raises(ValueError, match="interleave"):
        make_params(interleave=0)
    with pytest.raises(ValueError, match="unknown parameter"):
        make_params(bogus=1)
    with pytest.raises(ValueError, match="NaN"):
        make_params(clamp=float("nan"))


def test_viewer_schema_lists_the_viewer_parameters_with_ranges():
    schema = {s["name"]: s for s in viewer_schema()}
    for p in PARAMS:
        assert (p.name in schema) == p.viewer
    assert schema["indirect_vpls"]["max"] == 1024
    assert schema["indirect_vpls"]["default"] == PARAM_BY_NAME["indirect_vpls"].default
    assert schema["moving_indirect_vpls"]["special"] == "as still" and schema["moving_indirect_vpls"]["min"] == -1


def test_a_moving_cameras_vpl_count_at_minus_one_shows_the_still_count_in_use():
    assert values_in_use({"moving_indirect_vpls": -1, "indirect_vpls": 12}) == {"moving_indirect_vpls": 12}
    assert values_in_use({"moving_indirect_vpls": 7}) == {}
