"""Issue 35's summary: the controls and the ordering in today's arena and the calibrated one.

    python experiments/arena_fidelity.py            # writes results/arena_fidelity.{json,md}

Reads kept run data only (trains nothing): the calibrated arena's runs
(``results/arena_fidelity/run_data``: experiments/studies/arena_calibration.toml,
ordering.toml, table1_mjx.toml; today's arena at the paper's settings:
ordering_kinematic.toml; MCP+MF at the paper's settings in both: ordering_mcp.toml),
today's arena's Table 1 runs (``results/table1_stable``),
the advisor's own evaluations (``results/advisor.json``, ``results/advisor_mjx.json``) and
the checks of issue 35 item 4 (``results/arena_fidelity/lfd_checks/run_data``:
experiments/studies/lfd_td3.toml, lfd_checks.toml).
Per cell of the 2 x 2 design (arena: kinematic robot / MJX robot; settings: ``stable`` / the
paper's literal Eqs. (2) and (4)) it gives each type's success, collision share and
collision speed per evaluation arena, and the paired differences ATD3+AfDP − LfD and
ATD3+AfDP − DDPG, seed by seed on shared evaluation episodes (``advisor_jax.stats``). A
cell whose runs are not kept says so instead of a number.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
from pathlib import Path

from advisor_jax.analysis.items.base import comparison, markdown_table, scores
from advisor_jax.analysis.runs import load_runs, pool
from advisor_jax.fileio import atomic_write_json, atomic_write_text
from advisor_jax.stats import Interval, format_interval, t_interval

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
CALIBRATED = RESULTS / "arena_fidelity" / "run_data"
LFD_CHECKS = RESULTS / "arena_fidelity" / "lfd_checks" / "run_data"
KINEMATIC = [RESULTS / "table1_stable" / "run_data", RESULTS / "table1_stable" / "run_data_d2"]
MCP_PAPER = CALIBRATED / "ordering_mcp"  # experiments/studies/ordering_mcp.toml, both arenas
TYPES = ("ATD3+AfDP", "LfD", "MCP+MF", "DDPG")
PAIRS = (("ATD3+AfDP", "LfD"), ("ATD3+AfDP", "DDPG"))
ARENAS = ("training", "validation")
PAPER = {"DDPG": (72.2, 71.3), "ATD3+AfDP": (90.8, 89.4), "LfD": (80.2, 80.7),
         "MCP+MF": (82.3, 80.1), "advisor": (53.6, 50.4)}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Cell:
    arena: str  # the motion model: kinematic (today's) or mjx (calibrated)
    settings: str  # stable or paper
    dirs: tuple[Path, ...]
    where: dict  # the settings a point must have


CELLS = (
    Cell("kinematic", "stable", tuple(KINEMATIC), {"clip_q_target": 1.0}),
    Cell(
        "kinematic",
        "paper",
        (CALIBRATED / "ordering_kinematic", *([MCP_PAPER] if MCP_PAPER.is_dir() else [])),
        {"motion": "kinematic", "clip_q_target": 0.0},
    ),
    Cell("mjx", "stable", (CALIBRATED,), {"motion": "mjx", "clip_q_target": 1.0}),
    Cell("mjx", "paper", (CALIBRATED,), {"motion": "mjx", "clip_q_target": 0.0}),
)


def _matches(point, agent: str, where: dict) -> bool:
    if point.agent != agent or point.snapshot or point.budget != 500:
        return False
    if agent == "ATD3+AfDP" and point.settings.get("policy_delay") != 2:
        return False  # Table 1's ATD3+AfDP row (docs/architecture.md R36)
    return all(point.settings.get(k) == v for k, v in where.items())


def _row(point) -> dict:
    out = {"seeds": len(point.seeds), "text": point.text()}
    for arena in ARENAS:
        out[arena] = {key: t_interval(scores(point, arena, key))._asdict()
                      for key in ("success", "collision", "collision_speed")}  # fmt: skip
    return out


def cell_record(cell: Cell) -> dict:
    """Each type's row and the paired differences in one cell (None where not kept)."""
    record = {"arena": cell.arena, "settings": cell.settings, "where": cell.where}
    if not cell.dirs:
        return {**record, "kept": False}
    points, _ = pool(load_runs(list(cell.dirs)))
    chosen = {}
    for agent in TYPES:
        found = [p for p in points if _matches(p, agent, cell.where)]
        if len(found) > 1:
            raise ValueError(f"{cell}: {len(found)} points of {agent}: {[p.text() for p in found]}")
        if found:
            chosen[agent] = found[0]
    record["rows"] = {a: _row(p) for a, p in chosen.items()}
    record["not_run"] = [a for a in TYPES if a not in chosen]
    record["pairs"] = {
        f"{x} - {y}": {arena: comparison(chosen[x], chosen[y], arena) for arena in ARENAS}
        for x, y in PAIRS
        if x in chosen and y in chosen
    }
    record["runs"] = sorted({str(s.run.path.relative_to(ROOT)) for p in chosen.values()
                             for s in p.seeds.values()})  # fmt: skip
    return {**record, "kept": True}


