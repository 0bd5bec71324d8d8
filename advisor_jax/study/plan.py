"""Planning a study: how many agents one device holds, the pieces, and how long they take.

A study is groups (an agent type at one combination of static settings: one compile each)
of points × seeds. The plan cuts every group into **pieces**: a block of its points × a block
of its seeds, one population, one ``run_training``, one run directory. A piece holds at
most as many agents as fit one device:

    bytes per agent = replay (capacity × 46 floats: s, a, a_adv, r, s', terminal)
                    + networks × 5 (weights, targets, Adam's two moments, gradients)
                    + activations (batch × the widths of the actor and every critic)
    agents per device = (device memory × XLA's share / processes − PROCESS_OVERHEAD)
                        / bytes per agent

(4 bytes a number). The formula errs high: at ``paper`` sizes it gives 75.6 MB per agent,
where the measured peak grows by 54-66 MB per agent (``results/bench_train_largest/``).
Groups are then split further, down to ``MIN_AGENTS`` per piece, while splitting the
longest piece's group shortens the study on the devices at hand (pieces put on devices
longest first). Times come from ``throughput`` (measured rates, not guesses), or are
left out where nothing was measured for that device.

``processes`` > 1 (``--per-device``) trains that many pieces on each device at once, each
in its own process with that share of XLA's memory: small pieces leave a GPU idle between
kernels (results/bench_train_motion/: 8,505 agent env-steps/s at 16 agents, 12,474 at 64),
and pieces of different groups cannot share one population. The time estimate assumes no
gain from it (a device's pieces as if one after another), so it errs long.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import os
import shutil
import subprocess

from advisor_jax.contract import spec
from advisor_jax.study import throughput
from advisor_jax.study.spec import Study, StudyError

PROCESS_OVERHEAD = 1 << 30  # CUDA context, XLA's workspace and the program: 1 GiB a process
GPU_SHARE = 0.75  # JAX preallocates 75 % of a GPU unless XLA_PYTHON_CLIENT_MEM_FRACTION says
CPU_SHARE = 0.5  # of the host's memory, for one population at a time
MIN_AGENTS = 16  # below this a GPU idles between kernels (results/bench_train.md)
TRANSITION_FLOATS = 2 * spec.OBS_SIZE + 2 * spec.ACTION_SIZE + 2


@dataclasses.dataclass(frozen=True)
class Device:
    """A device that trains ``processes`` pieces at a time; ``index`` is its CUDA index
    (None: CPU)."""

    kind: str
    memory: int  # bytes
    index: int | None = None
    processes: int = 1

    @property
    def share(self) -> float:
        """The fraction of its memory one population's process may take."""
        if self.index is None and self.kind == "cpu":
            return CPU_SHARE / self.processes
        share = float(os.environ.get("XLA_PYTHON_CLIENT_MEM_FRACTION", GPU_SHARE))
        return share / self.processes

    @property
    def usable(self) -> int:
        """Bytes one population may take on it."""
        return int(self.memory * self.share)


def local_devices() -> list[Device]:
    """The GPUs ``nvidia-smi`` lists (those in CUDA_VISIBLE_DEVICES, if set), else the CPU.
    JAX is not asked: it would claim every GPU's memory in this process."""
    gpus = []
    if shutil.which("nvidia-smi"):
        query = [
            "nvidia-smi",
            "--query-gpu=index,name,memory.total",
            "--format=csv,noheader,nounits",
        ]
        try:
            out = subprocess.run(query, capture_output=True, text=True, timeout=30).stdout
        except (OSError, subprocess.SubprocessError):
            out = ""
        for line in out.strip().splitlines():
            index, name, mib = (part.strip() for part in line.split(","))
            gpus.append(Device(name, int(float(mib)) << 20, int(index)))
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is not None and gpus:
        wanted = [int(v) for v in visible.split(",") if v.strip().isdigit()]
        gpus = [g for g in gpus if g.index in wanted]
    if gpus:
        return gpus
    pages = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    return [Device("cpu", pages)]


