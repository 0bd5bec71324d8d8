"""Planning: bytes per agent, agents per device, pieces, balance over devices, time."""

from __future__ import annotations

import dataclasses
import textwrap

import pytest

from advisor_jax.agent.config import preset
from advisor_jax.study import plan as planning
from advisor_jax.study.spec import StudyError, load_study

GIB = 2**30


def test_bytes_per_agent_at_the_papers_sizes_by_hand():
    cfg, _ = preset("paper", "ATD3+AfDP")
    m = planning.agent_memory(cfg)
    assert m["replay"] == 100_000 * 46 * 4  # s, s' (20 each), a, a_adv (2 each), r, terminal
    assert m["parameters"] == 193_502 + 2 * 823_701  # the paper's counts (§5.3)
    assert m["networks"] == 5 * m["parameters"] * 4
    assert m["activations"] == 1000 * (600 + 300 + 2 + 2 * (1000 + 500 + 600 + 1)) * 4
    assert m["total"] / 1e6 == pytest.approx(75.6, abs=0.1)
    ddpg = planning.agent_memory(preset("paper", "DDPG")[0])
    assert ddpg["parameters"] == 193_502 + 823_701  # one critic


def test_agents_per_device_leave_the_process_overhead():
    cfg, _ = preset("paper", "ATD3+AfDP")
    device = planning.Device("gpu", 80 * GIB, 0)  # 75 % usable: 60 GiB
    per_agent = planning.agent_memory(cfg)["total"]
    assert planning.agents_per_device(cfg, device) == (60 * GIB - GIB) // per_agent


@pytest.mark.parametrize(
    ("points", "seeds", "count", "expected"),
    [
        (1, 16, 1, [(1, 16)]),
        (11, 16, 3, [(4, 16), (3, 16), (4, 16)]),
        (2, 16, 4, [(1, 8), (1, 8), (1, 8), (1, 8)]),
        (1, 16, 3, [(1, 5), (1, 6), (1, 5)]),
    ],
)
def test_split_group_covers_every_agent_once(points, seeds, count, expected):
    pieces = planning.split_group(points, tuple(range(seeds)), count)
    assert [(max(1, len(p)), len(s)) for p, s in pieces] == expected
    covered = sorted((p, s) for ps, ss in pieces for p in (ps or (None,)) for s in ss)
    assert len(covered) == len(set(covered)) == max(1, points) * seeds


def _study(tmp_path, grid="[0, 10, 20, 30]", seeds=16, extra=""):
    path = tmp_path / "s.toml"
    path.write_text(
        textwrap.dedent(f"""
        [study]
        preset = "paper"
        agents = ["ADDPG+AfD"]
        seeds = {seeds}
        [static]
        episodes = 40
        {extra}
        [grid]
        advisor_episodes = {grid}
    """)
    )
    return load_study(path)


