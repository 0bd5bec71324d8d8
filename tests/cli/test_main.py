"""The ``advisor-jax`` console script's ``arena`` and ``evaluate`` commands and its errors
(cli/main.py): files written, JSON output, one-line errors with exit status 2."""

from __future__ import annotations

import json

import mujoco
import numpy as np
import pytest

import envs
from advisor_jax.cli import main as cli
from advisor_jax.training.population import seed_key


def _run(argv, capsys):
    try:
        cli.main(argv)
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_cli_arena_writes_loadable_xml(tmp_path, capsys):
    path = tmp_path / "training.xml"
    code, _, _ = _run(["arena", "training", "--xml", str(path)], capsys)
    assert code == 0
    model = mujoco.MjModel.from_xml_path(str(path))
    assert model.nsensor == 16


def test_cli_procedural_seed_writes_that_seeds_layout(tmp_path, capsys):
    """The layout of ``env.layout_boxes(seed_key(3))``, which is the first episode's of
    ``reset`` with that key (tests/envs/test_env_config.py)."""
    path = tmp_path / "p.xml"
    assert _run(["arena", "procedural", "--seed", "3", "--xml", str(path)], capsys)[0] == 0
    model = mujoco.MjModel.from_xml_path(str(path))
    first = envs.make_env("procedural").layout_boxes(seed_key(3))
    for i, (cx, cy, hx, hy, _) in enumerate(np.asarray(first)):
        geom = model.geom(f"box{i}")
        np.testing.assert_allclose(geom.pos[:2], (cx, cy), atol=1e-5)
        np.testing.assert_allclose(geom.size[:2], (hx, hy), atol=1e-5)


def test_cli_arena_creates_no_directories(tmp_path, capsys):
    """A typo in the directory is one line, and nothing is created (it used to make every
    missing directory silently)."""
    target = tmp_path / "new" / "dir" / "arena.xml"
    code, _, err = _run(["arena", "training", "--xml", str(target)], capsys)
    assert code == 2 and "Traceback" not in err
    assert f"the directory {target.parent} does not exist" in err
    assert not (tmp_path / "new").exists()
    target.parent.mkdir(parents=True)
    assert _run(["arena", "training", "--xml", str(target)], capsys)[0] == 0
    assert mujoco.MjModel.from_xml_path(str(target)).nsensor == 16
    assert [p.name for p in target.parent.iterdir()] == ["arena.xml"]  # no temporary left


def test_cli_unwritable_path_is_a_one_line_error(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    target = blocker / "arena.xml"
    code, out, err = _run(["arena", "training", "--xml", str(target)], capsys)
    assert code == 2 and out == ""
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines[-1] == f"error: cannot write {target}: {blocker} is not a directory"
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["arena", "nowhere", "--xml", "x.xml"], "unknown arena 'nowhere'"),
        (["evaluate", "--policy", "oracle"], "--policy oracle: oracle does not exist"),
        (["evaluate", "--episodes", "0"], "--episodes must be a positive integer"),
        (["evaluate", "--hp", "beta=1"], "--hp beta: not an advisor quality knob"),
        (["evaluate", "--hp", "advisor_delay=2.5"], "advisor_delay=2.5 is not one of the"),
        (["evaluate", "--policy", "runs/x", "--hp", "advisor_noise=1"], "use them with --policy"),
        (["evaluate", "--advisor", "nowhere:thing"], "no module named 'nowhere'"),
        (["train", "--advisor", "no/such/run"], "unknown advisor 'no/such/run'"),
    ],
)
def test_cli_bad_values_exit_2_with_a_message(argv, needle, capsys):
    code, _, err = _run(argv, capsys)
    assert code == 2 and needle in err and "Traceback" not in err
    if "arena" in needle:
        assert "training, validation, physical, procedural" in err


