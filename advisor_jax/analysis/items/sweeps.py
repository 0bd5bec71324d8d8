"""The paper's sweep figures, drawn from whichever points vary the swept settings:

* Fig. 6: success against the advisor's terminal episode N_T (ADDPG+AfD in the paper),
  both arenas; a series per agent type and settings that vary N_T alone.
* Fig. 7: success against N_total, a line per advisor share N_T / N_total (the paper's
  training arena; validation beside it).
* Fig. 11: success against N_total for every agent type, both arenas; the settings that
  scale with the budget (N_T, LfD's and MCP+MF's episode counts) held as shares of it.
* ε: success over the ε_st × b grid, b read as the episode at which ε_st − bN reaches 0
  (N_T / 2, N_T, never, ...).

Every point is mean ± 95 % t interval over seeds with the seeds as dots.
"""

from __future__ import annotations

import math

from advisor_jax.agent.config import preset
from advisor_jax.agent.settings import flat_items
from advisor_jax.analysis.items.base import (
    ARENAS,
    BUDGET_SHARES,
    Item,
    cell,
    figure,
    interval_note,
    key_without,
    markdown_table,
    point_record,
    rank,
    scores,
    seeds_with_ci,
    simulated,
    uses_advisor_data,
)
from advisor_jax.analysis.runs import Point


def _series(points: list[Point], varying: tuple[str, ...], key=None) -> dict:
    """Points grouped by everything but ``varying`` (and the budget when ``varying`` holds
    "episodes"): {key: [points]}, only groups where ``varying`` takes ≥ 2 values."""
    groups: dict[tuple, list[Point]] = {}
    for p in points:
        k = key(p) if key else (key_without(p, varying), p.budget)
        groups.setdefault(k, []).append(p)
    out = {}
    for k, members in groups.items():
        values = {tuple(_value(p, n) for n in varying) for p in members}
        if len(values) >= 2:
            out[k] = sorted(members, key=lambda p: tuple(_value(p, n) for n in varying))
    return dict(sorted(out.items(), key=lambda kv: rank(kv[1][0].agent)))


def _value(point: Point, name: str) -> float:
    return point.budget if name == "episodes" else point.settings[name]


SHARE_NAMES = {"advisor_episodes": "N_T", "demo_episodes": "D", "random_episodes": "R",
               "mpc_episodes": "M", "dagger_episodes": "DAgger"}  # fmt: skip


def _title(point: Point, skip: tuple[str, ...]) -> str:
    """The series' label: its settings but ``skip``, its budget (unless that is the x axis)
    or, along N_total, the budget-scaled counts as shares of it."""
    text = point.text(skip=skip)
    if "episodes" not in skip:
        return text + f", {point.budget} ep"
    shares = [f"{SHARE_NAMES[n]} = {100 * point.settings[n] / point.budget:.0f} %"
              for n in _shares_read(point.agent) if n in skip]  # fmt: skip
    return ", ".join([text, *shares])


def _curve(ax, members: list[Point], x_of, arena: str, color, label: str) -> None:
    xs = [x_of(p) for p in members]
    means = []
    for p, x in zip(members, xs, strict=True):
        values = [100 * v for v in scores(p, arena)]
        seeds_with_ci(ax, x, values, color, width=0.02 * (max(xs) - min(xs) or 1))
        means.append(sum(values) / len(values) if values else math.nan)
    ax.plot(xs, means, color=color, lw=1.2, label=label)


def _sweep_item(name, title, series, x_of, x_label, arenas, skip, lines_of, note):
    fig, axes = figure(1, len(arenas), width=5.5, height=4.2)
    record = {"series": []}
    lines = [note, ""]
    for i, (_, members) in enumerate(series.items()):
        label = _title(members[0], skip)
        record["series"].append({"label": label, "points": [point_record(p) for p in members]})
        for ax, arena in zip(axes[0], arenas, strict=True):
            _curve(ax, members, x_of, arena, f"C{i % 10}", label)
        lines += [f"**{label}**", "", *lines_of(members), ""]
    for ax, arena in zip(axes[0], arenas, strict=True):
        ax.set_xlabel(x_label)
        ax.set_ylabel(f"success, {arena} env (%)")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    # one legend under both panels: inside them it hides the lowest lines' points
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=7)
    fig.suptitle(title, fontsize=10)
    points = [p for members in series.values() for p in members]
    return Item(name, title, record, fig, lines, points)


