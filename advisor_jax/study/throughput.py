"""How fast a population trains, for ``advisor-jax sweep --dry-run``'s time estimate.

The estimate is read from a table derived from measurements kept in ``results/``:

* agent env-steps/s of the full training step, per device kind, learner precision, network
  size (``paper`` and ``stable`` share one) and population size: the rows of
  ``experiments/bench_train.py``'s reports (``results/bench_train*.json``,
  ``results/bench_train_largest/*.json``, ``results/bench_train_programs/*.json``) of the
  program training picks (``--program auto``), ATD3+AfDP, the newest program's rows: those of
  the newest date with several rows and of any later date, and older rows of larger
  populations (``_newest_program``);
* each agent type's speed relative to ATD3+AfDP and its mean training-episode length, per
  training arena, from kept runs that trained every type alike on one device
  (``results/table1_stable/run_data``, ``results/table2/run_data``): the DDPG family
  updates its actor at every step, the baselines run extra phases;
* for the MJX robot (``motion = "mjx"``): its full step's speed relative to the kinematic
  robot's at the same population size, measured in one command
  (``results/bench_train_motion/``), and each type's mean training-episode length from the
  kept runs in the calibrated arena (``results/arena_fidelity/run_data``,
  ``results/table2_calibrated/run_data``; their speeds are not used: those pieces shared
  their GPUs).

    python -m advisor_jax.study.throughput       # writes results/sweep_throughput.json

A device, precision or size without a row has no estimate, and the plan says which
benchmark would give one.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from advisor_jax.fileio import atomic_write_json

RESULTS = Path(__file__).resolve().parents[2] / "results"
TABLE = RESULTS / "sweep_throughput.json"
REFERENCE_TYPE = "ATD3+AfDP"
SIZE_OF_PRESET = {"paper": "paper", "stable": "paper", "physical": "physical", "quick": "quick"}
TYPE_RUNS = (("training", "table1_stable"), ("physical", "table2"))  # (arena, results folder)
MOTION_BENCH = "bench_train_motion"  # bench_train_<motion>.json, one command per motion
MOTION_RUNS = ("arena_fidelity/run_data", "table2_calibrated/run_data")
COMPILE_S = 60.0  # compile, evaluation and files of one piece (bench_train's warm-up: 15-48 s)


def _bench_rows(paths: list[Path]) -> list[dict]:
    rows = []
    for path in paths:
        report = json.loads(path.read_text())
        size = SIZE_OF_PRESET.get(report.get("preset", "paper"))
        if (
            size is None
            or report.get("agent", REFERENCE_TYPE) != REFERENCE_TYPE
            or report.get("program", "auto") != "auto"
        ):
            continue
        for row in report.get("rows", []):
            if row.get("devices", 1) != 1 or "agent_steps_per_s" not in row:
                continue
            rows.append(
                {
                    "device": report["device"],
                    "precision": row.get("precision", "fp32"),
                    "size": size,
                    "agents": row["agents"],
                    "date": report["date"],
                    "agent_steps_per_s": row["agent_steps_per_s"],
                    "source": str(path.relative_to(RESULTS.parent)),
                }
            )
    by_key: dict[tuple, list[dict]] = {}
    for row in rows:
        by_key.setdefault((row["device"], row["precision"], row["size"]), []).append(row)
    kept = []
    for found in by_key.values():
        kept += _newest_program(found).values()
    return sorted(kept, key=lambda r: (r["device"], r["precision"], r["agents"]))


def _newest_program(found: list[dict]) -> dict[int, dict]:
    """Rows of one device, precision and size by population: those of the newest date that
    measured several populations (the newest program) and of any later date (single rows,
    such as a larger population), each population's newest; all dates where no date has
    several rows. Populations larger than all of those keep the rows of the newest date
    that measured such populations: the best measurement of their size, where the table
    would otherwise clamp them to a far smaller population's rate."""
    by_date = sorted(found, key=lambda r: r["date"], reverse=True)
    dates = [r["date"] for r in by_date]
    base = next((d for d in dates if dates.count(d) >= 2), dates[-1])
    chosen: dict[int, dict] = {}
    for r in by_date:
        if r["date"] >= base:
            chosen.setdefault(r["agents"], r)
    larger = [r for r in by_date if r["agents"] > max(chosen)]
    for r in larger:
        if r["date"] == larger[0]["date"]:
            chosen.setdefault(r["agents"], r)
    return chosen


def _type_rows(run_root: Path) -> dict:
    """Per agent type of the kept runs under ``run_root``: agent env-steps/s relative to
    ATD3+AfDP's and mean steps per training episode."""
    from advisor_jax.analysis.runs import load_runs

    runs = load_runs([run_root]).runs
    rates = {
        r.agent: sum(r.summary["env_steps_per_agent"]) / r.summary["train_seconds"] for r in runs
    }
    out = {}
    for r in runs:
        length = np.asarray(r.metrics()["length"], np.float64)
        out[r.agent] = {
            "relative_speed": rates[r.agent] / rates[REFERENCE_TYPE],
            "steps_per_episode": float(length[length > 0].mean()),
            "source": str(r.path.relative_to(RESULTS.parent)),
        }
    return out


def _motion_factors(folder: Path) -> dict:
    """{motion: [{agents, precision, factor}]}: agent env-steps/s under each motion model
    relative to ``kinematic`` at the same population size and precision."""
    reports = {p.stem.removeprefix("bench_train_"): json.loads(p.read_text())
               for p in sorted(folder.glob("bench_train_*.json"))}  # fmt: skip
    base = reports.get("kinematic")
    if base is None:
        return {}
    rate = {(r["agents"], r["precision"]): r["agent_steps_per_s"] for r in base["rows"]}
    out = {}
    for motion, report in reports.items():
        if motion == "kinematic":
            continue
        out[motion] = [
            {"agents": r["agents"], "precision": r["precision"],
             "factor": r["agent_steps_per_s"] / rate[(r["agents"], r["precision"])],
             "source": str((folder / f"bench_train_{motion}.json").relative_to(RESULTS.parent))}
            for r in report["rows"]
            if (r["agents"], r["precision"]) in rate and r.get("devices", 1) == 1
        ]  # fmt: skip
    return out


