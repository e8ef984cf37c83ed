"""The example notebook runs (issue 55 item 3): ``scripts/example_recording.ipynb`` executed
cell by cell in a Jupyter kernel of this Python (nbclient), so it never rots."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from kali_daemons.tools import launcher

from .conftest import leftovers, unique_name

NOTEBOOK = Path(__file__).resolve().parent.parent / "scripts" / "example_recording.ipynb"


def test_the_recording_notebook_runs_and_plots_every_tick(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It starts its lockstep cell, records a move, reads the file back (asserting every tick
    is there, in order), draws its two figures and stops the cell, leaving nothing behind."""
    name = unique_name("nb")
    monkeypatch.setenv("KALI_INSTANCE", name)  # the kernel inherits it: the cell it starts
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    try:
        client.execute()
    finally:
        launcher.stop(name)  # if a cell failed before the notebook's own stop
    outputs = [o for cell in nb.cells if cell.cell_type == "code" for o in cell.outputs]
    assert not [o for o in outputs if o.output_type == "error"]
    texts = [o.get("data", {}).get("text/plain", "") for o in outputs]
    status = next(text for text in texts if "'gaps'" in text)
    assert "'gaps': 0" in status and "'error': ''" in status, status
    figures = [o for o in outputs if o.output_type == "display_data" and "image/png" in o.data]
    assert len(figures) == 2  # demand, angle, error and torque; the wrist wrench
    assert (tmp_path / "move.mcap").stat().st_size > 100_000
    assert leftovers(name) == ([], [])
