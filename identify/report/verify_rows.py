"""The rows of the verification's ISO 9283 figures, for the terminal and the report (no numerics, no plotting):
lengths in mm, angles in mrad, each ± its standard uncertainty when the run states one."""

from __future__ import annotations

from typing import Any

MM = 1e3
MODES = ("before", "after")


def _cell(run: dict[str, Any] | None, name: str) -> str:
    """``value ± uncertainty`` of figure ``name`` of a run's plain data (m -> mm, rad -> mrad: both x 1000)."""
    value = ((run or {}).get("figures") or {}).get(name)
    if value is None:
        return "-"
    u = ((run or {}).get("uncertainty") or {}).get(name)
    return f"{value * MM:.4f}" + ("" if u is None else f" ± {u * MM:.4f}")


def pose_cells(run: dict[str, Any] | None, figure: str, pose: int) -> str:
    """AP or RP (``figure``) of pose ``pose`` with its uncertainty, mm; '-' when the run has none."""
    return _cell(run, f"{figure} P{pose}")


def iso_rows(runs: dict[str, dict[str, Any]]) -> list[list[str]]:
    """ISO 9283 beyond AP/RP, before and after, ± standard uncertainty [mm]: rows of (figure, before, after), from
    the runs' plain data (``Accuracy.as_dict``); empty when no run has them."""
    figures = [("AD P2-P4 (7.3)", "ad"), ("RD P2-P4 (7.3)", "rd"), ("dAP P1 (7.6, run)", "dap"),
               ("dRP P1 (7.6, run)", "drp")] + [(f"vAP P{k} (7.2)", f"vap P{k}") for k in range(1, 6)]
    rows = [[label, *(_cell(runs.get(m), name) for m in MODES)] for label, name in figures]
    return [r for r in rows if r[1:] != ["-", "-"]]


def orientation_rows(runs: dict[str, dict[str, Any]], per_pose: bool = False) -> list[list[str]]:
    """Orientation AP and RP about the base's x, y, z (a, b, c) before and after, ± uncertainty [mrad]: per pose, or
    (``per_pose`` False) the pose with the largest |value| of each figure before and after, named; empty when no
    run measured orientation."""
    rows = []
    for figure in ("ap", "rp"):
        for axis in "abc":
            if per_pose:
                rows += [[f"{figure.upper()} {axis} P{k}", *(_cell(runs.get(m), f"{figure}_{axis} P{k}")
                                                               for m in MODES)] for k in range(1, 6)]
                continue
            cells = []
            for m in MODES:
                values = ((runs.get(m) or {}).get("figures") or {})
                poses = [k for k in range(1, 6) if f"{figure}_{axis} P{k}" in values]
                if not poses:
                    cells.append("-")
                    continue
                k = max(poses, key=lambda p: abs(values[f"{figure}_{axis} P{p}"]))
                cells.append(f"{_cell(runs.get(m), f'{figure}_{axis} P{k}')} P{k}")
            rows.append([f"{figure.upper()} {axis} (worst)", *cells])
    return [r for r in rows if r[1:] != ["-", "-"]]