def _motion_lengths(roots: list[Path]) -> dict:
    """{motion: {arena: {agent: mean steps per training episode}}} of kept runs under
    ``roots`` that moved another robot than the kinematic one."""
    from advisor_jax.analysis.runs import load_runs

    lengths: dict[tuple, list[np.ndarray]] = {}
    for root in roots:
        if not root.is_dir():
            continue
        for run in load_runs([root]).runs:
            motion = run.config.get("motion", "kinematic")
            if motion == "kinematic" or ":" in motion:  # the calibrated models only
                continue
            length = np.asarray(run.metrics()["length"], np.float64)
            key = (motion, run.config.get("arena", "training"), run.agent)
            lengths.setdefault(key, []).append(length[length > 0])
    out: dict = {}
    for (motion, arena, agent), found in sorted(lengths.items()):
        out.setdefault(motion, {}).setdefault(arena, {})[agent] = float(
            np.concatenate(found).mean()
        )
    return out


def derive(results: Path = RESULTS) -> dict:
    """The table written to ``sweep_throughput.json``."""
    paths = sorted(results.glob("bench_train*.json"))  # first: the canonical file wins a date's tie
    for folder in ("bench_train_largest", "bench_train_programs"):
        paths += sorted((results / folder).glob("*.json"))
    return {
        "note": "derived by `python -m advisor_jax.study.throughput` from the files named in "
        "each row; agent env-steps/s of ATD3+AfDP, one device",
        "rows": _bench_rows(paths),
        "agent_types": {
            arena: _type_rows(results / folder / "run_data") for arena, folder in TYPE_RUNS
        },
        "motion_factors": _motion_factors(results / MOTION_BENCH),
        "motion_steps_per_episode": _motion_lengths([results / p for p in MOTION_RUNS]),
    }


def load_table(path: Path = TABLE) -> dict | None:
    """The derived table, or None where the repository's results/ is not at hand."""
    return json.loads(path.read_text()) if path.is_file() else None


def motion_factor(table: dict, motion: str, precision: str, agents: int) -> float:
    """The full step's speed under ``motion`` relative to the kinematic robot's, at
    ``agents`` (interpolated in log agents, clamped; measured on one device kind and used
    for every kind); 1 for ``kinematic`` and where nothing was measured."""
    rows = [r for r in table.get("motion_factors", {}).get(motion.partition(":")[0], [])
            if r["precision"] == precision]  # fmt: skip
    if not rows:
        return 1.0
    rows.sort(key=lambda r: r["agents"])
    xs = np.log([r["agents"] for r in rows])
    return float(np.interp(math.log(max(agents, 1)), xs, [r["factor"] for r in rows]))


def agent_steps_per_s(
    table: dict,
    device: str,
    precision: str,
    preset: str,
    agents: int,
    motion: str = "kinematic",
) -> float | None:
    """Interpolated (in log agents, clamped at the ends) env-steps/s of ATD3+AfDP for a
    population of ``agents`` on one ``device`` (or the GPU that ``measured_as`` stands in
    for it), times ``motion_factor``; None where nothing was measured."""
    size = SIZE_OF_PRESET.get(preset)
    measured = measured_as(table, device, precision, preset)
    rows = [
        r
        for r in table["rows"]
        if r["device"] == measured and r["precision"] == precision and r["size"] == size
    ]
    if not rows:
        return None
    xs = np.log([r["agents"] for r in rows])
    ys = np.array([r["agent_steps_per_s"] for r in rows])
    rate = float(np.interp(math.log(max(agents, 1)), xs, ys))
    return rate * motion_factor(table, motion, precision, agents)


def measured_as(table: dict, device: str, precision: str, preset: str) -> str | None:
    """The device whose measured rates estimate ``device``: itself where it was measured at
    this precision and preset's sizes; for a GPU measured nowhere, the first measured GPU
    (by name: an estimate, said so in the plan, better than none for ``--time-limit``);
    None where no GPU was."""
    size = SIZE_OF_PRESET.get(preset)
    kinds = sorted(
        {r["device"] for r in table["rows"] if r["precision"] == precision and r["size"] == size}
    )
    if device in kinds:
        return device
    if device == "cpu":
        return None
    return next((k for k in kinds if k != "cpu"), None)


def agent_type(table: dict, agent: str, arena: str, motion: str = "kinematic") -> dict:
    """``relative_speed`` and ``steps_per_episode`` of ``agent`` trained in ``arena`` (the
    training arena's for other simulated arenas; ATD3+AfDP's where the kept runs lack that
    type); under another motion model, its episodes' length there where kept runs have it."""
    by_arena = table.get("agent_types", {})
    types = by_arena.get(arena) or by_arena.get("training", {})
    row = (
        types.get(agent)
        or types.get(REFERENCE_TYPE)
        or {
            "relative_speed": 1.0,
            "steps_per_episode": 100.0,
        }
    )
    by_motion = table.get("motion_steps_per_episode", {}).get(motion.partition(":")[0], {})
    lengths = by_motion.get(arena) or by_motion.get("training", {})
    if agent in lengths:
        row = {**row, "steps_per_episode": lengths[agent]}
    return row


if __name__ == "__main__":
    atomic_write_json(TABLE, derive())
    print(f"wrote {TABLE}")