def lfd_checks_record() -> dict:
    """Issue 35 item 4 in the calibrated arena at `stable`: LfD on ATD3+AfDP's learner (TD3,
    policy delay 2) and on fewer demonstrations D, each paired by seed with the ordering
    study's ATD3+AfDP and LfD (DDPG, D = 250) on the same evaluation episodes."""
    dirs = [CALIBRATED / "ordering", *sorted(p for p in LFD_CHECKS.glob("*") if p.is_dir())]
    points, _ = pool(load_runs(dirs))
    where = {"motion": "mjx", "clip_q_target": 1.0}
    atd3 = [p for p in points if _matches(p, "ATD3+AfDP", where)]
    lfd = [p for p in points if _matches(p, "LfD", where)]
    reference = [p for p in lfd if p.settings["algo"] == "ddpg"
                 and p.settings["demo_episodes"] == 250]  # fmt: skip
    if len(atd3) != 1 or len(reference) != 1:
        raise ValueError(f"{dirs}: expected one ATD3+AfDP and one LfD (DDPG, D = 250) point")
    checks = [p for p in lfd if p is not reference[0]]
    rows = {p.text(): _row(p) for p in [atd3[0], reference[0], *checks]}
    pairs = {}
    for p in checks:
        for x, y in ((atd3[0], p), (p, reference[0])):
            pairs[f"{x.text()} - {y.text()}"] = {a: comparison(x, y, a) for a in ARENAS}
    demos = sorted(p.settings["demo_episodes"] for p in checks if p.settings["algo"] == "ddpg")
    runs = sorted({str(s.run.path.relative_to(ROOT)) for p in checks for s in p.seeds.values()})
    return {"rows": rows, "pairs": pairs, "demo_episodes_run": demos, "runs": runs}


def advisor_rows() -> dict:
    """The advisor's own evaluation (500 episodes per arena) under each motion model."""
    out = {}
    for motion, name in (("kinematic", "advisor.json"), ("mjx", "advisor_mjx.json")):
        record = json.loads((RESULTS / name).read_text())
        arenas = {r["arena"]: r for r in record["main"]}
        out[motion] = {"file": f"results/{name}", "arenas": arenas}
    return out


def _speed(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f}"


def _pct(iv: dict) -> str:
    return format_interval(Interval(**iv), scale=100.0)


