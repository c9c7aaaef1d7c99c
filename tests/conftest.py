"""Shared fixtures. Tests that need the real data use ``data_root`` / ``sdd_dir``.

The data is read from ``$CONFORMAL_CONTROL_DATA`` or from ``../shared/data`` beside the
project root. If it is missing, data tests FAIL (they are never skipped): CI always has it.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import settings

from conformal_control.data.scene import Scene

ROOT = Path(__file__).resolve().parents[1]

# Property tests are reproducible by default (the same examples on every run and in CI);
# `pytest --hypothesis-profile=explore` searches new examples.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.register_profile("explore", max_examples=500)
settings.load_profile("ci")


def _data_root() -> Path:
    env = os.environ.get("CONFORMAL_CONTROL_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = _data_root()
    if not (root / "sdd").is_dir() or not (root / "ethucy").is_dir():
        pytest.fail(
            f"real data not found at {root} (expected sdd/ and ethucy/ inside); set "
            "CONFORMAL_CONTROL_DATA or place the shared data beside the project",
            pytrace=False,
        )
    return root


@pytest.fixture(scope="session")
def sdd_dir(data_root: Path) -> Path:
    return data_root / "sdd"


@pytest.fixture(scope="session")
def ethucy_dir(data_root: Path) -> Path:
    return data_root / "ethucy"


@pytest.fixture(scope="session")
def nexus4(sdd_dir: Path):
    from conformal_control.data import load_scene

    return load_scene("nexus_4", sdd_dir)


@pytest.fixture(scope="session")
def crossing():
    from conformal_control.data import load_scene

    return load_scene("crossing", seed=0)


# ---------------------------------------------------------------- constructed scenes
def _line_scene(
    tracks: list[np.ndarray],
    *,
    fps: float = 10.0,
    start_index: int = 20,
    robot: tuple[float, float] = (0.0, 0.0),
) -> Scene:
    """A scene from (F, 2) tracks (NaN where absent); the robot's goal is far away."""
    pos = np.stack(tracks, axis=1)
    return Scene(
        name="constructed",
        fps=fps,
        first_frame=0,
        start_index=start_index,
        positions=pos,
        agent_ids=np.arange(len(tracks)) + 1,
        start=np.asarray(robot, dtype=float),
        goals=np.array([[robot[0], robot[1] + 500.0]]),
        v_max=1.0,
        robot_radius=0.5,
        agent_radius=0.5,
    )


def _straight(
    p0: tuple[float, float], v: tuple[float, float], n: int = 200, fps: float = 10.0
) -> np.ndarray:
    """Positions p0 + v t at t = 0, 1/fps, ... (n frames)."""
    t = np.arange(n)[:, None] / fps
    return np.asarray(p0, dtype=float) + t * np.asarray(v, dtype=float)


def _run_stopped_robot(scene: Scene, crowd: str, crowd_params: dict | None = None, frames=150):
    """Run an episode in which the robot is commanded to stand still; return the env."""
    from conformal_control.families.cbf.dynamics import VelocityTrackingDoubleIntegrator
    from conformal_control.world.reactive import make_environment

    env = make_environment(
        scene,
        crowd=crowd,
        crowd_params=crowd_params,
        dynamics=VelocityTrackingDoubleIntegrator(K_acc=2.0),
        tau_frames=4,
        substeps=4,
        max_frames=frames,
    )
    env.reset()
    while not env.done:
        env.sense()
        for _ in range(env.control_instants()):
            env.apply(np.zeros(2))
            if env.done:
                break
        env.reveal()
    return env


@pytest.fixture
def line_scene():
    return _line_scene


@pytest.fixture
def straight():
    return _straight


@pytest.fixture
def run_stopped_robot():
    return _run_stopped_robot


@pytest.fixture
def error_line(capsys: pytest.CaptureFixture[str]):
    """Read stderr, which must be exactly one line, one sentence, ``error: ...``; returns it
    (the check of ``tests/test_cli_attacks.py``, for the attack files beside it)."""
    import re

    def read() -> str:
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert len(lines) == 1, f"expected one line on stderr, got:\n{err}"
        line = lines[0]
        assert line.startswith("error: "), line
        assert "Traceback" not in err and "internal error" not in line, line
        assert not re.search(r"[.!?] +[A-Z][a-z]", line.removeprefix("error: ")), line
        return line

    return read
