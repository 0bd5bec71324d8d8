"""Do two runs of the same settings, trained by two versions of the program, learn the same?

``advisor-jax report --versus NAME`` pairs points that differ in one setting. A change to how
the program computes (a faster layout of the networks, another compiled program) changes no
setting, so its check is this: a CONTROL run and a TREATMENT run of the same agent, settings,
seeds and evaluation episodes, each loaded as ``advisor-jax report`` loads runs (one point
each, on the evaluation both share), and TREATMENT − CONTROL in success, seed by seed, per
arena, with the 95 % t interval of the mean difference (``stats.paired_difference``).

    python experiments/paired_runs.py CONTROL_RUN TREATMENT_RUN --out OUT

(results/precision_study.md names each pairing it made, e.g. a bf16 population trained by
the tree before a change against one trained after it).

Writes ``paired.md`` and ``paired.json`` into ``--out``; refuses runs whose settings,
seeds or evaluation episodes differ. Where both runs kept metrics.npz, it also counts the
seeds whose training episodes were the same, episode for episode (``same_episodes``): a change
that computes exactly what it replaced shows there, where the interval can only say "not
resolved". Where both run.json record ``agent_params_sha256`` (from 2026-12-08), it counts the
seeds whose final networks are equal bit for bit (``same_networks``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from advisor_jax.analysis.items.base import ARENAS
from advisor_jax.analysis.runs import Point, load_runs, pool
from advisor_jax.bench import writing
from advisor_jax.fileio import atomic_write_json
from advisor_jax.stats import format_interval, paired_difference, t_interval


def the_point(path: Path, eval_seed: int | None) -> Point:
    """The one point (agent, settings, final budget) of the runs below ``path``."""
    points, _ = pool(load_runs([path], eval_seed))
    final = [p for p in points if not p.snapshot]
    if len(final) != 1:
        raise ValueError(f"{path}: {len(final)} points, expected one run of one setting")
    return final[0]


def compare(control: Point, treatment: Point) -> dict:
    """Per arena: both sides' mean ± interval and the paired difference (points of success)."""
    if (control.agent, control.settings) != (treatment.agent, treatment.settings):
        raise ValueError("the runs differ in agent or settings; use advisor-jax report --versus")
    if sorted(control.seeds) != sorted(treatment.seeds):
        raise ValueError(f"different seeds: {sorted(control.seeds)} / {sorted(treatment.seeds)}")
    rows = {}
    for arena in ARENAS:
        c, t = control.scores(arena), treatment.scores(arena)
        if any(v is None for v in (*c.values(), *t.values())):
            continue
        paired = paired_difference(t, c)
        rows[arena] = dict(
            control=format_interval(t_interval(list(c.values())), 100),
            treatment=format_interval(t_interval(list(t.values())), 100),
            difference=format_interval(paired.interval, 100),
            verdict=paired.verdict,
            differences=paired.differences,
            seeds=paired.seeds,
        )
    return rows


EPISODE_ARRAYS = ("outcome", "length", "reward_per_step", "collision_speed")
"""Per-episode arrays of ``metrics.npz`` (seeds × episodes) that ``same_episodes`` compares."""


def same_episodes(control: Point, treatment: Point) -> dict | None:
    """How many seeds trained the same episodes in both points: every entry of
    ``EPISODE_ARRAYS`` equal (NaN equal to NaN). None where a run lacks metrics.npz."""
    seeds = sorted(set(control.seeds) & set(treatment.seeds))
    rows = {
        s: [(control.seeds[s].episodes(n), treatment.seeds[s].episodes(n)) for n in EPISODE_ARRAYS]
        for s in seeds
    }
    if any(c is None or t is None for pairs in rows.values() for c, t in pairs):
        return None

    def equal(c: np.ndarray, t: np.ndarray) -> bool:
        return c.shape == t.shape and np.array_equal(c, t, equal_nan=True)

    same = [s for s in seeds if all(equal(c, t) for c, t in rows[s])]
    return dict(arrays=list(EPISODE_ARRAYS), seeds=len(seeds), identical_seeds=same)


def _networks_sha256(seed) -> str | None:
    """A seed's final networks' sha256 (its run's ``agent_params_sha256``), or None where
    the run does not record them (versions before 2026-12-08)."""
    found = seed.run.summary.get("agent_params_sha256")
    return None if found is None else found[seed.index]


def same_networks(control: Point, treatment: Point) -> dict | None:
    """How many seeds ended with the same networks, bit for bit, in both points; None where a
    run does not record them."""
    hashes = [{s: _networks_sha256(r) for s, r in p.seeds.items()} for p in (control, treatment)]
    if any(h is None for found in hashes for h in found.values()):
        return None
    seeds = sorted(set(hashes[0]) & set(hashes[1]))
    return dict(
        seeds=len(seeds), identical_seeds=[s for s in seeds if hashes[0][s] == hashes[1][s]]
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("control", type=Path)
    parser.add_argument("treatment", type=Path)
    parser.add_argument("--eval-seed", type=int, default=None)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    given = sys.argv[1:] if argv is None else argv
    command = writing.command_line("experiments/paired_runs.py", given)
    print(write_pairing(args.control, args.treatment, args.out, command, args.eval_seed)[1])
    return 0


def write_pairing(
    control_path: Path,
    treatment_path: Path,
    out: Path,
    command: str,
    eval_seed: int | None = None,
    name: str = "paired",
) -> tuple[dict, str]:
    """``out``/``name``.json and .md: ``compare`` and ``same_episodes`` of the two runs; returns
    what each file holds (the JSON record, the page)."""
    control = the_point(control_path, eval_seed)
    treatment = the_point(treatment_path, eval_seed)
    rows = compare(control, treatment)
    episodes = same_episodes(control, treatment)
    out.mkdir(parents=True, exist_ok=True)
    record = dict(agent=control.agent, control=str(control_path), treatment=str(treatment_path),
                  arenas=rows)  # fmt: skip
    if episodes is not None:
        record["same_episodes"] = episodes
    if (networks := same_networks(control, treatment)) is not None:
        record["same_networks"] = networks
    atomic_write_json(out / f"{name}.json", record)
    table = "\n".join(writing.markdown_table(
        ("arena", "control success (%)", "treatment success (%)", "treatment − control", "verdict"),
        [(a, r["control"], r["treatment"], r["difference"], r["verdict"]) for a, r in rows.items()],
        align="l",
    ))  # fmt: skip
    text = (
        f"# {control.agent}: {treatment_path} against {control_path}\n\n"
        f"Same agent, settings, {len(control.seeds)} seeds and evaluation episodes; success, "
        "mean ± 95 % interval; the difference paired by seed.\n\n"
        f"{table}\n\n{_episodes_line(episodes)}{_networks_line(networks)}Command: `{command}`\n"
    )
    (out / f"{name}.md").write_text(text)
    return record, text


def _episodes_line(episodes: dict | None) -> str:
    if episodes is None:
        return ""
    n_same, n = len(episodes["identical_seeds"]), episodes["seeds"]
    names = ", ".join(name.replace("_", " ") for name in episodes["arrays"])
    return f"Training episodes ({names}), every one equal: {n_same} of {n} seeds.\n\n"


def _networks_line(networks: dict | None) -> str:
    if networks is None:
        return ""
    n_same, n = len(networks["identical_seeds"]), networks["seeds"]
    return f"Final networks (sha256 per seed), bit for bit equal: {n_same} of {n} seeds.\n\n"


if __name__ == "__main__":
    sys.exit(main())
