"""The fault-injection matrix's table: rows collected by ``test_faults.py``, printed at the
end of the run (issue 7: "print the matrix as a table")."""

from __future__ import annotations

import pytest

MATRIX: list[dict[str, object]] = []
COLUMNS = ("fault", "halt", "within", "amps", "brakes", "program", "status", "stop", "restart")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Print the matrix, one row per fault injected (a failed row shows what it reached)."""
    if not MATRIX:
        return
    rows = [[str(r.get(c, "FAILED" if c == "halt" else "")) for c in COLUMNS] for r in MATRIX]
    widths = [max(len(c), *(len(r[k]) for r in rows)) for k, c in enumerate(COLUMNS)]
    tr = terminalreporter
    tr.section("fault-injection matrix (real time, both arms moving)")
    tr.write_line("  ".join(c.ljust(w) for c, w in zip(COLUMNS, widths, strict=True)))
    for r in rows:
        tr.write_line("  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)))
