"""``import conformal_control`` and the command line's start-up stay free of heavy imports.

The package imports every public name on first use, and the command line imports a
command's dependencies only when that command runs; checked in a fresh interpreter
(``sys.modules`` after the import), not by timing.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: never imported by ``import conformal_control`` / ``conformal_control.cli`` / ``--help``
HEAVY = ("torch", "darts", "matplotlib", "pandas", "scipy", "numba", "sklearn", "statsmodels")


def _loaded_after(code: str) -> list[str]:
    probe = (
        f"{code}\nimport json, sys\n"
        f"print(json.dumps(sorted(m for m in {(*HEAVY, 'numpy')!r} if m in sys.modules)))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_package_imports_nothing_heavy_not_even_numpy():
    assert _loaded_after("import conformal_control") == []


def test_import_cli_imports_nothing_heavy():
    loaded = _loaded_after("import conformal_control, conformal_control.cli")
    assert not set(loaded) & set(HEAVY), loaded


@pytest.mark.parametrize("argv", [["--help"], ["--version"], ["run", "--help"]])
def test_cli_help_and_version_import_nothing_heavy(argv):
    code = (
        "import contextlib, io\n"
        "from conformal_control.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    try:\n"
        f"        main({argv!r})\n"
        "    except SystemExit as exc:\n"
        "        assert exc.code in (0, None), exc.code\n"
    )
    loaded = _loaded_after(code)
    assert not set(loaded) & set(HEAVY), loaded


def test_public_names_resolve_lazily_and_are_listed():
    code = (
        "import conformal_control as cc\n"
        "from conformal_control import ConformalLoop, GuaranteeMonitor\n"
        "from conformal_control.core.loop import ConformalLoop as L\n"
        "assert ConformalLoop is L\n"
        "missing = [n for n in cc.__all__ if getattr(cc, n, None) is None]\n"
        "assert not missing, missing\n"
        "assert set(cc.__all__) <= set(dir(cc))\n"
        "try:\n"
        "    cc.no_such_name\n"
        "except AttributeError as exc:\n"
        "    assert 'no_such_name' in str(exc)\n"
        "else:\n"
        "    raise AssertionError('no AttributeError')\n"
    )
    # every public name imported: numpy now, but still neither torch nor darts
    loaded = _loaded_after(code)
    assert "numpy" in loaded
    assert not {"torch", "darts"} & set(loaded), loaded


def test_the_base_class_of_every_role_is_a_top_level_name():
    # a plugin author subclasses ``cc.<Base>`` for any role, the crowd model and the
    # fallback included, without knowing which module defines it
    import conformal_control as cc
    from conformal_control.testing import ROLE_BASES

    missing = [
        f"{role}: {base.__name__}"
        for role, base in ROLE_BASES.items()
        if getattr(cc, base.__name__, None) is not base or base.__name__ not in cc.__all__
    ]
    assert not missing, missing