def _rows(members, first: str, first_of) -> list[str]:
    return markdown_table(
        [first, "seeds", *(f"{a} env (%)" for a in ARENAS)],
        [(first_of(p), len(p.seeds), *(cell(scores(p, a)) for a in ARENAS)) for p in members],
    )


def fig6(points: list[Point], context) -> Item | None:
    afd = [p for p in simulated(points) if uses_advisor_data(p.agent)]
    series = _series(afd, ("advisor_episodes",))
    if not series:
        return None
    return _sweep_item(
        "fig6",
        "Fig. 6: success against the advisor's terminal episode N_T",
        series,
        lambda p: p.settings["advisor_episodes"],
        "N_T (advisor in data collection until N > N_T)",
        ARENAS,
        ("advisor_episodes",),
        lambda m: _rows(
            m,
            "N_T (share of N_total)",
            lambda p: (
                f"{p.settings['advisor_episodes']:g} "
                f"({100 * p.settings['advisor_episodes'] / p.budget:.0f} %)"
            ),
        ),
        f"Evaluation success (%), {interval_note([p for m in series.values() for p in m])}.",
    )


def _shares_read(agent: str) -> tuple[str, ...]:
    """The budget-scaled counts ``agent`` reads: N_T with AfD, a baseline's prior episodes."""
    if agent == "LfD":
        return ("demo_episodes",)
    if agent == "MCP+MF":
        return ("random_episodes", "mpc_episodes", "dagger_episodes")
    return ("advisor_episodes",) if uses_advisor_data(agent) else ()


def _share_key(point: Point) -> tuple:
    """Agent and settings, with the budget-scaled counts it reads as shares of the budget
    (the others, which it ignores, left out)."""
    base = key_without(point, BUDGET_SHARES)
    shares = tuple(round(point.settings[n] / point.budget, 3) for n in _shares_read(point.agent))
    return base, shares


def _by_share(series: dict) -> dict:
    """Series keyed by ``_share_key`` in the order of agent type, then share (25 % first)."""
    return dict(sorted(series.items(), key=lambda kv: (rank(kv[1][0].agent), kv[0][1])))


def fig7(points: list[Point], context) -> Item | None:
    afd = [p for p in simulated(points) if uses_advisor_data(p.agent)]
    series = _by_share(_series(afd, ("episodes",), key=_share_key))
    shares = {round(m[0].settings["advisor_episodes"] / m[0].budget, 3) for m in series.values()}
    if len(shares) < 2:
        return None

    def share(p):
        return f"N_T = {100 * p.settings['advisor_episodes'] / p.budget:.0f} % of N_total"

    return _sweep_item(
        "fig7",
        "Fig. 7: success against N_total per advisor share N_T / N_total",
        series,
        lambda p: p.budget,
        "N_total (training episodes)",
        ARENAS,
        ("episodes", *BUDGET_SHARES),
        lambda m: [share(m[0]), "", *_rows(m, "N_total", lambda p: p.budget)],
        "Evaluation success (%) (the paper's Fig. 7 shows the training arena), "
        f"{interval_note([p for m in series.values() for p in m])}.",
    )


def _program_shares(point: Point) -> tuple:
    """The shares of its preset's budget that the preset gives ``point``'s type (N_T = 250
    of 500 at `stable`: 0.5), in ``_share_key``'s order."""
    static, hp = preset(point.preset, point.agent)
    counts = flat_items(hp)
    return tuple(round(counts[n] / static.episodes, 3) for n in _shares_read(point.agent))


def _at_program_shares(series: dict) -> dict:
    """Of the series that differ only in their shares (Fig. 7's subject), the one at the
    preset's shares where there is one; the others stay where none is."""
    kept = {}
    for base in {k[0] for k in series}:
        group = {k: m for k, m in series.items() if k[0] == base}
        program = {k: m for k, m in group.items() if k[1] == _program_shares(m[0])}
        kept |= program or group
    return {k: m for k, m in series.items() if k in kept}


