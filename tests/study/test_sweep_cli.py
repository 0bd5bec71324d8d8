"""``advisor-jax sweep`` without training: --dry-run, --slurm, the kept plan, one-line errors."""

from __future__ import annotations

import dataclasses
import json
import re
import textwrap
from pathlib import Path

import pytest

from advisor_jax.cli.main import main
from advisor_jax.study import plan_file, sweep
from advisor_jax.study.spec import load_study

STUDY = """
[study]
name = "tiny"
preset = "quick"
agents = ["DDPG", "ADDPG+AfD"]
seeds = 2
[static]
episodes = 4
[agent."ADDPG+AfD".grid]
advisor_episodes = [0, 2]
"""


@pytest.fixture
def study_file(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(textwrap.dedent(STUDY))
    return path


def test_dry_run_prints_the_plan_and_writes_nothing(study_file, tmp_path, capsys):
    out = tmp_path / "sweep"
    main(["sweep", str(study_file), "--out", str(out), "--dry-run"])
    err = capsys.readouterr().err
    assert "tiny: 2 pieces, 6 agents" in err
    assert "memory: DDPG (fp32, buffer 20,000, batch 128)" in err
    assert "advisor_episodes=0 | advisor_episodes=2" in err
    assert "estimated time" in err
    assert not out.exists()


def test_dry_run_says_what_the_runs_keep_on_disk_and_drop_checkpoints_reaches_them(
    study_file, tmp_path, capsys, monkeypatch
):
    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    memory = [planning.agent_memory(study.config(g)[0]) for g in study.groups]
    agents = [2, 4]  # DDPG: 2 seeds; ADDPG+AfD: 2 seeds × 2 points
    state = sum(n * (m["replay"] + m["networks"]) for n, m in zip(agents, memory, strict=True))
    main(["sweep", str(study_file), "--out", str(tmp_path / "a"), "--dry-run"])
    err = " ".join(capsys.readouterr().err.split())
    assert f"checkpoints/ at most {state / 1e6:.0f} MB in all" in err
    assert "drop_checkpoints = true in [study] deletes them" in err  # printed, not markup

    dropping = tmp_path / "dropping.toml"
    dropping.write_text(
        study_file.read_text().replace("seeds = 2", "seeds = 2\ndrop_checkpoints = true")
    )
    main(["sweep", str(dropping), "--out", str(tmp_path / "b"), "--dry-run"])
    assert "checkpoints/ deleted as each piece finishes" in " ".join(
        capsys.readouterr().err.split()
    )
    kept = load_study(dropping)
    assert kept.drop_checkpoints and kept.args(kept.groups[0]).drop_checkpoints
    assert not study.drop_checkpoints and not study.args(study.groups[0]).drop_checkpoints

    calls = []  # a piece trains with the study's choice
    monkeypatch.setattr(
        "advisor_jax.training.host_loop.run_training", lambda *a, **k: calls.append(k)
    )
    plan = planning.plan_study(kept, planning.local_devices()[0])
    sweep.run_piece(kept, tmp_path / "b", plan, 0, progress=False)
    assert calls[0]["drop_checkpoints"] is True


def test_a_disk_too_small_for_the_runs_is_a_warning_naming_both_sizes(
    study_file, tmp_path, capsys, monkeypatch
):
    from collections import namedtuple

    from advisor_jax.cli import sweep as sweep_cli

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(sweep_cli.shutil, "disk_usage", lambda path: usage(0, 0, 10**9))
    main(["sweep", str(study_file), "--out", str(tmp_path / "a" / "b"), "--dry-run"])
    assert "warning" not in capsys.readouterr().err  # 6 quick agents: about 30 MB

    seen = []
    monkeypatch.setattr(
        sweep_cli.shutil, "disk_usage", lambda path: seen.append(path) or usage(0, 0, 5 * 10**6)
    )
    main(["sweep", str(study_file), "--out", str(tmp_path / "a" / "b"), "--dry-run"])
    err = " ".join(capsys.readouterr().err.split())
    assert re.search(r"warning: the unfinished pieces' runs may keep up to \d+ MB on disk", err)
    assert f"{tmp_path} has 5 MB free (drop_checkpoints = true in [study]" in err
    assert seen == [tmp_path]  # the nearest folder that exists


def test_the_planning_process_keeps_jax_off_the_gpus(study_file, tmp_path, monkeypatch):
    """The process that plans and starts workers checks the studies on the CPU: on a GPU it
    would otherwise take the memory planned for its workers (JAX preallocates on first use)."""
    from advisor_jax.cli import sweep as sweep_cli

    updates, checked_after = [], []
    monkeypatch.setattr(sweep_cli.jax.config, "update", lambda k, v: updates.append((k, v)))
    real_load = sweep_cli.load_study
    monkeypatch.setattr(
        sweep_cli, "load_study", lambda path: checked_after.append(list(updates)) or real_load(path)
    )
    main(["sweep", str(study_file), "--out", str(tmp_path / "a"), "--dry-run"])
    assert checked_after == [[("jax_platforms", "cpu")]]
    updates.clear()
    with pytest.raises(SystemExit):  # a worker (--piece) trains on its device: left alone
        main(["sweep", str(study_file), "--out", str(tmp_path / "b"), "--piece", "9"])
    assert updates == []


def test_the_estimate_counts_only_the_unfinished_pieces(study_file, tmp_path, capsys):
    from advisor_jax.study import plan as planning
    from advisor_jax.study import throughput

    def hours(err):
        return float(re.search(r"(\d+\.\d+) device-hours", err).group(1))

    out = tmp_path / "sweep"
    main(["sweep", str(study_file), "--out", str(out), "--dry-run", "--devices", "1"])
    whole = capsys.readouterr().err
    study = load_study(study_file)
    plan = planning.plan_study(study, planning.local_devices()[0], 1, None, throughput.load_table())
    finished = out / "runs" / plan.pieces[0].name  # as a kept run directory says it
    finished.mkdir(parents=True)
    (finished / "run.json").write_text(json.dumps({"status": "finished"}))
    main(["sweep", str(study_file), "--out", str(out), "--dry-run", "--devices", "1"])
    rest = capsys.readouterr().err
    assert f"for the {len(plan.pieces) - 1} unfinished pieces" in rest
    assert 0 < hours(rest) < hours(whole)


def test_slurm_writes_a_job_array_of_the_pieces_and_keeps_the_plan(study_file, tmp_path, capsys):
    out, script = tmp_path / "sweep", tmp_path / "job.sh"
    main(["sweep", str(study_file), "--out", str(out), "--slurm", str(script),
          "--device-memory", "80", "--sbatch", "partition=gpu"])  # fmt: skip
    text = script.read_text()
    assert "#SBATCH --array=0-1" in text and "#SBATCH --gres=gpu:1" in text
    assert "#SBATCH --partition=gpu" in text
    assert f'advisor-jax sweep {study_file} --out {out} --piece "$SLURM_ARRAY_TASK_ID"' in text
    assert "\ncd " in text and (out / "logs").is_dir()  # Slurm needs --output's folder
    plan = json.loads((out / "plan.json").read_text())
    assert [p["agents"] for p in plan["pieces"]] == [2, 4]
    assert "sbatch" in capsys.readouterr().err
    # a later call (a task, or a resumed sweep) keeps this plan, whatever the device
    kept = plan_file.load_plan(out, load_study(study_file))
    assert [p.name for p in kept.pieces] == [p["name"] for p in plan["pieces"]]


def test_a_changed_study_is_refused_for_the_same_out(study_file, tmp_path, capsys):
    out = tmp_path / "sweep"
    main(["sweep", str(study_file), "--out", str(out), "--slurm", str(tmp_path / "j.sh"),
          "--device-memory", "80"])  # fmt: skip
    study_file.write_text(study_file.read_text().replace("seeds = 2", "seeds = 3"))
    with pytest.raises(SystemExit) as exit_:
        main(["sweep", str(study_file), "--out", str(out), "--dry-run"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "holds a sweep of another study" in err and "Traceback" not in err


def test_runs_of_another_plan_without_its_plan_json_are_refused(study_file, tmp_path, capsys):
    """Kept runs copied into a fresh DIR would not count as finished pieces under a plan made
    for another number of devices (other pieces, other names): refused before anything
    trains, naming them; with their plan.json beside them they count."""
    out = tmp_path / "sweep"
    main(["sweep", str(study_file), "--out", str(out), "--slurm", str(tmp_path / "j.sh"),
          "--device-memory", "80", "--devices", "2"])  # fmt: skip
    plan = plan_file.load_plan(out, load_study(study_file))
    stray = out / "runs" / "007-DDPG-from-a-four-gpu-plan"
    stray.mkdir(parents=True)
    (stray / "run.json").write_text(json.dumps({"status": "finished"}))
    assert sweep.stray_runs(out, plan) == [stray.name]
    kept_plan = (out / "plan.json").read_text()
    (out / "plan.json").unlink()
    with pytest.raises(SystemExit) as exit_:
        main(["sweep", str(study_file), "--out", str(out), "--dry-run"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "holds 1 run(s) that are no piece of the plan" in err and stray.name in err
    assert "copy that plan.json there" in err and "Traceback" not in err
    (out / "plan.json").write_text(kept_plan)  # the kept plan is not checked for strays
    main(["sweep", str(study_file), "--out", str(out), "--dry-run"])


def test_bad_input_is_one_line_before_anything_compiles(study_file, tmp_path, capsys):
    study_file.write_text(study_file.read_text().replace("[0, 2]", "[0, 9]"))
    with pytest.raises(SystemExit) as exit_:
        main(["sweep", str(study_file), "--out", str(tmp_path / "o")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "N_T" in err and "jax" not in err.lower()
    with pytest.raises(SystemExit):
        main(["sweep", str(study_file), "--out", str(tmp_path / "o"), "--piece", "7"])
    assert not (tmp_path / "o").exists()


def test_a_piece_out_of_range_names_the_plan(study_file, tmp_path, capsys):
    with pytest.raises(SystemExit):
        main(["sweep", str(study_file), "--out", str(tmp_path / "o"), "--piece", "7"])
    assert "--piece 7: the plan has pieces 0-1" in capsys.readouterr().err


def test_per_device_shares_the_memory_and_is_kept_with_the_plan(study_file, tmp_path, capsys):
    out = tmp_path / "sweep"
    args = ["sweep", str(study_file), "--out", str(out), "--device-memory", "80"]
    main([*args, "--dry-run", "--per-device", "4"])
    err = " ".join(capsys.readouterr().err.split())
    assert "15.0 GiB usable by each of 4 processes" in err  # 80 GiB x 0.75 / 4
    assert "no gain assumed" in err
    for bad, message in ((["--per-device", "0"], "--per-device 0: need at least one"),
                         (["--per-device", "2", "--slurm", str(tmp_path / "j.sh")],
                          "--per-device 2 is for local runs")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            main([*args, *bad])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()  # refused before the plan was written


def test_run_local_fills_each_device_with_per_device_workers(study_file, tmp_path, monkeypatch):
    """Two devices x two processes: four pieces at once, each pinned to its GPU with half
    of XLA's memory share; the others wait for a free slot."""
    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    gpu = planning.Device("G", 80 << 30, 0, processes=2)
    plan = planning.plan_study(study, gpu, devices=2, max_agents=1)  # 6 pieces of 1 agent
    started, live, most = [], [], []

    class FakeProcess:  # a worker that finishes at its second poll
        def __init__(self, command, env, **_):
            started.append(env)
            live.append(self)
            most.append(len(live))
            self.returncode, self.polls = None, 0

        def poll(self):
            self.polls += 1
            if self.polls == 2:
                self.returncode = 0
                live.remove(self)
            return self.returncode

    monkeypatch.setattr(sweep.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(sweep.time, "sleep", lambda _: None)
    monkeypatch.delenv("XLA_PYTHON_CLIENT_MEM_FRACTION", raising=False)
    devices = [planning.Device("G", 80 << 30, 0), planning.Device("G", 80 << 30, 1)]
    (tmp_path / "o").mkdir()
    result = sweep.run_local(study, tmp_path / "o", plan, devices, progress=False)
    assert sorted(result) == list(range(len(plan.pieces))) and set(result.values()) == {"finished"}
    assert len(started) == len(plan.pieces) == 6 and max(most) == 4
    assert [env["CUDA_VISIBLE_DEVICES"] for env in started[:4]] == ["0", "1", "0", "1"]
    assert {env["XLA_PYTHON_CLIENT_MEM_FRACTION"] for env in started} == {"0.3750"}


def _failing_workers(monkeypatch, fails, polls=lambda gpu: 2):
    """Fake workers that end at their ``polls(gpu)``-th poll, with exit 1 where ``fails(gpu,
    piece)``; returns the (gpu, piece) of every start, in order."""
    started = []

    class FakeProcess:
        def __init__(self, command, env, **_):
            where = (env.get("CUDA_VISIBLE_DEVICES"), int(command[command.index("--piece") + 1]))
            started.append(where)
            self.code, self.returncode, self.polls = int(fails(*where)), None, 0
            self.end = polls(where[0])

        def poll(self):
            self.polls += 1
            if self.polls == self.end:
                self.returncode = self.code
            return self.returncode

    monkeypatch.setattr(sweep.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(sweep.time, "sleep", lambda _: None)
    return started


def test_a_device_that_fails_twice_in_a_row_takes_no_more_and_its_pieces_run_elsewhere(
    study_file, tmp_path, monkeypatch
):
    """GPU 0 fails every piece (its memory taken by another process, as happened on four
    H200s): after two failures in a row it takes no more, and both pieces are started once
    more on GPU 1, so the whole study still finishes."""
    from rich.console import Console

    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    gpu = planning.Device("G", 80 << 30, 0)
    plan = planning.plan_study(study, gpu, devices=2, max_agents=1)  # 6 pieces
    started = _failing_workers(monkeypatch, lambda gpu, piece: gpu == "0")
    devices = [planning.Device("G", 80 << 30, 0), planning.Device("G", 80 << 30, 1)]
    console = Console(record=True, width=200)
    (tmp_path / "o").mkdir()
    result = sweep.run_local(study, tmp_path / "o", plan, devices, False, console)
    assert set(result.values()) == {"finished"} and len(result) == 6
    on_0 = [piece for gpu, piece in started if gpu == "0"]
    assert len(on_0) == 2 and all((("1", piece) in started) for piece in on_0)
    assert len(started) == 8
    text = console.export_text()
    assert "GPU 0: 2 pieces in a row failed on it; it takes no more pieces" in text
    assert text.count("it will be started once more") == 2


def test_a_retry_waits_for_another_device_rather_than_run_where_it_failed(
    study_file, tmp_path, monkeypatch
):
    """The first piece fails on GPU 0 (and would again there). GPU 1 is slow: GPU 0 runs
    the other pieces while GPU 1 still runs its first, so when the retry comes up only GPU 0
    is free. The retry waits for GPU 1, where it finishes."""
    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    plan = planning.plan_study(study, planning.Device("G", 80 << 30, 0), devices=2, max_agents=1)
    first = []

    def fails(gpu, piece):
        first.extend([] if first else [piece])
        return gpu == "0" and piece == first[0]

    started = _failing_workers(monkeypatch, fails, polls=lambda gpu: 2 if gpu == "0" else 30)
    devices = [planning.Device("G", 80 << 30, 0), planning.Device("G", 80 << 30, 1)]
    (tmp_path / "o").mkdir()
    result = sweep.run_local(study, tmp_path / "o", plan, devices, progress=False)
    assert set(result.values()) == {"finished"} and len(result) == len(plan.pieces)
    assert [gpu for gpu, piece in started if piece == first[0]] == ["0", "1"]
    assert len(started) == len(plan.pieces) + 1


def test_a_piece_that_fails_twice_fails_the_sweep_and_the_rest_is_kept(
    study_file, tmp_path, monkeypatch, capsys
):
    """Piece 0 fails wherever it runs: started twice, then the sweep ends with an error
    naming it; piece 1 finishes. On a device where everything fails, what the device did
    not get to is "stranded", not "left" for a time limit."""
    started = _failing_workers(monkeypatch, lambda gpu, piece: piece == 0)
    out = tmp_path / "o"
    with pytest.raises(SystemExit) as exit_:
        main(["sweep", str(study_file), "--out", str(out), "--no-progress"])
    err = " ".join(capsys.readouterr().err.split())
    assert exit_.value.code == 2
    assert f"pieces failed twice: 0 of {out} (see {out / 'logs'})" in err
    assert "run the same command again to retry them" in err
    assert [piece for _, piece in started] == [1, 0, 0]  # longest first; the retry once more

    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    cpu = planning.Device("cpu", 8 << 30, None)
    plan = planning.plan_study(study, cpu, devices=1, max_agents=1)  # 6 pieces
    started = _failing_workers(monkeypatch, lambda gpu, piece: True)
    result = sweep.run_local(study, tmp_path / "p", plan, [cpu], progress=False)
    assert len(started) == 2 and set(result.values()) == {"stranded"}


def test_first_fitting_takes_the_longest_piece_that_ends_in_time():
    from advisor_jax.study.plan import Piece

    def piece(i, seconds):
        return Piece(i, 0, (0,), (0,), f"p{i}", seconds)

    queue = [piece(0, 600.0), piece(1, 300.0), piece(2, None), piece(3, 60.0)]
    assert sweep.first_fitting(queue, None, 2.0) == 0  # no limit: longest first
    assert sweep.first_fitting(queue, 700.0, 2.0) == 1  # 600 x 2 > 700 >= 300 x 2
    assert sweep.first_fitting(queue, 100.0, 2.0) == 2  # no estimate: it always fits
    assert sweep.first_fitting([queue[0], queue[1]], 100.0, 2.0) is None


def _timed_plan(study_file, processes: int):
    """A one-GPU plan of 3 pieces of 2 agents, each estimated at 100 s."""
    from advisor_jax.study import plan as planning

    study = load_study(study_file)
    gpu = planning.Device("G", 80 << 30, 0, processes=processes)
    plan = planning.plan_study(study, gpu, devices=1, max_agents=2)
    pieces = tuple(dataclasses.replace(p, seconds=100.0) for p in plan.pieces)
    return study, gpu, dataclasses.replace(plan, pieces=pieces)


def _timed_workers(monkeypatch, seconds: float) -> list[str]:
    """Fake workers that each take ``seconds`` of a fake clock (sleep and monotonic);
    returns the pieces started, in order."""
    clock, started = [0.0], []

    class FakeProcess:
        def __init__(self, command, env, **_):
            started.append(command[command.index("--piece") + 1])
            self.returncode, self.end = None, clock[0] + seconds

        def poll(self):
            if clock[0] >= self.end:
                self.returncode = 0
            return self.returncode

    def sleep(dt):
        clock[0] += dt

    monkeypatch.setattr(sweep.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(sweep.time, "sleep", sleep)
    monkeypatch.setattr(sweep.time, "monotonic", lambda: clock[0])
    return started


def test_time_limit_starts_what_ends_in_time_and_leaves_the_rest(study_file, tmp_path, monkeypatch):
    """One device, pieces of 100 s estimated: the first two fit a 250 s limit one after the
    other; each took 1.2 x its estimate, so the third (predicted 120 s with 10 s left) waits."""
    study, gpu, plan = _timed_plan(study_file, processes=1)
    started = _timed_workers(monkeypatch, 120.0)
    (tmp_path / "o").mkdir()
    result = sweep.run_local(study, tmp_path / "o", plan, [gpu], progress=False, time_limit=250.0)
    assert len(plan.pieces) == 3 and len(started) == 2
    assert sorted(result.values()) == ["finished", "finished", "left"]


@pytest.mark.parametrize("kept_processes, starts", [(2, 2), (1, 0)])
def test_time_limit_starts_from_the_ratio_earlier_calls_measured(
    study_file, tmp_path, monkeypatch, kept_processes, starts
):
    """Two workers per device: with nothing measured a piece is predicted to take 2 x its
    100 s estimate, more than the 150 s left; timing.json from an earlier call with two
    workers per device says 1.2 x, so the pieces start (and add their own records), while a
    ratio measured with one worker per device is not taken for two. (Two pieces start at
    once; the third would start with 40 s left and waits.)"""
    study, gpu, plan = _timed_plan(study_file, processes=2)
    _timed_workers(monkeypatch, 110.0)
    out = tmp_path / "o"
    out.mkdir()
    kept = [{"piece": "x", "processes": kept_processes, "ratio": 1.2}]
    (out / "timing.json").write_text(json.dumps(kept))
    result = sweep.run_local(study, out, plan, [gpu], progress=False, time_limit=150.0)
    assert len(plan.pieces) == 3
    assert list(result.values()).count("finished") == starts
    records = json.loads((out / "timing.json").read_text())
    assert len(records) == 1 + starts
    assert all(r["ratio"] == pytest.approx(1.1, abs=0.02) for r in records[1:])
    assert sweep.kept_ratios(out, kept_processes)[0] == 1.2


def test_kept_ratios_prefer_the_same_kind_of_device(tmp_path):
    records = [
        {"device": "H200", "processes": 2, "ratio": 1.24},
        {"device": "H100", "processes": 2, "ratio": 1.51},
        {"device": "H100", "processes": 1, "ratio": 1.0},
    ]
    (tmp_path / "timing.json").write_text(json.dumps(records))
    assert sweep.kept_ratios(tmp_path, 2, "H100") == [1.51]
    assert sweep.kept_ratios(tmp_path, 2, "A100") == [1.24, 1.51]  # none of its kind: all
    assert sweep.kept_ratios(tmp_path, 1) == [1.0]
    (tmp_path / "timing.json").write_text("{not json")
    assert sweep.kept_ratios(tmp_path, 2, "H100") == []


def test_time_limit_is_checked_before_anything_runs(study_file, tmp_path, capsys):
    out = tmp_path / "o"
    local = "--time-limit is for local runs"
    for bad, message in ((["--time-limit", "0"], "give a positive number of minutes"),
                         (["--time-limit", "5", "--dry-run"], local),
                         (["--time-limit", "5", "--piece", "0"], local)):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            main(["sweep", str(study_file), "--out", str(out), *bad])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not out.exists()


def _second_study(tmp_path, name="other"):
    path = tmp_path / f"{name}.toml"
    path.write_text(textwrap.dedent(STUDY).replace('name = "tiny"', f'name = "{name}"'))
    return path


def test_several_studies_plan_into_one_dir_each_and_share_the_devices(
    study_file, tmp_path, monkeypatch, capsys
):
    other = _second_study(tmp_path)
    out = tmp_path / "o"
    main(["sweep", str(study_file), str(other), "--out", str(out), "--dry-run"])
    err = capsys.readouterr().err
    assert "tiny: 2 pieces" in err and "other: 2 pieces" in err and "all 2 studies" in err
    assert not out.exists()

    started = []

    class FakeProcess:  # a worker that has finished when first polled
        def __init__(self, command, env, **_):
            started.append((command[command.index("--out") + 1], command[-2]))
            self.returncode = None

        def poll(self):
            self.returncode = 0
            return 0

    monkeypatch.setattr(sweep.subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(sweep.time, "sleep", lambda _: None)
    main(["sweep", str(study_file), str(other), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert (out / "tiny" / "plan.json").is_file() and (out / "other" / "plan.json").is_file()
    assert [Path(o).name for o, _ in started] == ["tiny", "tiny", "other", "other"]  # in order
    assert "2 of 2 pieces finished in" in err and f"advisor-jax report {out / 'tiny'}" in err


def test_several_studies_need_their_own_names_and_no_piece(study_file, tmp_path, capsys):
    twin = tmp_path / "twin.toml"  # another file, the same name
    twin.write_text(study_file.read_text())
    other = str(_second_study(tmp_path))
    for args, message in (([str(twin)], "each needs its own name"),
                          ([other, "--piece", "0"], "take one STUDY")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            main(["sweep", str(study_file), *args, "--out", str(tmp_path / "o")])
        assert exit_.value.code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_kept_plans_of_different_per_device_are_run_apart(study_file, tmp_path):
    from advisor_jax.study import plan as planning
    from advisor_jax.study.spec import StudyError

    study = load_study(study_file)
    plans = [planning.plan_study(study, planning.Device("G", 80 << 30, 0, processes=k), 1)
             for k in (1, 2)]  # fmt: skip
    jobs = [sweep.Job(study, tmp_path / f"o{k}", plan) for k, plan in enumerate(plans)]
    with pytest.raises(StudyError, match="differ in --per-device"):
        sweep.run_jobs(jobs, [planning.Device("G", 80 << 30, 0)], progress=False)
