"""The rows of the verification's ISO 9283 figures beyond AP and RP, for the terminal and the report (no numerics,
no plotting): lengths in mm."""

from __future__ import annotations

from typing import Any

MM = 1e3


def iso_rows(runs: dict[str, dict[str, Any]]) -> list[list[str]]:
    """ISO 9283 beyond AP/RP, before and after, ± standard uncertainty [mm]: rows of (figure, before, after), from
    the runs' plain data (``Accuracy.as_dict``); empty when no run has them."""
    def cell(mode: str, part: str, key: str, std: str | None) -> str:
        data = (runs.get(mode) or {}).get(part)
        if not data:
            return "-"
        return f"{data[key] * MM:.4f}" + (f" ± {data[std] * MM:.4f}" if std else "")

    figures = [("AD P2-P4 (7.3)", "distance", "ad", "ad_std"), ("RD P2-P4 (7.3)", "distance", "rd", "rd_std"),
               ("dAP P1 (7.6)", "drift", "dap", "dap_std"), ("dRP P1 (7.6)", "drift", "drp", None)]
    rows = [[name, *(cell(m, part, key, std) for m in ("before", "after"))] for name, part, key, std in figures]
    return [r for r in rows if r[1:] != ["-", "-"]]