def fig11(points: list[Point], context) -> Item | None:
    series = _by_share(_series(simulated(points), ("episodes",), key=_share_key))
    series = _at_program_shares(series)
    if not series:
        return None
    return _sweep_item(
        "fig11",
        "Fig. 11: success against the number of training episodes",
        series,
        lambda p: p.budget,
        "N_total (training episodes)",
        ARENAS,
        ("episodes", *BUDGET_SHARES),
        lambda m: _rows(m, "N_total", lambda p: p.budget),
        "Evaluation success (%) of every agent type against its budget (N_T and the "
        "baselines' prior episodes as shares of it, at the preset's shares where several "
        "were run: the others are Fig. 7's), "
        + interval_note([p for m in series.values() for p in m])
        + ".",
    )


def reaches_zero(point: Point) -> str:
    """When ε_st − bN reaches 0, against N_T: ``N_T/2``, ``N_T``, ``never`` or N."""
    start, decay = point.settings["eps_start"], point.settings["eps_decay"]
    if decay == 0:
        return "never"
    at, n_t = start / decay, point.settings["advisor_episodes"]
    for name, value in (("N_T/2", n_t / 2), ("N_T", n_t), ("2 N_T", 2 * n_t)):
        if n_t and math.isclose(at, value, rel_tol=1e-3):
            return name
    return f"N={at:.0f}"


def eps(points: list[Point], context) -> Item | None:
    afd = [p for p in simulated(points) if uses_advisor_data(p.agent)]
    series = _series(afd, ("eps_start", "eps_decay"))
    if not series:
        return None
    fig, axes = figure(len(series), len(ARENAS), width=5.0, height=3.6)
    record, lines = {"series": []}, []
    for row, members in enumerate(series.values()):
        starts = sorted({p.settings["eps_start"] for p in members})
        rules = sorted({reaches_zero(p) for p in members}, key=_rule_order)
        label = _title(members[0], ("eps_start", "eps_decay"))
        record["series"].append(
            {
                "label": label,
                "points": [
                    {**point_record(p), "eps_reaches_zero": reaches_zero(p)} for p in members
                ],
            }
        )
        table = []
        for start in starts:
            cells = []
            for rule in rules:
                match = [
                    p
                    for p in members
                    if p.settings["eps_start"] == start and reaches_zero(p) == rule
                ]
                cells.append(
                    " / ".join(cell(scores(match[0], a)) for a in ARENAS) if match else "–"
                )
            table.append((f"{start:g}", *cells))
        lines += [
            f"**{label}**: success, training / validation env (%)",
            "",
            *markdown_table(["ε_st \\ ε reaches 0 at", *rules], table),
            "",
        ]
        for ax, arena in zip(axes[row], ARENAS, strict=True):
            for j, rule in enumerate(rules):
                for k, start in enumerate(starts):
                    match = [
                        p
                        for p in members
                        if p.settings["eps_start"] == start and reaches_zero(p) == rule
                    ]
                    if match:
                        x = j + (k - (len(starts) - 1) / 2) * 0.25
                        seeds_with_ci(
                            ax,
                            x,
                            [100 * v for v in scores(match[0], arena)],
                            f"C{k}",
                            label=f"ε_st = {start:g}" if j == 0 else None,
                            width=0.1,
                        )
            ax.set_xticks(range(len(rules)), [f"ε = 0 at {r}" for r in rules], fontsize=8)
            ax.set_ylabel(f"success, {arena} env (%)")
            ax.set_ylim(-3, 103)
            ax.grid(alpha=0.3, axis="y")
            ax.set_title(label, fontsize=8)
            ax.legend(fontsize=7)
    note = (
        "Evaluation success (%) over the ε schedule of Eq. 1: ε_st and the decay b, read as "
        "the episode at which ε_st − bN reaches 0 (b = 0: never; the advisor stops at N_T "
        f"whatever ε says), {interval_note([p for m in series.values() for p in m])}."
    )
    points_shown = [p for m in series.values() for p in m]
    return Item(
        "eps", "ε schedule: success over ε_st × b", record, fig, [note, "", *lines], points_shown
    )


def _rule_order(rule: str) -> tuple:
    named = {"N_T/2": 0, "N_T": 1, "2 N_T": 2, "never": 9}
    return (named.get(rule, 5), rule)
