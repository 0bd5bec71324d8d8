"""Study files: groups, points and expressions, and the one-line errors before any compile."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from advisor_jax.study.spec import StudyError, evaluate, load_study

ROOT = Path(__file__).resolve().parents[2]


def study(tmp_path, text: str, name: str = "s.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return load_study(path)


HEAD = """
[study]
preset = "quick"
agents = ["ADDPG+AfD"]
seeds = 2
"""


def test_the_quick_study_reads():
    s = load_study(ROOT / "experiments" / "studies" / "quick.toml")
    assert [g.agent for g in s.groups] == ["DDPG", "ADDPG+AfD"]
    assert s.seeds == (0, 1, 2) and s.eval_seed == 0
    assert s.groups[1].points == ({"advisor_episodes": 0.0}, {"advisor_episodes": 15.0})
    assert s.groups[1].written[1] == {"advisor_episodes": "0.5 * episodes"}


def test_shares_of_n_total_follow_each_static_combination(tmp_path):
    s = study(
        tmp_path,
        HEAD
        + """
        [static]
        episodes = [20, 40]
        [grid]
        advisor_episodes = ["0.25 * episodes", "episodes"]
    """,
    )
    assert [g.static for g in s.groups] == [{"episodes": 20}, {"episodes": 40}]
    assert [p["advisor_episodes"] for g in s.groups for p in g.points] == [5, 20, 10, 40]


def test_eps_decay_reaching_zero_at_half_n_t_at_n_t_and_never(tmp_path):
    s = study(
        tmp_path,
        HEAD
        + """
        [hp]
        advisor_episodes = 20
        [grid]
        eps_start = [0.5, 1.0]
        eps_decay = ["eps_start / (advisor_episodes / 2)", "eps_start / advisor_episodes", 0]
    """,
    )
    decays = [(p["eps_start"], p["eps_decay"]) for p in s.groups[0].points]
    assert decays == [(0.5, 0.05), (0.5, 0.025), (0.5, 0.0), (1.0, 0.1), (1.0, 0.05), (1.0, 0.0)]
    assert s.groups[0].hp == {"advisor_episodes": 20.0}


def test_expressions():
    assert evaluate("(1 + 2) * 3 / 4 - -1", {}) == 3.25
    assert evaluate("0.5 * episodes", {"episodes": 500}) == 250
    for bad in ("__import__('os')", "episodes ** 2", "x[0]", "1 +"):
        with pytest.raises(ValueError):
            evaluate(bad, {"episodes": 1, "x": 1})


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[grid]\nbta = [1, 2]", r"\[grid\] bta: unknown hyperparameter"),
        ("[grid]\nbeta = [1, -2]", r"beta=-2 is outside"),
        ("[grid]\nepisodes = [10, 20]", r"episodes is a static setting .* under \[static\]"),
        ("[static]\nbeta = 1", r"beta is a hyperparameter: put it under \[hp\] or \[grid\]"),
        ("[static]\nepisodes = 20\n[grid]\nadvisor_episodes = [10, 30]",
         r"advisor_episodes = 30 \(N_T\) is beyond episodes = 20 \(N_total\)"),
        ("[grid]\nadvisor_episodes = [\"0.5 * episode\"]", r"unknown name 'episode'"),
        ("[grid]\neps_start = [\"eps_decay\"]\neps_decay = [\"eps_start\"]", r"cycle"),
        ("[grid]\nbeta = 1", r"give a non-empty list"),
        ("[hp]\nbeta = 1\n[grid]\nbeta = [1, 2]", r"beta is in both \[hp\] and \[grid\]"),
        ("[static]\nprecision = \"fp16\"", r"precision"),
        ("[extra]\nx = 1", r"unknown table \[extra\]"),
        ("[agent.\"DDPG\".grid]\nbeta = [1]", r"not one of \[study\] agents"),
        ("[grid]\nadvisor_episodes = [\"1 / 0\"]", r"divides by zero"),
    ],
)  # fmt: skip
def test_bad_studies_are_one_line_errors_naming_the_value(tmp_path, text, message):
    with pytest.raises(StudyError, match=message) as err:
        study(tmp_path, HEAD + text)
    assert "\n" not in str(err.value)
    assert str(err.value).startswith(str(tmp_path / "s.toml"))


def test_missing_keys_unknown_agents_and_toml_errors(tmp_path):
    with pytest.raises(StudyError, match=r"\[study\] needs seeds"):
        study(tmp_path, '[study]\npreset = "quick"\nagents = ["DDPG"]')
    with pytest.raises(StudyError, match="unknown agent 'DDGP'"):
        study(tmp_path, '[study]\npreset = "quick"\nagents = ["DDGP"]\nseeds = 1')
    with pytest.raises(StudyError, match="not valid TOML"):
        study(tmp_path, "[study\n")
    with pytest.raises(StudyError, match="cannot read study"):
        load_study(tmp_path / "missing.toml")


def test_a_baseline_setting_for_another_agent_is_refused(tmp_path):
    with pytest.raises(StudyError, match="unknown baseline setting demo_episodes"):
        study(tmp_path, HEAD + "[hp]\ndemo_episodes = 10")


def test_the_digest_ignores_comments_and_sees_values(tmp_path):
    a = study(tmp_path, HEAD + "[grid]\nbeta = [1, 2]", "a.toml")
    b = study(tmp_path, HEAD + "# a comment\n[grid]\nbeta = [1, 2]", "b.toml")
    c = study(tmp_path, HEAD + "[grid]\nbeta = [1, 3]", "c.toml")
    assert a.digest == b.digest != c.digest


def test_the_advisor_quality_study_reads(monkeypatch):
    """Two advisors × three qualities for the advised types, one point for each control,
    every advisor evaluated alone; a study without eval_advisor keeps the digest it had."""
    import dataclasses
    import hashlib
    import json

    monkeypatch.chdir(ROOT)  # the trained advisor's path is relative to the repository
    s = load_study(ROOT / "experiments" / "paper" / "advisor_quality.toml")
    assert s.eval_advisor and s.eval_episodes == 500 and len(s.seeds) == 16
    advised = [g for g in s.groups if g.agent in ("ADDPG+AfD", "ADDPG+AfP", "ATD3+AfDP", "LfD")]
    assert len(advised) == 8 and all(len(g.points) == 3 for g in advised)
    assert {g.static["advisor"] for g in advised} == {
        "rule", "experiments/paper/advisors/atd3_quick_300ep"
    }  # fmt: skip
    controls = [g for g in s.groups if g not in advised]
    assert [(g.agent, g.static["advisor"], g.points) for g in controls] == [
        (a, "rule", ({"advisor_random": 0.0},)) for a in ("ADDPG", "ATD3", "DDPG")
    ]
    cfg, _, _ = s.config(advised[1])
    assert cfg.advisor == "experiments/paper/advisors/atd3_quick_300ep"
    quick = load_study(ROOT / "experiments" / "studies" / "quick.toml")
    record = {k: v for k, v in dataclasses.asdict(quick).items()
              if k not in ("path", "name", "eval_advisor")}  # fmt: skip
    text = json.dumps(record, sort_keys=True, default=str)
    assert quick.digest == hashlib.sha256(text.encode()).hexdigest()[:16]
    assert dataclasses.replace(quick, eval_advisor=True).digest != quick.digest


def test_an_unknown_advisor_is_named(tmp_path):
    with pytest.raises(StudyError, match="unknown advisor 'no/such/run:0'"):
        study(tmp_path, HEAD + '[static]\nadvisor = "no/such/run:0"\n')