def test_cli_evaluate_json(capsys):
    code, out, _ = _run(["evaluate", "--arena", "training", "--episodes", "8", "--json"], capsys)
    assert code == 0
    result = json.loads(out)
    assert result["episodes"] == 8 and result["policy"] == "advisor"
    total = result["success_rate"] + result["collision_rate"] + result["timeout_rate"]
    assert total == pytest.approx(1.0)
    assert result["advisor"]["spec"] == "rule" and result["quality"]["advisor_random"] == 0.0
    code, out, _ = _run(["evaluate", "--episodes", "8", "--json", "--hp", "advisor_random=1"],
                        capsys)  # fmt: skip
    randomly = json.loads(out)  # the same episodes, the advisor acting at random
    assert code == 0 and randomly["quality"]["advisor_random"] == 1.0
    assert randomly["mean_length"] != result["mean_length"]


def test_cli_help_lists_subcommands(capsys):
    code, out, _ = _run(["--help"], capsys)
    assert code == 0 and "arena" in out and "evaluate" in out


def test_train_help_reads_at_80_columns(capsys, monkeypatch):
    """One paragraph per option (tyro kept the docstrings' line breaks: mid-sentence breaks
    at 80 columns), one form per flag, a metavar for optional numbers, no empty default."""
    from advisor_jax.cli.helptext import _field_docstrings
    from advisor_jax.training.request import TrainArgs

    monkeypatch.setenv("COLUMNS", "80")
    code, narrow, _ = _run(["train", "--help"], capsys)
    assert code == 0
    for bad in ("--no-no-", "{None}", "(default: )"):
        assert bad not in narrow, bad
    boxed = [line for line in narrow.splitlines() if line[:1] in "│╭╰"]
    assert boxed and max(len(line) for line in boxed) <= 80
    monkeypatch.setenv("COLUMNS", "400")
    wide = _run(["train", "--help"], capsys)[1].splitlines()
    for name, doc in _field_docstrings(TrainArgs).items():
        text = " ".join(doc.split())
        if len(text) < 300:  # fits one line at 400 columns: it must be on one
            assert any(text in line for line in wide), name


def test_hp_without_a_value_answers_with_the_hp_syntax(capsys):
    code, _, err = _run(["train", "--hp", "beta"], capsys)
    assert code == 2 and "--hp expects NAME=VALUE, e.g. --hp beta=0.1, got 'beta'" in err
    code, _, err = _run(["train", "--grid", "beta"], capsys)
    assert code == 2 and "--grid expects NAME=V1,V2,..." in err


@pytest.mark.parametrize("command", ["sweep", "report", "evaluate", "export", "reevaluate"])
def test_no_help_shows_an_empty_default(command, capsys):
    code, out, _ = _run([command, "--help"], capsys)
    assert code == 0 and "(default: )" not in out and "{None}" not in out


def test_reevaluate_writes_eval_seed_files_where_asked(tmp_path, capsys, monkeypatch):
    """``advisor-jax reevaluate RUN... --eval-seed S`` writes eval_seed<S>.json into each run
    (or OUT/<run name>) from training.run_directory.reevaluate (tested on a real run in
    tests/training/test_run.py), and says where, with the mean success."""
    from advisor_jax.training import run_directory

    calls = []

    def score_again(run, eval_seed, episodes, arenas):
        calls.append((run.name, eval_seed, episodes, arenas))
        return {"training": {"success": [0.5, 1.0], "episodes": episodes}}

    monkeypatch.setattr(run_directory, "reevaluate", score_again)
    runs = [tmp_path / "a", tmp_path / "b"]
    argv = ["reevaluate", *map(str, runs), "--eval-seed", "8", "--episodes", "20"]
    code, _, err = _run(argv, capsys)
    assert code == 0 and calls == [("a", 8, 20, ()), ("b", 8, 20, ())]
    written = json.loads((tmp_path / "b" / "eval_seed8.json").read_text())
    assert written["training"]["success"] == [0.5, 1.0]
    assert "eval_seed8.json: eval seed 8, mean success % training 75.0" in " ".join(err.split())
    code, _, _ = _run(["reevaluate", str(runs[0]), "--eval-seed", "3", "--arenas",
                       "validation", "--out", str(tmp_path / "o")], capsys)  # fmt: skip
    assert code == 0 and calls[-1] == ("a", 3, 100, ("validation",))
    assert (tmp_path / "o" / "a" / "eval_seed3.json").is_file()
    code, _, err = _run(["reevaluate", "--eval-seed", "3"], capsys)
    assert code == 2 and "name at least one finished run directory" in err
