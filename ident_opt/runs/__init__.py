"""Two runs side by side: this run's fit against another run's (`compare --against OTHER.json`).

The question after a maintenance, a payload change or a new cut-off: which parameters moved beyond their standard
errors, and did the held-out errors change? `read_run` reads a `compare --json` or `identify --json`; `summarize`
takes the same payload from memory; `side_by_side` puts two summaries together.

    import ident_opt as iopt
    before = iopt.read_run("last_week/compare.json")
    today = iopt.read_run("today/compare.json")
    diff = iopt.side_by_side(today, before)
    diff.parameters[diff.parameters["beyond"]]   # the parameters that moved beyond their errors
"""

from ident_opt.runs._side_by_side import (
    Z_BEYOND,
    RunSummary,
    SideBySide,
    read_payload,
    read_run,
    side_by_side,
    summarize,
)

__all__ = ["Z_BEYOND", "RunSummary", "SideBySide", "read_payload", "read_run", "side_by_side", "summarize"]
