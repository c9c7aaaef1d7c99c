"""Registry: discovery through entry points, unknown names, unavailable plugins, clashes."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from conformal_control.cli import main
from conformal_control.core import registry
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


# ------------------------------------------------------------------ the entry-point cache
CACHED_DISCOVERY = """
import json, sys
from conformal_control.core import registry
rows = [[e.role, e.name, registry._target_text(e.target), e.origin, e.version]
        for e in registry.entries()]
print(json.dumps({"metadata": "importlib.metadata" in sys.modules, "rows": rows}))
"""


def _discover_in_a_process(cache: Path, extra_path: Path | None = None) -> dict:
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "CONFORMAL_CONTROL_CACHE": str(cache)}
    if extra_path is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(extra_path), env.get("PYTHONPATH")]))
    out = subprocess.run(
        [sys.executable, "-c", CACHED_DISCOVERY], env=env, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_entry_points_are_read_from_the_cache_while_nothing_is_installed(tmp_path: Path) -> None:
    first = _discover_in_a_process(tmp_path / "cache")
    assert first["metadata"]  # scanned, and the cache written
    assert len(list((tmp_path / "cache").glob("entry-points-*.json"))) == 1
    second = _discover_in_a_process(tmp_path / "cache")
    assert not second["metadata"]  # from the cache: importlib.metadata not even imported
    assert second["rows"] == first["rows"]
    assert ["predictor", "constant_velocity"] in [r[:2] for r in second["rows"]]


def test_an_installed_distribution_invalidates_the_cache(tmp_path: Path) -> None:
    site = tmp_path / "site"
    site.mkdir()
    before = _discover_in_a_process(tmp_path / "cache", site)
    assert before["metadata"]
    assert _discover_in_a_process(tmp_path / "cache", site)["rows"] == before["rows"]
    info = site / "late_cc_plugin-0.1.dist-info"  # installed after the cache was written
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: late-cc-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[conformal_control.predictors]\nlate = x:Y\n")
    after = _discover_in_a_process(tmp_path / "cache", site)
    assert after["metadata"]  # scanned again
    assert ["predictor", "late", "x:Y", "late-cc-plugin", "0.1"] in after["rows"]


def test_an_unreadable_cache_is_ignored(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    rows = _discover_in_a_process(cache)["rows"]
    for f in cache.glob("entry-points-*.json"):
        f.write_text("{not json")
    again = _discover_in_a_process(cache)
    assert again["metadata"] and again["rows"] == rows


# ------------------------------------------------------------------ a cache is a hint, never code
def _cache_rows(cache: Path) -> tuple[Path, dict]:
    import json

    (path,) = cache.glob("entry-points-*.json")
    return path, json.loads(path.read_text())


def _tamper(cache: Path, edit) -> None:
    import json

    path, stored = _cache_rows(cache)
    edit(stored["rows"])
    path.write_text(json.dumps(stored))


def _retarget_constant_velocity(rows: list) -> None:
    for row in rows:
        if row[1] == "constant_velocity":
            row[2] = "subprocess:Popen"


def test_a_tampered_cache_row_is_never_loaded(tmp_path: Path) -> None:
    """A cache pointing a core name at ``subprocess:Popen`` used to be obeyed (the command
    ran); now the row is checked against the installed distribution and the cache is
    scanned again."""
    cache = tmp_path / "cache"
    first = _discover_in_a_process(cache)
    _tamper(cache, _retarget_constant_velocity)
    again = _discover_in_a_process(cache)
    assert again["metadata"]  # the cache was refused: scanned again
    assert again["rows"] == first["rows"]
    assert ["subprocess:Popen"] not in [r[2:3] for r in again["rows"]]
    _, stored = _cache_rows(cache)  # and rewritten from the scan
    assert "subprocess:Popen" not in [r[2] for r in stored["rows"]]
    assert not _discover_in_a_process(cache)["metadata"]  # the rewritten cache is used


def _point_at_a_folder_not_installed(tmp_path: Path):
    """A metadata folder made by an attacker outside sys.path, declaring the bad row."""
    info = tmp_path / "evil" / "conformal_control-0.0.dist-info"
    info.mkdir(parents=True)
    (info / "entry_points.txt").write_text(
        "[conformal_control.predictors]\nconstant_velocity = subprocess:Popen\n"
    )

    def edit(rows: list) -> None:
        for row in rows:
            if row[1] == "constant_velocity":
                row[2], row[4], row[5] = "subprocess:Popen", "0.0", str(info)

    return edit


def _add_undeclared_row(rows: list) -> None:
    rows.append(["conformal_control.predictors", "extra", "subprocess:Popen", *rows[0][3:]])


def _drop_core_rows(rows: list) -> None:
    rows[:] = [r for r in rows if r[3] != "conformal-control"]


def _credit_another_distribution(rows: list) -> None:
    rows[0][3] = "other-dist"


def _wrong_version(rows: list) -> None:
    row = next(r for r in rows if r[5].endswith(".dist-info") and r[3] != "conformal-control")
    row[4] = "9.9"


def _duplicate_row(rows: list) -> None:
    rows.append(list(rows[0]))


@pytest.mark.parametrize(
    "edit",
    [
        lambda tmp: _add_undeclared_row,
        lambda tmp: _drop_core_rows,
        lambda tmp: _credit_another_distribution,
        lambda tmp: _wrong_version,
        lambda tmp: _duplicate_row,
        _point_at_a_folder_not_installed,
    ],
    ids=[
        "row no distribution declares",
        "core rows dropped",
        "row credited to another distribution",
        "wrong version",
        "duplicated row",
        "row from a folder not installed",
    ],
)
def test_a_cache_that_disagrees_with_the_installed_metadata_is_refused(
    edit, tmp_path: Path
) -> None:
    cache = tmp_path / "cache"
    first = _discover_in_a_process(cache)
    _tamper(cache, edit(tmp_path))
    again = _discover_in_a_process(cache)
    assert again["metadata"] and again["rows"] == first["rows"]


def test_the_cache_file_is_private(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    _discover_in_a_process(cache)
    path, _ = _cache_rows(cache)
    assert path.stat().st_mode & 0o777 == 0o600
    assert cache.stat().st_mode & 0o777 == 0o700
