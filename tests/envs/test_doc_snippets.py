"""The environments' snippets of the Multi-robot page run as a reader copies them (the issue:
they called a `my_policy` they never defined) and print the output the page shows."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_FENCE = re.compile(r"```python\n(.*?)```\n\n```text\n(.*?)```", re.S)


def _policy_blocks() -> list[tuple[str, str]]:
    text = (ROOT / "docs" / "multi-robot.md").read_text()
    blocks = [(m[1], m[2]) for m in _FENCE.finditer(text) if "my_policy" in m[1]]
    return blocks


BLOCKS = _policy_blocks()


def test_every_snippet_with_a_policy_shows_its_output() -> None:
    text = (ROOT / "docs" / "multi-robot.md").read_text()
    assert text.count("my_policy(") == sum(b.count("my_policy(") for b, _ in BLOCKS)
    assert len(BLOCKS) == 3  # ConformalShield, ConformalCrowdParallel, ReciprocalShield


@pytest.mark.parametrize(("code", "shown"), BLOCKS, ids=["shield", "parallel", "reciprocal"])
def test_a_policy_snippet_runs_and_prints_what_the_page_shows(
    code: str, shown: str, tmp_path: Path
) -> None:
    assert "def my_policy(" in code
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == shown.strip()


def test_the_monitor_of_an_unshielded_environment_never_changes_the_action() -> None:
    """An environment without a shield applies the policy's action as it is: its monitor's
    filter returns the action even next to an agent within the collision distance (the
    filters' edge rule would brake there, freezing unshielded robots in contact: the
    parallel snippet's robots stopped for good)."""
    import numpy as np

    from conformal_control.envs.roles import MonitorFilter
    from conformal_control.families.cbf.roles import EscapeRows

    f = MonitorFilter()
    f.reset()
    toward = np.array([1.5, 0.0])  # straight at an agent 0.5 m ahead, inside d_c
    escape = EscapeRows(np.array([0]), np.array([[-1.0, 0.0]]), np.zeros(1), np.ones(1))
    A, b = np.array([[-2.0, 0.0]]), np.array([-1.0])
    res = f.solve_escaping(toward, A, b, 0.0, escape)
    np.testing.assert_array_equal(res.decision, toward)
    assert res.status == "fallback" and res.fallback == "unfiltered"  # recorded, not applied
