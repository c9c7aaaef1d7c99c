"""ConformalCrowd-v0 is found by gymnasium in a fresh interpreter, as the docs show."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _fresh(code: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    return subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, env=env
    )


def _docs_block() -> tuple[str, str]:
    """The Python block of the docs' ConformalCrowd-v0 section and the output shown after it."""
    text = (ROOT / "docs" / "multi-robot.md").read_text()
    section = text.split("### `ConformalCrowd-v0`", 1)[1]
    m = re.search(r"```python\n(.*?)```\n\n```text\n(.*?)```", section, re.S)
    assert m is not None, "the section shows a Python block and its output"
    return m.group(1), m.group(2)


def test_the_documented_id_works_in_a_fresh_interpreter(tmp_path):
    code, shown = _docs_block()
    assert "import conformal_control" not in code  # the id alone finds the environment
    proc = _fresh(code, tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == shown.strip()


def test_the_short_id_is_registered_once_the_module_id_was_used(tmp_path):
    proc = _fresh(
        "import gymnasium as gym\n"
        "print('ConformalCrowd-v0' in gym.registry)\n"
        "gym.make('conformal_control.envs:ConformalCrowd-v0', max_frames=2).close()\n"
        "env = gym.make('ConformalCrowd-v0', max_frames=2)\n"
        "print(type(env.unwrapped).__name__, env.unwrapped.scene.name)\n",
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "ConformalCrowdEnv", "crossing"]