def markdown(record: dict) -> list[str]:
    lines = ["# Arena fidelity: the controls and the paper's ordering in two arenas", "",
             record["note"], ""]  # fmt: skip
    rows = []
    for cell in record["cells"]:
        if not cell["kept"]:
            rows.append((f"{cell['arena']} / {cell['settings']}", "not run", "", "", "", ""))
            continue
        for agent, row in cell["rows"].items():
            t, v = row["training"], row["validation"]
            rows.append((f"{cell['arena']} / {cell['settings']}", agent, row["seeds"],
                         f"{_pct(t['success'])} / {_pct(v['success'])}",
                         f"{_pct(t['collision'])} / {_pct(v['collision'])}",
                         format_interval(Interval(**t["collision_speed"]), digits=2)))  # fmt: skip
        rows += [(f"{cell['arena']} / {cell['settings']}", agent, "not run", "", "", "")
                 for agent in cell.get("not_run", [])]  # fmt: skip
    header = ("arena / settings", "agent", "seeds", "success % (train / val)",
              "collision % (train / val)", "collision speed, train (m/s)")  # fmt: skip
    lines += ["## Each type", "", *markdown_table(header, rows, "llr"), ""]
    if any(cell.get("not_run") for cell in record["cells"]):
        lines += ["A type not run in a cell: MCP+MF at `paper` is "
                  "experiments/studies/ordering_mcp.toml (both arenas).", ""]  # fmt: skip
    lines += ["## The advisor (500 episodes per arena, its own evaluation)", ""]
    adv = []
    for motion, item in record["advisor"].items():
        for arena, r in item["arenas"].items():
            adv.append((motion, arena, f"{100 * r['success_rate']:.1f}",
                        f"{100 * r['collision_rate']:.1f}", _speed(r["mean_collision_speed"]),
                        item["file"]))  # fmt: skip
    lines += markdown_table(("arena", "evaluation arena", "success %", "collision %",
                             "collision speed (m/s)", "file"), adv, "llr")  # fmt: skip
    lines += ["", "## The 2 x 2 design: paired differences (success points, seed by seed)", ""]
    pairs = []
    for cell in record["cells"]:
        for name in (f"{x} - {y}" for x, y in PAIRS):
            found = (cell.get("pairs") or {}).get(name)
            cells = [found[a]["text"] if found and found[a] else "not run" for a in ARENAS]
            pairs.append((cell["arena"], cell["settings"], name, *cells))
    lines += markdown_table(("arena", "settings", "difference", "training env",
                             "validation env"), pairs, "lllr")  # fmt: skip
    lines += ["", "## Other explanations (issue 35 item 4): calibrated arena, `stable`", ""]
    checks = record["lfd_checks"]
    rows = [(name, row["seeds"], f"{_pct(row['training']['success'])} / "
             f"{_pct(row['validation']['success'])}")
            for name, row in checks["rows"].items()]  # fmt: skip
    lines += markdown_table(("agent", "seeds", "success % (train / val)"), rows, "lr")
    lines += [""]
    pairs = [(name, *[d[a]["text"] if d[a] else "–" for a in ARENAS])
             for name, d in checks["pairs"].items()]  # fmt: skip
    lines += markdown_table(("difference (success points, seed by seed)", "training env",
                             "validation env"), pairs, "lr")  # fmt: skip
    if not checks["demo_episodes_run"]:
        lines += ["", "The demonstrations' share D in {10, 50} "
                  "(experiments/studies/lfd_checks.toml) has not been run."]  # fmt: skip
    lines += ["", f"Made by `{record['command']}` on {record['date']} from kept run data; "
              "the runs of each cell are listed in `arena_fidelity.json`."]  # fmt: skip
    return lines


def main(out: Path = RESULTS) -> dict:
    record = {
        "item": "arena_fidelity",
        "note": (
            "Today's arena moves a kinematic robot; the calibrated one simulates a Pioneer "
            "3-DX with MJX (docs/arena_calibration.md). Training runs: bf16, 500 episodes, "
            "16 seeds, evaluated on 200 shared episodes per arena (eval seed 0), except "
            "today's arena at `stable`, which is Table 1's fp32 runs (50 episodes per arena, "
            "eval seed 0)."
        ),
        "cells": [cell_record(c) for c in CELLS],
        "advisor": advisor_rows(),
        "lfd_checks": lfd_checks_record(),
        "paper": PAPER,
        "date": datetime.date.today().isoformat(),
        "command": "python experiments/arena_fidelity.py",
    }
    atomic_write_json(out / "arena_fidelity.json", record)
    atomic_write_text(out / "arena_fidelity.md", "\n".join(markdown(record)) + "\n")
    print(f"wrote {out / 'arena_fidelity.json'} and .md")
    return record


if __name__ == "__main__":
    main()
