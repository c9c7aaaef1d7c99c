"""Every example notebook executes without error (nbclient, fresh kernel, small settings)."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "examples").glob("*.ipynb"))


def test_there_are_notebooks():
    names = {p.stem for p in NOTEBOOKS}
    assert {"quickstart", "nexus_4", "compare_predictors", "write_a_plugin", "sweep"} <= names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes(path: Path, data_root: Path, monkeypatch) -> None:
    import nbformat  # the docs extra: pip install -e ".[docs]"
    from nbclient import NotebookClient

    monkeypatch.setenv("CONFORMAL_CONTROL_DATA", str(data_root))
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    )
    client.execute()  # raises CellExecutionError, naming the cell, on any error
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    # every notebook shows at least one figure
    assert any("image/png" in o.get("data", {}) for o in outputs), path.name


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_stored_outputs_are_rounded_and_machine_free(path: Path) -> None:
    """What the docs show of a notebook: numbers a reader can read (no 14.900000000000144,
    no 17-digit floats) and no path of the machine it ran on (a warning's file name)."""
    import json
    import re

    cells = json.loads(path.read_text())["cells"]
    for i, cell in enumerate(cells):
        for out in cell.get("outputs", []):
            text = "".join(out.get("text", [])) + "".join(out.get("data", {}).get("text/plain", []))
            long = re.findall(r"-?\d+\.\d{7,}", text)
            assert not long, f"{path.name} cell {i} prints unrounded numbers: {long[:3]}"
            assert not re.search(r"/(tmp|home|root|work)/", text), f"{path.name} cell {i}"