def parameter_count(sizes: list[int]) -> int:
    """Weights and biases of dense layers through ``sizes`` (input first)."""
    return sum(a * b + b for a, b in itertools.pairwise(sizes))


def agent_memory(cfg) -> dict[str, int]:
    """Bytes one agent of ``cfg`` needs on a device, by part (the module docstring)."""
    agent = cfg.agent
    obs, act = spec.OBS_SIZE, spec.ACTION_SIZE
    actor = parameter_count([obs, *agent.actor_hidden, act])
    first = obs * agent.critic_state_hidden + agent.critic_state_hidden
    critic = first + parameter_count([agent.critic_state_hidden + act, *agent.critic_hidden, 1])
    parameters = actor + agent.n_critics * critic
    widths = sum(agent.actor_hidden) + act
    widths += agent.n_critics * (agent.critic_state_hidden + sum(agent.critic_hidden) + 1)
    parts = {
        "replay": agent.buffer_size * TRANSITION_FLOATS * 4,
        "networks": (5 * parameters + len(cfg.snapshot_episodes) * actor) * 4,
        "activations": agent.batch_size * widths * 4,
    }
    parts["parameters"] = parameters
    parts["total"] = parts["replay"] + parts["networks"] + parts["activations"]
    return parts


def agents_per_device(cfg, device: Device) -> int:
    return max(0, (device.usable - PROCESS_OVERHEAD) // agent_memory(cfg)["total"])


@dataclasses.dataclass(frozen=True)
class Piece:
    """One population: points (indices into its group's) × seeds."""

    index: int
    group: int
    points: tuple[int, ...]
    seeds: tuple[int, ...]
    name: str
    seconds: float | None = None  # estimated training time on the planned device

    @property
    def agents(self) -> int:
        return max(1, len(self.points)) * len(self.seeds)


@dataclasses.dataclass(frozen=True)
class Plan:
    digest: str
    device: Device
    devices: int
    caps: tuple[int, ...]  # agents per piece, per group
    pieces: tuple[Piece, ...]
    explained: tuple[str, ...]  # how it was decided, one line each
    max_agents: int | None = None  # --max-agents, part of how the pieces were cut

    def makespan(self, skip: frozenset[int] = frozenset()) -> float | None:
        """Seconds until the last device is done, pieces placed longest first (those in
        ``skip``, e.g. finished, left out)."""
        pieces = [p for p in self.pieces if p.index not in skip]
        if any(p.seconds is None for p in pieces):
            return None
        return _makespan(pieces, self.devices)


def _work(piece: Piece) -> float:
    """A piece's estimated seconds, else its agents (a proxy where nothing was measured)."""
    return piece.seconds if piece.seconds is not None else piece.agents


def _makespan(pieces, devices: int) -> float:
    """When the last of ``devices`` is done, pieces placed longest first on the least loaded
    (a device's pieces as if one after another, also with ``--per-device``)."""
    loads = [0.0] * devices
    for p in sorted(pieces, key=lambda p: -_work(p)):
        loads[loads.index(min(loads))] += _work(p)
    return max(loads, default=0.0)


def _blocks(items: list, n: int) -> list[list]:
    """``items`` in ``n`` contiguous blocks of nearly equal length."""
    bounds = [round(i * len(items) / n) for i in range(n + 1)]
    return [items[a:b] for a, b in itertools.pairwise(bounds)]


def split_group(n_points: int, seeds: tuple[int, ...], count: int):
    """At least ``count`` (point block, seed block) pairs covering points × seeds, the
    largest as small as can be, seed blocks split last: [(points, seeds)]."""
    points = list(range(n_points)) or [None]
    best = None
    for s in range(1, len(seeds) + 1):
        p = min(len(points), math.ceil(count / s))
        largest = math.ceil(len(points) / p) * math.ceil(len(seeds) / s)
        key = (p * s < count, p * s, largest, s)
        if best is None or key < best[0]:
            best = (key, p, s)
    _, p, s = best
    return [
        (tuple(x for x in pb if x is not None), tuple(sb))
        for pb in _blocks(points, p)
        for sb in _blocks(list(seeds), s)
    ]


def _seconds(study: Study, group, cfg, agents: int, device: Device, table) -> float | None:
    """Training time of a population of ``agents`` of ``group`` (None: nothing measured)."""
    if table is None:
        return None
    rate = throughput.agent_steps_per_s(
        table, device.kind, cfg.agent.precision, study.preset, agents, cfg.motion
    )
    if rate is None:
        return None
    kind = throughput.agent_type(table, group.agent, cfg.arena, cfg.motion)
    steps = agents * cfg.episodes * kind["steps_per_episode"]
    return steps / (rate * kind["relative_speed"]) + throughput.COMPILE_S


def plan_study(
    study: Study,
    device: Device,
    devices: int = 1,
    max_agents: int | None = None,
    table: dict | None = None,
) -> Plan:
    """Pieces of ``study`` for ``devices`` devices like ``device`` (see the module docstring).
    A group one agent of which does not fit the device is a StudyError."""
    configs = [study.config(g)[0] for g in study.groups]
    caps, counts = [], []
    for group, cfg in zip(study.groups, configs, strict=True):
        fit = agents_per_device(cfg, device)
        if fit < 1:
            need = (agent_memory(cfg)["total"] + PROCESS_OVERHEAD) / 2**30
            raise StudyError(
                f"{study.path}: one agent of {group.agent} needs {need:.1f} GiB with the "
                f"process, more than the {device.usable / 2**30:.1f} GiB usable on "
                f"{device.kind}; lower buffer_size or batch_size under [static]"
                + ("" if device.processes == 1 else " or --per-device")
            )
        caps.append(min(fit, max_agents or fit))
        total = max(1, len(group.points)) * len(study.seeds)
        counts.append(math.ceil(total / caps[-1]))

    def pieces_of(counts):
        out = []
        for g, (group, cfg, count) in enumerate(zip(study.groups, configs, counts, strict=True)):
            for points, seeds in split_group(len(group.points), study.seeds, count):
                n = max(1, len(points)) * len(seeds)
                seconds = _seconds(study, group, cfg, n, device, table)
                name = f"{len(out):03d}-{group.agent.replace('+', '_')}"
                name += "".join(
                    f"-{k}{v}"
                    for k, v in group.static.items()
                    if k in ("episodes", "precision", "policy_delay", "arena")
                )
                out.append(Piece(len(out), g, points, seeds, name, seconds))
        return out

    pieces = pieces_of(counts)
    while devices > 1:  # split the longest piece's group while that shortens the study
        longest = max(pieces, key=_work)
        total = max(1, len(study.groups[longest.group].points)) * len(study.seeds)
        if total / (counts[longest.group] + 1) < MIN_AGENTS:
            break
        trial = counts[: longest.group] + [counts[longest.group] + 1] + counts[longest.group + 1 :]
        split = pieces_of(trial)
        if _makespan(split, devices) >= _makespan(pieces, devices):
            break
        counts, pieces = trial, split
    explained = _explain(study, device, devices, configs, caps, table)
    return Plan(study.digest, device, devices, tuple(caps), tuple(pieces), explained, max_agents)


def kept_on_disk(study, configs, agents) -> tuple[int, int]:
    """Bytes that finished runs of ``agents[i]`` agents of each group (``configs[i]``) keep:
    (params/, the networks; checkpoints/, replay buffers and optimizer states, 0 where the
    study drops them). params/ is about 4 bytes a parameter; checkpoints/ is bounded by
    ``agent_memory``'s replay and networks (a buffer's unfilled rows cost little on disk: 48
    ``stable`` agents' checkpoints/ took 843 MiB, 18.4 MB per agent against this bound's
    55.2; their params/ 362 MiB, 7.9 MB per agent against 7.4 here)."""
    parts = [agent_memory(cfg) for cfg in configs]
    params = sum(n * m["parameters"] * 4 for n, m in zip(agents, parts, strict=True))
    state = sum(n * (m["replay"] + m["networks"]) for n, m in zip(agents, parts, strict=True))
    return params, 0 if study.drop_checkpoints else state


def _disk_line(study, configs) -> str:
    """What the finished runs keep on disk (``kept_on_disk``)."""
    agents = [len(study.seeds) * len(g.points or [{}]) for g in study.groups]
    params, state = kept_on_disk(study, configs, agents)
    if study.drop_checkpoints:
        return (f"disk: params/ about {size_text(params)} in all; checkpoints/ deleted as each "
                "piece finishes (drop_checkpoints)")  # fmt: skip
    return (f"disk: params/ about {size_text(params)} and checkpoints/ at most "
            f"{size_text(state)} in all (replay buffers; drop_checkpoints = true in [study] "
            "deletes them as each piece finishes)")  # fmt: skip


def size_text(n: float) -> str:
    """``n`` bytes as "41 MB" or "6.8 GB"."""
    return f"{n / 1e9:.1f} GB" if n >= 1e9 else f"{n / 1e6:.0f} MB"


def _explain(study, device, devices, configs, caps, table) -> tuple[str, ...]:
    gib = 2**30
    each = "one process" if device.processes == 1 else f"each of {device.processes} processes"
    lines = [
        f"devices: {devices} × {device.kind}, {device.memory / gib:.1f} GiB each, "
        f"{device.usable / gib:.1f} GiB usable by {each}"
        + (" (XLA's share)" if device.index is not None or device.kind != "cpu" else "")
    ]
    seen = set()
    for group, cfg, cap in zip(study.groups, configs, caps, strict=True):
        m = agent_memory(cfg)
        text = (
            f"{group.agent} ({cfg.agent.precision}, buffer {cfg.agent.buffer_size:,}, batch "
            f"{cfg.agent.batch_size:,}): {m['total'] / 1e6:.1f} MB per agent = replay "
            f"{m['replay'] / 1e6:.1f} + networks {m['networks'] / 1e6:.1f} ({m['parameters']:,} "
            f"parameters × 5) + activations {m['activations'] / 1e6:.1f}; + "
            f"{PROCESS_OVERHEAD / gib:.0f} GiB per process → at most {cap} agents per piece"
        )
        if text not in seen:
            seen.add(text)
            lines.append("memory: " + text)
    lines.append(_disk_line(study, configs))
    if table is None:
        lines.append(f"time: not estimated ({throughput.TABLE} not found)")
    else:
        missing = sorted(
            {
                (device.kind, cfg.agent.precision, study.preset)
                for cfg in configs
                if throughput.agent_steps_per_s(
                    table, device.kind, cfg.agent.precision, study.preset, 1
                )
                is None
            }
        )
        lines.append(
            "time: agents × episodes × each type's mean steps per episode / (the measured "
            "agent env-steps/s of ATD3+AfDP at that population size × the type's relative "
            f"speed × the motion model's) + {throughput.COMPILE_S:.0f} s per piece; rates "
            f"from {throughput.TABLE.name} (results/bench_train*.json, kept Table 1/2 runs, "
            "results/bench_train_motion)"
            + (
                ""
                if device.processes == 1
                else "; a device's pieces counted one after "
                "another (no gain assumed from running them at once)"
            )
        )
        stand_ins = sorted(
            {
                (device.kind, cfg.agent.precision, study.preset, measured)
                for cfg in configs
                if (
                    measured := throughput.measured_as(
                        table, device.kind, cfg.agent.precision, study.preset
                    )
                )
                not in (None, device.kind)
            }
        )
        for kind, precision, preset, measured in stand_ins:
            lines.append(
                f"time: nothing measured for {kind}, {precision}, --preset {preset}: the rates "
                f"of {measured} stand in for it (run python experiments/bench_train.py "
                f"--preset {preset} --precision {precision} --agents 1 16 64 there, then "
                "python -m advisor_jax.study.throughput)"
            )
        for kind, precision, preset in missing:
            lines.append(
                f"time: nothing measured for {kind}, {precision}, --preset {preset}: run "
                f"python experiments/bench_train.py --preset {preset} --precision {precision} "
                "--agents 1 16 64, then python -m advisor_jax.study.throughput"
            )
    return tuple(lines)
