"""Registry: discovery through entry points, unknown names, unavailable plugins, clashes."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from conformal_control import registry
from conformal_control.cli import main
from conformal_control.predictors import ConstantVelocityPredictor


@pytest.fixture
def fake_distribution(tmp_path: Path, monkeypatch):
    """A third-party distribution installed on sys.path, registering through entry points."""
    (tmp_path / "fake_cc_plugin.py").write_text(
        textwrap.dedent(
            '''
            from conformal_control.predictors import ConstantVelocityPredictor

            class SlowCV(ConstantVelocityPredictor):
                """Constant velocity at half speed (a fake third-party plugin)."""

            class Impostor(ConstantVelocityPredictor):
                """Tries to take over the core constant_velocity name."""
            '''
        )
    )
    info = tmp_path / "fake_cc_plugin-1.2.3.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-cc-plugin\nVersion: 1.2.3\n")
    (info / "entry_points.txt").write_text(
        textwrap.dedent(
            """
            [conformal_control.predictors]
            slow_cv = fake_cc_plugin:SlowCV
            constant_velocity = fake_cc_plugin:Impostor
            needs_missing_dep = no_such_module_for_cc_tests.models:Model

            [conformal_control.barriers]
            broken_attr = fake_cc_plugin:DoesNotExist
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    yield
    monkeypatch.undo()
    registry.refresh()


def test_third_party_entry_points_are_discovered(fake_distribution):
    e = registry.entry("predictor", "slow_cv")
    assert e.origin == "fake-cc-plugin" and e.version == "1.2.3"
    assert registry.get("predictor", "slow_cv").__name__ == "SlowCV"
    assert e.summary() == "Constant velocity at half speed (a fake third-party plugin)."


def test_missing_dependency_is_listed_unavailable_with_reason(fake_distribution):
    e = registry.entry("predictor", "needs_missing_dep")
    assert "needs_missing_dep" in registry.names("predictor")
    assert not e.available
    assert "no_such_module_for_cc_tests" in e.error and "fake-cc-plugin" in e.error
    with pytest.raises(registry.PluginUnavailableError, match="optional dependencies"):
        registry.get("predictor", "needs_missing_dep")
    bad = registry.entry("barrier", "broken_attr")
    assert not bad.available and "DoesNotExist" in bad.error


def test_name_clash_keeps_first_and_is_reported(fake_distribution):
    assert registry.get("predictor", "constant_velocity") is ConstantVelocityPredictor
    (clash,) = [c for c in registry.clashes() if c.name == "constant_velocity"]
    assert clash.ignored == "fake_cc_plugin:Impostor" and clash.ignored_origin == "fake-cc-plugin"
    assert "ignored" in str(clash) and "kept" in str(clash)


def test_plugins_command_lists_everything(fake_distribution, capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    for role, group in registry.ROLES.items():
        assert f"{role} ({group}):" in out
    assert "slow_cv" in out and "[fake-cc-plugin 1.2.3]" in out
    assert "Extrapolate each agent at its recent average velocity." in out
    assert "needs_missing_dep    UNAVAILABLE" in out
    assert "name clashes" in out and "fake_cc_plugin:Impostor" in out


def test_plugins_command_role_and_check(fake_distribution, capsys):
    assert main(["plugins", "--role", "barrier", "--check"]) == 0
    out = capsys.readouterr().out
    assert "predictor (" not in out
    assert "apf" in out and "PASS:" in out and "broken_attr" in out
    assert "unavailable (not checked)" in out


def test_plugins_check_reports_failures(capsys):
    from conformal_control.predictors.base import Forecast

    @registry.register("predictor", "_kit_nan")
    class NaNCV(ConstantVelocityPredictor):
        """Broken on purpose."""

        def predict(self, query):
            fc = super().predict(query)
            return Forecast(fc.positions * float("nan"))

    try:
        assert main(["plugins", "--role", "predictor", "--check"]) == 1
    finally:
        registry.unregister("predictor", "_kit_nan")
    out = capsys.readouterr().out
    assert "FAIL check_predictor_finite_on_clean_input [NaNCV(window=5)]: " in out
    assert "expected finite positions" in out and "1 failed" in out


def test_unknown_name_suggests_close_matches():
    with pytest.raises(registry.UnknownPluginError) as info:
        registry.get("predictor", "constant_velocty")
    err = info.value
    assert isinstance(err, ValueError)
    assert err.suggestions == ["constant_velocity"]
    assert "did you mean 'constant_velocity'?" in str(err)
    assert "oracle" in str(err)  # lists the known names
    with pytest.raises(ValueError, match="unknown plugin role 'predictr'"):
        registry.get("predictr", "oracle")


def test_lazy_and_direct_registration():
    try:
        target = "conformal_control.predictors.constant_velocity:ConstantVelocityPredictor"
        registry.register("predictor", "_kit_lazy", target)
        assert registry.entry("predictor", "_kit_lazy").origin == "runtime"
        assert registry.get("predictor", "_kit_lazy") is ConstantVelocityPredictor
        registry.register("predictor", "_kit_lazy", ConstantVelocityPredictor)  # same target: ok
        with pytest.raises(ValueError, match="already registered"):
            registry.register("predictor", "_kit_lazy", registry.PluginEntry)
        with pytest.raises(ValueError, match="module:Class"):
            registry.register("predictor", "_kit_bad", "no_colon_here")
        registry.register("predictor", "_kit_missing", "cc_missing_mod_xyz:P")
        assert not registry.entry("predictor", "_kit_missing").available
    finally:
        registry.refresh()
    assert "_kit_lazy" not in registry.names("predictor")  # refresh drops runtime ones
    assert "constant_velocity" in registry.names("predictor")
