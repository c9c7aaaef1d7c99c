"""A wheel that carries everything: built from the sources, it holds every file of the
package (suite manifests, tuned settings, the data manifest, the typing marker, the
predictors' test data: every non-Python file under ``conformal_control/``), and installed
from it -- not editable -- ``conformal-control run`` and ``bench scenarios`` work and give
what the development install gives.

To stay fast the test installs only the wheel (``--no-deps``) into a fresh virtual
environment and lends it this environment's packages through a ``.pth`` file (a path line:
the development install's own ``.pth`` hooks there are not run, so ``conformal_control``
can only come from the wheel, which the test checks).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import conformal_control

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "conformal_control"


def _package_files() -> set[str]:
    """Every file of the package in the source tree (bytecode aside), as wheel paths."""
    return {
        p.relative_to(ROOT).as_posix()
        for p in PACKAGE.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    }


def _run(args: list[str], cwd: Path, env: dict[str, str]) -> str:
    proc = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{' '.join(args)}:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


def test_the_wheel_carries_every_package_file_and_runs_installed(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, src / name)
    shutil.copytree(
        PACKAGE, src / PACKAGE.name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc")
    )
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    dist = tmp_path / "dist"
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(dist),
            str(src),
        ],
        tmp_path,
        env,
    )
    (wheel,) = dist.glob("*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        info = next(n for n in names if n.endswith(".dist-info/METADATA"))
        metadata = zf.read(info).decode()
        entry_points = zf.read(info.replace("METADATA", "entry_points.txt")).decode()
    want = _package_files()
    assert {"conformal_control/data/manifest.json", "conformal_control/py.typed"} <= want
    assert any(n.startswith("conformal_control/data/suite_manifests/") for n in want)
    assert any(n.startswith("conformal_control/experiments/bench/tuned/") for n in want)
    missing = sorted(want - names)
    assert not missing, f"not in the wheel (add them to package-data in pyproject.toml): {missing}"
    assert f"Version: {conformal_control.__version__}\n" in metadata
    assert "Provides-Extra: ros\n" in metadata
    assert "conformal-control = conformal_control.cli:main" in entry_points

    # install it, not editable, into a fresh environment borrowing this one's dependencies
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path, env)
    python = venv / "bin" / "python"
    _run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "-q",
            "--no-deps",
            str(wheel),
        ],
        tmp_path,
        env,
    )
    purelib = Path(
        _run(
            [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            tmp_path,
            env,
        ).strip()
    )
    (purelib / "zz_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp_path / "work"
    work.mkdir()
    where = _run([str(python), "-c", "import conformal_control as c; print(c.__file__)"], work, env)
    assert Path(where.strip()).is_relative_to(venv), where
    cli = venv / "bin" / "conformal-control"
    assert cli.is_file()
    scenarios = _run([str(cli), "bench", "scenarios"], work, env)
    dev = _run([sys.executable, "-m", "conformal_control.cli", "bench", "scenarios"], work, env)
    assert "crossings-v2" in scenarios and scenarios == dev
    _run([str(cli), "run", "--out", "demo"], work, env)
    metrics = json.loads((work / "demo" / "metrics.json").read_text())
    _run([sys.executable, "-m", "conformal_control.cli", "run", "--out", "dev"], work, env)
    ref = json.loads((work / "dev" / "metrics.json").read_text())
    timing = {k for k in ref if "wall" in k}  # the only measured time
    assert {k: v for k, v in metrics.items() if k not in timing} == {
        k: v for k, v in ref.items() if k not in timing
    }