def test_a_piece_holds_what_fits_one_device(tmp_path):
    s = _study(tmp_path)  # 4 points x 16 seeds = 64 agents of 75.6 MB
    small = planning.Device("gpu", 4 * GIB, 0)  # 3 GiB usable, 2 GiB after the overhead
    plan = planning.plan_study(s, small)
    assert plan.caps == (2 * GIB // planning.agent_memory(s.config(s.groups[0])[0])["total"],)
    assert all(p.agents <= plan.caps[0] for p in plan.pieces)
    assert sum(p.agents for p in plan.pieces) == 64
    # one critic: 18.4 MB replay + 1,017,203 parameters x 20 B + 1000 x 3003 x 4 B = 50.8 MB
    assert "50.8 MB per agent" in " ".join(plan.explained)
    assert "at most 42 agents per piece" in " ".join(plan.explained)  # 2 GiB / 50.8 MB


def test_a_study_whose_agent_does_not_fit_is_refused(tmp_path):
    s = _study(tmp_path)
    with pytest.raises(
        StudyError,
        match=r"one agent of ADDPG\+AfD needs 1\.0 GiB with the process, more than the 0\.8",
    ):
        planning.plan_study(s, planning.Device("gpu", GIB, 0))


def test_pieces_spread_over_devices_down_to_the_minimum(tmp_path):
    s = _study(tmp_path)
    big = planning.Device("gpu", 80 * GIB, 0)
    assert len(planning.plan_study(s, big, devices=1).pieces) == 1
    four = planning.plan_study(s, big, devices=4)
    assert [p.agents for p in four.pieces] == [16, 16, 16, 16]
    many = planning.plan_study(s, big, devices=16)  # not below MIN_AGENTS per piece
    assert min(p.agents for p in many.pieces) >= planning.MIN_AGENTS
    capped = planning.plan_study(s, big, devices=1, max_agents=20)
    assert max(p.agents for p in capped.pieces) <= 20


def test_a_piece_command_keeps_the_cap_that_cut_the_pieces(tmp_path):
    from advisor_jax.study.plan_file import load_plan, save_plan
    from advisor_jax.study.sweep import piece_command

    s = _study(tmp_path)
    big = planning.Device("gpu", 80 * GIB, 0)
    capped = planning.plan_study(s, big, max_agents=20)
    save_plan(tmp_path, s, capped)
    kept = load_plan(tmp_path, s)
    assert kept.max_agents == 20 and kept.pieces == capped.pieces
    assert piece_command(s, tmp_path, 3, kept).endswith("--piece 3 --max-agents 20")
    free = planning.plan_study(s, big)
    assert piece_command(s, tmp_path, 0, free).endswith("--piece 0")
    shared = planning.plan_study(s, dataclasses.replace(big, processes=4))
    assert piece_command(s, tmp_path, 1, shared).endswith("--piece 1 --per-device 4")
    assert shared.caps[0] < free.caps[0] // 3  # a quarter of the memory, less the overhead
    (tmp_path / "shared").mkdir()
    save_plan(tmp_path / "shared", s, shared)
    assert load_plan(tmp_path / "shared", s).device.processes == 4


ROW = {"device": "G", "precision": "fp32", "size": "paper"}
TABLE = {
    "rows": [{**ROW, "agents": 1, "agent_steps_per_s": 100.0},
             {**ROW, "agents": 16, "agent_steps_per_s": 1600.0}],
    "agent_types": {"training": {"ADDPG+AfD": {"relative_speed": 0.5, "steps_per_episode": 50.0}}},
}  # fmt: skip


def test_time_from_the_measured_rate_and_the_type(tmp_path):
    from advisor_jax.study import throughput

    assert throughput.agent_steps_per_s(TABLE, "G", "fp32", "stable", 4) == pytest.approx(850.0)
    assert throughput.agent_steps_per_s(TABLE, "G", "fp32", "paper", 64) == 1600.0  # clamped
    assert throughput.agent_steps_per_s(TABLE, "G", "bf16", "paper", 4) is None
    s = _study(tmp_path, grid="[0]")
    plan = planning.plan_study(s, planning.Device("G", 80 * GIB, 0), table=TABLE)
    (piece,) = plan.pieces
    steps = 16 * 40 * 50.0  # agents x episodes x steps per episode
    assert piece.seconds == pytest.approx(steps / (1600.0 * 0.5) + throughput.COMPILE_S)
    assert plan.makespan() == piece.seconds
    # another GPU measured nowhere: G's rates stand in, and the plan says so
    other = planning.plan_study(s, planning.Device("H", 80 * GIB, 0), table=TABLE)
    assert other.makespan() == piece.seconds
    text = " ".join(" ".join(other.explained).split())
    assert "nothing measured for H, fp32, --preset paper: the rates of G stand in for it" in text
    assert throughput.measured_as(TABLE, "H", "bf16", "paper") is None  # no GPU at bf16
    unknown = planning.plan_study(s, planning.Device("cpu", 80 * GIB, None), table=TABLE)
    assert unknown.makespan() is None  # a CPU is never estimated from a GPU
    assert "nothing measured for cpu, fp32, --preset paper" in " ".join(unknown.explained)


def test_time_under_the_mjx_robot_uses_its_measured_speed_and_episode_length(tmp_path):
    from advisor_jax.study import throughput

    table = {**TABLE,
             "motion_factors": {"mjx": [{"agents": 1, "precision": "fp32", "factor": 0.5},
                                        {"agents": 16, "precision": "fp32", "factor": 0.75}]},
             "motion_steps_per_episode": {"mjx": {"training": {"ADDPG+AfD": 80.0}}}}  # fmt: skip
    assert throughput.motion_factor(table, "mjx", "fp32", 4) == pytest.approx(0.625)  # log mid
    assert throughput.motion_factor(table, "mjx:wheel_torque_max=0.5", "fp32", 64) == 0.75
    assert throughput.motion_factor(table, "kinematic", "fp32", 4) == 1.0
    assert throughput.motion_factor(table, "mjx", "bf16", 4) == 1.0  # not measured: as is
    assert throughput.agent_type(table, "ADDPG+AfD", "training", "mjx") == {
        "relative_speed": 0.5, "steps_per_episode": 80.0}  # fmt: skip
    assert throughput.agent_type(table, "DDPG", "training", "mjx")["steps_per_episode"] == 100.0
    s = _study(tmp_path, grid="[0]", extra='motion = "mjx"')
    (piece,) = planning.plan_study(s, planning.Device("G", 80 * GIB, 0), table=table).pieces
    steps = 16 * 40 * 80.0  # agents x episodes x the mjx robot's steps per episode
    rate = 1600.0 * 0.75 * 0.5  # ATD3+AfDP's rate x the motion factor x the type's speed
    assert piece.seconds == pytest.approx(steps / rate + throughput.COMPILE_S)


def test_the_throughput_table_keeps_the_newest_program_and_later_single_rows():
    """The newest date with several populations is the program in use; a later single row
    (a larger population measured alone) joins it; older rows of other sizes do not, but
    for populations larger than any of those."""
    from advisor_jax.study.throughput import _newest_program

    def row(date, agents):
        return {"date": date, "agents": agents}

    found = [row("2026-11-24", 512), row("2026-11-24", 768), row("2026-11-25", 64),
             row("2026-11-25", 768), row("2026-11-27", 1024)]  # fmt: skip
    assert _newest_program(found) == {
        1024: row("2026-11-27", 1024),
        768: row("2026-11-25", 768),
        64: row("2026-11-25", 64),
    }
    alone = [row("2026-11-24", 512), row("2026-11-25", 768)]  # no date with several rows
    assert _newest_program(alone) == {768: alone[1], 512: alone[0]}
    # a newer main table of small populations keeps the newest larger ones beyond it
    larger = [row("2026-11-27", 1024), row("2026-11-27", 1152), row("2026-11-27", 64),
              row("2026-11-28", 1), row("2026-11-28", 64), row("2026-11-25", 896)]  # fmt: skip
    assert _newest_program(larger) == {1: larger[3], 64: larger[4], 1024: larger[0],
                                       1152: larger[1]}  # fmt: skip


def test_the_throughput_table_reads_only_the_program_training_picks(tmp_path, monkeypatch):
    """A benchmark of a forced program (``--program general``) measures a program training
    does not run; the same date's ``auto`` report in ``bench_train_programs/`` is read."""
    import json

    from advisor_jax.study import throughput

    def report(program, rate):
        rows = [{"agents": a, "devices": 1, "precision": "fp32", "agent_steps_per_s": rate}
                for a in (1, 64)]  # fmt: skip
        return {"device": "G", "date": "2026-11-28", "preset": "paper", "agent": "ATD3+AfDP",
                "program": program, "rows": rows}  # fmt: skip

    folder = tmp_path / "results" / "bench_train_programs"
    folder.mkdir(parents=True)
    monkeypatch.setattr(throughput, "RESULTS", folder.parent)
    for name, program, rate in (("a_general", "general", 1.0), ("b_auto", "auto", 2.0)):
        (folder / f"{name}.json").write_text(json.dumps(report(program, rate)))
    rows = throughput._bench_rows(sorted(folder.glob("*.json")))
    assert [(r["agents"], r["agent_steps_per_s"]) for r in rows] == [(1, 2.0), (64, 2.0)]


def test_the_committed_throughput_table_is_derived_from_the_committed_results():
    """``sweep --dry-run`` estimates from ``results/sweep_throughput.json``: a new benchmark
    in ``results/`` without ``python -m advisor_jax.study.throughput`` fails here."""
    import json

    from advisor_jax.study import throughput

    assert throughput.derive() == json.loads(throughput.TABLE.read_text())
