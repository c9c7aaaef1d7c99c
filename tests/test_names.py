"""One name per concept: a role is called the same in the registry, the run
specification, ``config.json``, the command line and the loop; 0.2's names still work,
with a DeprecationWarning."""

from __future__ import annotations

import argparse
import inspect
import warnings

import pytest

from conformal_control.cli import build_parser
from conformal_control.core import registry, spec
from conformal_control.core.loop import ConformalLoop, ConformalStepper
from conformal_control.data.synthetic import crossing_scene
from conformal_control.runs.build import build_flagship
from conformal_control.testing import checks_for


def _run_options() -> set[str]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {s for a in sub.choices["run"]._actions for s in a.option_strings}


def test_the_registry_roles_are_the_run_fields_and_the_cli_options():
    assert set(registry.ROLES) == set(spec.ROLE_FIELDS)
    options = _run_options()
    for role in registry.ROLES:
        flag = "--" + role.replace("_", "-")
        assert flag in options, flag
        if role != "fallback":  # the fallback is a name only
            assert f"{flag}-param" in options, f"{flag}-param"
    assert not set(registry.RENAMED_ROLES) & set(registry.ROLES)


def test_config_json_records_the_roles_by_their_names():
    fl = build_flagship(crossing_scene(duration=4.0), family="cbf")
    recorded = fl.role_params()
    assert set(recorded) <= set(registry.ROLES)
    assert {"rule", "family"} <= set(recorded)
    assert set(spec.RunSpec().as_dict()) >= set(registry.ROLES)


def test_the_loop_calls_the_family_family():
    for cls in (ConformalStepper, ConformalLoop):
        names = list(inspect.signature(cls).parameters)
        assert "family" in names and "policy" not in names


@pytest.mark.parametrize(("old", "new"), sorted(registry.RENAMED_ROLES.items()))
def test_a_role_name_of_0_2_still_works_with_a_deprecation_warning(old, new):
    with pytest.warns(DeprecationWarning, match=f"'{old}' is now called '{new}'"):
        assert registry.names(old) == registry.names(new)
    with pytest.warns(DeprecationWarning):
        assert registry.entry(old, registry.names(new)[0]).role == new
    with pytest.warns(DeprecationWarning):
        assert checks_for(old) is checks_for(new)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        registry.names(new)  # the names of now: no warning


def test_the_loop_still_takes_policy_with_a_deprecation_warning():
    fl = build_flagship(crossing_scene(duration=4.0))
    with pytest.warns(DeprecationWarning, match="policy= is now family="):
        stepper = ConformalStepper(policy=fl.family, loss=fl.loss, rule=fl.rule)
    assert stepper.family is fl.family
    with pytest.warns(DeprecationWarning, match="attribute policy is now family"):
        assert stepper.policy is fl.family
    with pytest.warns(DeprecationWarning, match="Flagship.policy is now Flagship.family"):
        assert fl.policy is fl.family
    with pytest.warns(DeprecationWarning):
        loop = ConformalLoop(fl.env, policy=fl.family, loss=fl.loss, rule=fl.rule)
    assert loop.run(max_intervals=2).lambda_final == loop.lam


def test_the_cli_lists_plugins_under_a_role_name_of_0_2(capsys):
    from conformal_control.cli import main

    assert main(["plugins", "--role", "update_rule"]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("rule (conformal_control.update_rules):")
    assert "'update_rule' is now called 'rule'" in captured.err
