"""``advisor-jax report`` on hand-made runs: which items appear, their numbers, the refusals."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from advisor_jax import stats
from advisor_jax.analysis.items.sweeps import reaches_zero
from advisor_jax.analysis.report import make_report
from advisor_jax.analysis.runs import load_runs, pool
from advisor_jax.cli.main import main
from tests.analysis.fake_runs import write_run

T_975_3 = 3.182446305284263  # Student-t 97.5 % quantile, 3 degrees of freedom


@pytest.fixture
def runs(tmp_path):
    root = tmp_path / "runs"
    write_run(root, "addpg", "ADDPG", [0, 1, 2, 3], [0.6, 0.7, 0.8, 0.9])
    write_run(root, "ddpg", "DDPG", [0, 1, 2, 3], [0.5, 0.7, 0.6, 0.8])
    write_run(root, "ddpg_noclip", "DDPG", [0, 1, 2, 3], [0.4, 0.5, 0.6, 0.5],
              hp={"clip_q_target": 0.0})  # fmt: skip
    write_run(root, "afd", "ADDPG+AfD", [0, 1, 2], [0.5, 0.6, 0.7],
              hp={"advisor_episodes": 0.0})  # fmt: skip
    write_run(root, "afd250", "ADDPG+AfD", [0, 1, 2], [0.7, 0.8, 0.9])
    return root


@pytest.fixture
def saved_figures(monkeypatch):
    """{file name: matplotlib figure} of every PNG a report writes in the test."""
    import advisor_jax.analysis.report as report

    figures = {}
    real_save = report.save_png

    def keep(fig, path, **kwargs):
        figures[path.name] = fig
        return real_save(fig, path, **kwargs)

    monkeypatch.setattr(report, "save_png", keep)
    return figures


def test_table1_rows_and_the_papers_claim_seed_by_seed(runs, tmp_path):
    out = tmp_path / "report"
    make_report([runs], out, items=["table1"], command="advisor-jax report runs", say=lambda m: 0)
    record = json.loads((out / "table1.json").read_text())
    assert record["item"] == "table1" and (out / "table1.png").is_file()
    rows = {(p["agent"], json.dumps(p["settings"])): p for p in record["points"]}
    ddpg = rows[("DDPG", "{}")]
    assert ddpg["seeds"] == 4 and ddpg["training"]["mean"] == pytest.approx(0.65)
    sd = math.sqrt(sum((v - 0.65) ** 2 for v in (0.5, 0.7, 0.6, 0.8)) / 3)
    half = T_975_3 * sd / 2
    assert ddpg["training"]["ci95"] == pytest.approx([0.65 - half, 0.65 + half])
    assert ddpg["training"]["iqm"] == pytest.approx(0.65)  # mean of 0.6, 0.7
    (claim,) = [c for c in record["claims"] if c["better"] == "ADDPG" and c["worse"] == "DDPG"]
    # ADDPG - DDPG per seed: +10, 0, +20, +10 points; P(ADDPG > DDPG) over the 16 pairs
    assert claim["training"]["mean"] == pytest.approx(10.0)
    gt = sum(a > b for a in (0.6, 0.7, 0.8, 0.9) for b in (0.5, 0.7, 0.6, 0.8))
    eq = sum(a == b for a in (0.6, 0.7, 0.8, 0.9) for b in (0.5, 0.7, 0.6, 0.8))
    assert claim["training"]["probability_of_improvement"] == pytest.approx((gt + eq / 2) / 16)
    assert record["provenance"]["training_commands"][0].startswith("advisor-jax train")
    assert record["provenance"]["evaluation"] == [[0, 50]]


def test_settings_compared_seed_by_seed_and_items_without_points_skipped(runs, tmp_path):
    out, said = tmp_path / "report", []
    make_report([runs], out, versus_settings=["clip_q_target=1"], say=said.append)
    pairs = json.loads((out / "versus.json").read_text())["pairs"]
    (pair,) = pairs
    assert (pair["agent"], pair["treatment_value"], pair["control_value"]) == ("DDPG", "1", "0")
    assert pair["difference"]["training"]["mean"] == pytest.approx(15.0)  # +10 +20 0 +30
    assert (out / "fig6.json").is_file()  # ADDPG+AfD at two values of N_T
    assert "note: table2: skipped, no points it applies to" in said
    assert not (out / "table2.json").exists()
    text = (out / "report.md").read_text()
    assert "## Fig. 6" in text and "table2: skipped" in text
    for path in out.glob("*.json"):  # strict JSON: no NaN or Infinity
        assert "NaN" not in path.read_text() and "Infinity" not in path.read_text()


def test_eps_decay_is_read_as_where_epsilon_reaches_zero(tmp_path):
    for name, start, decay in (("h", 1.0, 0.008), ("n", 0.5, 0.002), ("z", 1.0, 0.0)):
        write_run(tmp_path, name, "ADDPG+AfD", [0], [0.5],
                  hp={"eps_start": start, "eps_decay": decay})  # fmt: skip
    points, _ = pool(load_runs([tmp_path]))
    rules = {(p.settings["eps_start"], p.settings["eps_decay"]): reaches_zero(p) for p in points}
    assert rules == {(1.0, 0.008): "N_T/2", (0.5, 0.002): "N_T", (1.0, 0.0): "never"}


def test_the_command_refuses_runs_on_other_episodes_in_one_line(tmp_path, capsys):
    write_run(tmp_path, "a", "DDPG", [0], [0.8], eval_seed=0)
    write_run(tmp_path, "b", "DDPG", [1], [0.7], eval_seed=8)
    with pytest.raises(SystemExit) as exit_:
        main(["report", str(tmp_path), "--out", str(tmp_path / "r")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "different episodes" in err and "Traceback" not in err
    with pytest.raises(SystemExit):
        main(["report", str(tmp_path), "--out", str(tmp_path / "r"), "--items", "fig12"])
    assert "unknown item 'fig12'" in capsys.readouterr().err


def test_budget_figures_hold_the_advisor_share_and_eps_its_grid(tmp_path):
    for n in (100, 200):
        for share in (0.25, 0.5):
            write_run(tmp_path, f"afd{n}_{share}", "ADDPG+AfD", [0, 1, 2], [0.5, 0.6, share],
                      episodes=n, hp={"advisor_episodes": share * n})  # fmt: skip
        write_run(tmp_path, f"ddpg{n}", "DDPG", [0, 1, 2], [0.4, 0.5, n / 400], episodes=n)
    for name, start, decay in (("h", 1.0, 0.008), ("n", 1.0, 0.004), ("z", 1.0, 0.0)):
        write_run(tmp_path, name, "ADDPG+AfD", [0, 1, 2], [0.5, 0.6, 0.7],
                  hp={"eps_start": start, "eps_decay": decay})  # fmt: skip
    out = tmp_path / "report"
    make_report([tmp_path], out, items=["fig7", "fig11", "eps"], say=lambda m: 0)
    fig7 = json.loads((out / "fig7.json").read_text())
    budgets = [[p["episodes"] for p in s["points"]] for s in fig7["series"]]
    assert budgets == [[100, 200], [100, 200]]  # one line per share, N_total along it
    shares = [s["label"] for s in fig7["series"]]
    assert len(shares) == 2 and "25 %" in shares[0] and "50 %" in shares[1]
    fig11 = json.loads((out / "fig11.json").read_text())
    afd = [s["label"] for s in fig11["series"] if s["label"].startswith("ADDPG+AfD")]
    assert len(afd) == 1 and "N_T = 50 %" in afd[0]  # the preset's share; 25 % is Fig. 7's
    ddpg = [s for s in fig11["series"] if s["label"].startswith("DDPG")]
    assert [p["training"]["per_seed"][2] for p in ddpg[0]["points"]] == [0.25, 0.5]
    eps = json.loads((out / "eps.json").read_text())
    rules = [p["eps_reaches_zero"] for p in eps["series"][0]["points"]]
    assert sorted(rules) == ["N_T", "N_T/2", "never"]
    assert all((out / f"{n}.png").is_file() for n in ("fig7", "fig11", "eps"))


def test_a_claim_pairs_the_row_that_agrees_on_every_shared_setting(tmp_path):
    """ATD3+AfDP at policy delay 2 in bf16 meets LfD in bf16 (not LfD at the preset's fp32,
    which agrees on fewer settings), and the claim names the policy delay as what differs."""
    from advisor_jax.analysis.items.table1 import claims, rows_of
    from advisor_jax.analysis.runs import load_runs, pool

    write_run(tmp_path, "atd3", "ATD3+AfDP", [0, 1, 2], [0.9, 0.8, 0.85], policy_delay=2,
              precision="bf16")  # fmt: skip
    write_run(tmp_path, "lfd_bf16", "LfD", [0, 1, 2], [0.6, 0.7, 0.65], precision="bf16")
    write_run(tmp_path, "lfd_kin", "LfD", [0, 1, 2], [0.95, 0.95, 0.95])
    found = [c for c in claims(rows_of(pool(load_runs([tmp_path]))[0]))
             if c["kind"] == "over baseline"]  # fmt: skip
    assert len(found) == 1
    assert "precision=bf16" in found[0]["worse"] and found[0]["differs"] == ["policy_delay"]
    assert found[0]["training"]["mean"] == pytest.approx(100 * (0.85 - 0.65))


def test_every_figure_labels_its_axes(runs, tmp_path, saved_figures):
    """Every panel with data has an x and a y label (issue 38: plots without y labels)."""
    figures = saved_figures
    make_report([runs], tmp_path / "report", versus_settings=["clip_q_target=1"],
                say=lambda m: 0)  # fmt: skip
    assert len(figures) >= 3
    for name, fig in figures.items():
        for ax in fig.axes:
            if ax.get_visible() and (ax.lines or ax.collections or ax.patches):
                assert ax.get_xlabel() or ax.get_xticklabels(), (name, ax.get_title())
                assert ax.get_ylabel(), (name, ax.get_title())


def test_advisor_quality_plots_agents_against_their_advisors_own_success(tmp_path):
    root, teacher = tmp_path / "runs", "experiments/paper/advisors/teacher"
    for name, knob, own, agent_success in (("r0", 0.0, 0.55, 0.80), ("r3", 0.3, 0.35, 0.70)):
        write_run(root, f"afd_{name}", "ADDPG+AfD", [0, 1, 2, 3],
                  [agent_success + d for d in (0.0, 0.02, -0.02, 0.04)],
                  hp={"advisor_random": knob}, advisor_success=[own] * 4,
                  snapshots={100: [0.4, 0.5, 0.45, 0.5]})  # fmt: skip
    write_run(root, "afd_teacher", "ADDPG+AfD", [0, 1, 2, 3], [0.9, 0.92, 0.88, 0.9],
              advisor=teacher, advisor_success=[0.85] * 4)  # fmt: skip
    write_run(root, "addpg", "ADDPG", [0, 1, 2, 3], [0.75, 0.75, 0.75, 0.79],
              advisor_success=[0.55] * 4, snapshots={100: [0.3, 0.3, 0.3, 0.3]})  # fmt: skip
    write_run(root, "lfd", "LfD", [0, 1, 2, 3], [0.6, 0.6, 0.7, 0.7], advisor_success=[0.55] * 4)
    out = tmp_path / "report"
    make_report([root], out, items=["advisor_quality"], say=lambda _: None)
    record = json.loads((out / "advisor_quality.json").read_text())
    final = next(s for s in record["series"] if s["agent"] == "ADDPG+AfD" and s["budget"] == 500)
    labels = [a["label"] for a in final["advisors"]]
    assert labels == ["rule, advisor_random=0.3", "rule", "teacher"]  # by the advisor's success
    assert [a["advisor_success"]["training"] for a in final["advisors"]] == [0.35, 0.55, 0.85]
    assert final["advisors"][2]["advisor_success"]["validation"] == pytest.approx(0.75)
    assert final["control"]["agent"] == "ADDPG"
    versus = final["advisors"][1]["versus_control"]["training"]  # rule: +5, +7, +3, +5 points
    assert versus["mean"] == pytest.approx(5.0) and versus["verdict"] == "holds"
    assert final["advisors"][0]["versus_control"]["training"]["verdict"] == "reversed"
    early = next(s for s in record["series"] if s["agent"] == "ADDPG+AfD" and s["budget"] == 100)
    assert [a["label"] for a in early["advisors"]] == ["rule, advisor_random=0.3", "rule"]
    assert early["control"]["training"]["mean"] == pytest.approx(0.3)
    lfd = next(s for s in record["series"] if s["agent"] == "LfD")
    assert lfd["control"] is None  # no DDPG among the runs
    assert (out / "advisor_quality.png").is_file()
    assert "agent − control, training (points)" in (out / "report.md").read_text()


def test_fig10_gives_the_firing_rate_as_a_share_of_eq11_per_point(tmp_path, saved_figures):
    """Fig. 10's number is the firing rate / Eq. (11) over episodes w..N_T (here 0.3 / 0.6,
    by hand), listed per point with its budget; the figure draws one run per type and the
    share of every point against N_T."""
    import numpy as np

    from advisor_jax.analysis.items.curves import FIRING_WINDOW

    episodes = 3 * FIRING_WINDOW
    for n_t in (FIRING_WINDOW * 2, FIRING_WINDOW * 3):
        run = tmp_path / f"afd{n_t}"
        write_run(tmp_path, run.name, "ADDPG+AfD", [0, 1], [0.5, 0.6], episodes=episodes,
                  hp={"advisor_episodes": float(n_t)}, outcome=np.zeros((2, episodes)))  # fmt: skip
        metrics = dict(np.load(run / "metrics.npz"))
        metrics["firing_rate"] = np.full((2, episodes), 0.3)
        metrics["expected_max_firing_rate"] = np.full((2, episodes), 0.6)
        np.savez(run / "metrics.npz", **metrics)
    figures = saved_figures
    out = tmp_path / "report"
    make_report([tmp_path], out, items=["fig10"], say=lambda m: 0)
    series = json.loads((out / "fig10.json").read_text())["series"]
    assert [s["share_of_expected_before_N_T"] for s in series] == pytest.approx([0.5, 0.5])
    text = (out / "report.md").read_text()
    assert f"advisor_episodes={2 * FIRING_WINDOW}, {episodes} ep: 0.50" in text
    left, right = figures["fig10.png"].axes[:2]
    assert len([ln for ln in left.lines if ln.get_xydata().size]) == 2  # one run: rate, Eq. 11
    drawn = [ln.get_xydata() for ln in right.lines if ln.get_xydata().size]
    assert len(drawn) == 1 and drawn[0].tolist() == [
        [2 * FIRING_WINDOW, 0.5],
        [3 * FIRING_WINDOW, 0.5],
    ]


def test_every_item_json_lists_its_points_flat(runs, tmp_path):
    """Each item's JSON has a flat ``points`` list (agent, budget, settings, seeds, and per
    arena the mean with its 95 % t interval), whatever its own layout."""
    out = tmp_path / "report"
    make_report([runs], out, items=["fig6"], say=lambda m: 0)
    points = json.loads((out / "fig6.json").read_text())["points"]
    row = next(p for p in points if p["settings"] == {"advisor_episodes": 0.0})
    assert (row["agent"], row["seeds"]) == ("ADDPG+AfD", 3)
    half = 4.302652729911275 * 0.1 / math.sqrt(3)  # t(0.975, 2 dof) × sd / √n, by hand
    assert row["training"]["mean"] == pytest.approx(0.6)
    assert row["training"]["ci95"] == pytest.approx([0.6 - half, 0.6 + half])
    assert row["validation"]["mean"] == pytest.approx(0.5)


def test_item_json_floats_keep_six_significant_digits(runs, tmp_path):
    """Floats in an item's JSON are rounded to six significant digits (float32 run data
    holds no more), numpy scalars and arrays included, and NaN is written as null."""
    from advisor_jax.analysis.report import _strict

    assert _strict(0.5349999908357859) == 0.535
    assert _strict({"a": (np.float32(0.1), np.array([1 / 3, 2e-9]))}) == {
        "a": [0.1, [0.333333, 2e-9]]
    }
    assert _strict([math.nan, math.inf, 7, True]) == [None, None, 7, True]
    out = tmp_path / "report"
    make_report([runs], out, items=["fig6"], say=lambda m: 0)
    numbers = re.findall(r"-?\d+\.\d+(?:e-?\d+)?", (out / "fig6.json").read_text())
    assert numbers and all(
        len(n.lstrip("-0.").replace(".", "").split("e")[0]) <= 6 for n in numbers
    )


def test_a_skipped_item_says_when_the_runs_were_scored_in_one_arena(tmp_path):
    """Runs evaluated in the training arena only: Table 1 is skipped, and the note says why
    and what to train with."""
    write_run(tmp_path / "runs", "a", "DDPG", [0, 1, 2], [0.8, 0.6, 0.7], arenas=("training",))
    said = []
    make_report([tmp_path / "runs"], tmp_path / "r", items=["table1"], say=said.append)
    (note,) = [line for line in said if "table1: skipped" in line]
    assert "1 point(s), e.g. DDPG, were evaluated in one arena only" in note
    assert "--eval-arenas training validation" in note


def test_up_to_twenty_lines_in_one_legend_have_twenty_colours():
    from matplotlib.colors import to_hex

    from advisor_jax.analysis.items.base import line_colour

    assert [line_colour(i, 10) for i in range(10)] == [f"C{i}" for i in range(10)]
    assert len({to_hex(line_colour(i, 17)) for i in range(17)}) == 17  # Table 1 with brax


def _with_outcomes(root, names):
    """Per-episode outcomes in the runs ``names`` below ``root``: seed k's success v as
    round(50 v) goals first, then collisions (every agent fails the last episodes)."""
    for name in names:
        path = root / name / "run.json"
        summary = json.loads(path.read_text())
        for ev in summary["evaluation"].values():
            n = ev["episodes"]
            ev["outcomes"] = ["1" * round(n * v) + "2" * (n - round(n * v)) for v in ev["success"]]
        path.write_text(json.dumps(summary))


def test_table1_adds_the_interval_for_new_episodes_where_every_row_has_outcomes(runs, tmp_path):
    def report(name):
        out = tmp_path / name
        make_report([runs], out, items=["table1"], command="report", say=lambda m: 0)
        return (out / "report.md").read_text(), json.loads((out / "table1.json").read_text())

    text, _ = report("none")
    assert "new seeds and new evaluation episodes" not in text  # runs before outcomes
    _with_outcomes(runs, ["addpg", "ddpg", "ddpg_noclip", "afd"])
    text, _ = report("some")
    assert "new seeds and new evaluation episodes" not in text  # afd250 has none
    _with_outcomes(runs, ["afd250"])
    text, record = report("all")
    assert "new seeds and new evaluation episodes" in text
    ddpg = next(p for p in record["points"] if p["agent"] == "DDPG" and not p["settings"])
    successes = np.array([[1.0] * round(50 * v) + [0.0] * (50 - round(50 * v))
                          for v in (0.5, 0.7, 0.6, 0.8)])  # fmt: skip
    want = stats.seeds_and_episodes_interval(successes)
    got = ddpg["training"]["seeds_and_episodes"]
    assert got["mean"] == pytest.approx(0.65) and got["ci95"] == pytest.approx(
        [want.low, want.high]
    )
    assert f"| DDPG | {stats.format_interval(want, scale=100)} |" in text
