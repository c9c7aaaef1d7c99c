"""The module paths of 0.3 keep working after the relocation of 0.4 (issue 33), each with a
dated deprecation warning naming the new path, and hand back the very module (or, for a
package front that moved apart, the very objects) of the new path."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import pytest

from conformal_control._moved import FACADES, MOVED, REMOVAL, new_path
from conformal_control.core.exceptions import ConformalControlDeprecationWarning


def _import_old(old: str):
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
    return module, [w for w in caught if issubclass(w.category, ConformalControlDeprecationWarning)]


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_is_the_new_module_with_a_dated_warning(old):
    module, caught = _import_old(old)
    assert module is importlib.import_module(MOVED[old])
    assert module.__spec__.name == MOVED[old]  # the real spec, not the old path's
    # one warning for this path (an old package front above it warns for itself)
    mine = [str(w.message) for w in caught if str(w.message).startswith(f"{old} moved to")]
    assert len(mine) == 1, [str(w.message) for w in caught]
    text = mine[0]
    assert MOVED[old] in text and "not before 2027-06-30" in text and REMOVAL in text


def test_an_old_package_front_hands_out_the_new_objects(monkeypatch):
    # the table's fronts, and one made up here so the mechanism is checked whatever the table
    monkeypatch.setitem(
        FACADES, "conformal_control.front_for_test", {"RunSpec": "conformal_control.core.spec"}
    )
    for front in sorted(FACADES):
        module, caught = _import_old(front)
        assert len(caught) == 1 and "not before 2027-06-30" in str(caught[0].message)
        for name, where in FACADES[front].items():
            assert getattr(module, name) is getattr(importlib.import_module(where), name)
        with pytest.raises(AttributeError, match="no attribute 'nope'"):
            module.nope  # noqa: B018
    sys.modules.pop("conformal_control.front_for_test")


def test_a_module_below_a_moved_package_follows_it():
    for old, new in MOVED.items():
        assert new_path(f"{old}.below") == f"{new}.below"
    assert new_path("conformal_control.data.scene") is None  # never moved
    assert new_path("conformal_control") is None


def test_an_old_path_warns_where_it_is_imported():
    """In a fresh interpreter: the warning points at the importing line, not at importlib."""
    old = sorted(MOVED)[0]
    code = f"import warnings; warnings.simplefilter('always')\nimport {old}\n"
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert "<string>:2: ConformalControlDeprecationWarning" in proc.stderr, proc.stderr
    assert MOVED[old] in proc.stderr


def test_the_entry_point_groups_keep_their_published_names():
    """Third-party plugins register under these group names: they are not module paths, and
    a module moving (``losses``, ``update_rules`` into ``core/``) does not rename them."""
    from pathlib import Path

    import tomllib

    from conformal_control.core.registry import ROLES

    published = {
        "predictor": "conformal_control.predictors",
        "barrier": "conformal_control.barriers",
        "safety_filter": "conformal_control.safety_filters",
        "fallback": "conformal_control.fallbacks",
        "loss": "conformal_control.losses",
        "rule": "conformal_control.update_rules",
        "dynamics": "conformal_control.dynamics",
        "reference": "conformal_control.references",
        "family": "conformal_control.families",
        "crowd": "conformal_control.crowd_models",
    }
    assert ROLES == published
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    groups = set(tomllib.loads(pyproject.read_text())["project"]["entry-points"])
    assert groups == set(published.values())
