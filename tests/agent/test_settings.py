"""Settings declared once (agent/settings.py, hparams.py, config.py, baselines.py): what
follows from the declarations, and run.json files of older versions loading back."""

from __future__ import annotations

import dataclasses
import glob
import json
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent.advisor_quality import AdvisorQuality
from advisor_jax.agent.baselines import BaselineConfig
from advisor_jax.agent.config import (
    PRESETS,
    AgentConfig,
    TrainConfig,
    default_hparams,
    hparams_from_row,
    parse_agent,
    preset,
    train_config_from_dict,
)
from advisor_jax.agent.hparams import (
    HPARAM_NAMES,
    PRIOR_HPARAMS,
    BaselineHParams,
    HParams,
    LfdHParams,
    McpHParams,
)
from advisor_jax.agent.settings import (
    PRESET_NAMES,
    flat_fields,
    flat_items,
    freeze,
    from_flat,
    preset_values,
    replace_flat,
    spec_of,
    validate,
)

ROOT = Path(__file__).resolve().parents[2]
ALL_HPARAMS = (HParams, AdvisorQuality, *PRIOR_HPARAMS.values())


def declared(cls) -> list:
    """``cls``'s fields but a nested struct of them (``HParams.quality``, in ALL_HPARAMS)."""
    return [f for f in dataclasses.fields(cls) if f.default_factory is not AdvisorQuality]


def test_every_setting_is_declared_with_a_spec():
    for cls in ALL_HPARAMS:
        for f in declared(cls):
            spec = spec_of(f)
            assert spec is not None and spec.sweepable and spec.help, f.name
            assert spec.allows(np.array([f.default])).all(), f"{f.name}'s default"
            for name, value in spec.presets.items():
                assert spec.allows(np.array([value])).all(), f"{f.name} in {name}"
    for cls in (AgentConfig, TrainConfig, BaselineConfig):
        for f in dataclasses.fields(cls):
            assert spec_of(f) is None or not spec_of(f).sweepable, f.name
    assert set(PRESETS) == set(PRESET_NAMES)


def test_learning_rates_and_tau_freeze_and_nothing_else():
    """A new learning rate must freeze, or a finished agent keeps learning."""
    frozen = {f.name for cls in ALL_HPARAMS for f in declared(cls) if spec_of(f).freezes}
    rates = {n for n in HPARAM_NAMES if n.startswith("lr_") or n.endswith("_lr")}
    assert frozen == rates | {"tau"}
    hp = BaselineHParams(rl=HParams(), prior=McpHParams())
    stopped, before = flat_items(freeze(hp, jnp.zeros((), bool))), flat_items(hp)
    for name, value in stopped.items():
        assert float(value) == (0.0 if name in frozen else before[name]), name
    assert flat_items(freeze(hp, jnp.ones((), bool))) == pytest.approx(flat_items(hp))


def test_flat_names_map_to_nested_fields():
    hp = BaselineHParams(rl=HParams(), prior=LfdHParams())
    fields = flat_fields(hp)
    assert fields["demo_episodes"][0] == ("prior", "demo_episodes")
    assert fields["gamma"][0] == ("rl", "gamma")
    changed = replace_flat(hp, demo_episodes=7.0, gamma=0.5)
    assert changed.prior.demo_episodes == 7.0 and changed.rl.gamma == 0.5
    assert from_flat(hp, flat_items(changed)) == changed
    with pytest.raises(ValueError, match="unknown hyperparameter 'mpc_episodes' for"):
        replace_flat(hp, mpc_episodes=3.0)
    assert set(HPARAM_NAMES) == {n for c in ALL_HPARAMS for n in flat_fields(c())}


@pytest.mark.parametrize(
    ("hp", "message"),
    [(HParams(tau=0.0), r"tau=0 is outside \(0, 1\]"),
     (HParams(clip_q_target=0.5), "clip_q_target=0.5 is a switch: 0 or 1"),
     (BaselineHParams(HParams(), LfdHParams(demo_episodes=0.5)),
      r"demo_episodes=0.5 is outside \[1"),
     (BaselineHParams(HParams(), McpHParams(model_lr=-1.0)), r"model_lr=-1 is outside \(0, inf\)")],
)  # fmt: skip
def test_ranges_come_from_the_declarations(hp, message):
    with pytest.raises(ValueError, match=message):
        validate(hp)


def test_presets_come_from_the_declarations():
    cfg, hp = preset("physical", "ATD3+AfDP")
    assert (cfg.arena, cfg.episodes, cfg.agent.batch_size, cfg.agent.policy_delay) == (
        "physical", 200, 500, 3)  # fmt: skip
    assert (hp.lr_actor, hp.eps_start, hp.advisor_episodes) == (1e-4, 0.9, 100.0)
    stable = preset("stable", "DDPG")[1]
    assert flat_items(stable) == {**flat_items(HParams()), "beta": 1.0, "beta_normalize": 1.0,
                                  "clip_actor_target": 1.0, "clip_q_target": 1.0}  # fmt: skip
    assert preset_values(TrainConfig, "quick", changed_only=True) == {
        "episodes": 60, "chunk_steps": 500}  # fmt: skip
    mcp = preset("quick", "MCP+MF")
    assert mcp[0].agent.baseline.mpc_rounds == 2 and mcp[1].prior.random_episodes == 6.0
    lfd = preset("quick", "LfD")[0].agent.baseline
    assert lfd == BaselineConfig(bc_steps=200, bc_batch=128, critic_warmup=100)  # LfD's keys


def _recorded_runs():
    return sorted(glob.glob(str(ROOT / "results" / "*" / "run_data" / "*" / "run.json")))


def test_run_json_of_older_versions_loads():
    """Every run.json recorded under results/ (written by several older versions): its
    config, and each agent's hyperparameters from its row."""
    paths = _recorded_runs()
    if not paths:
        pytest.skip("no recorded runs in this checkout")
    for path in paths:
        summary = json.loads(Path(path).read_text())
        cfg = train_config_from_dict(summary["config"])
        for row in summary["agents"]:
            hp = hparams_from_row(cfg.agent, row)
            assert type(hp) is type(default_hparams(cfg.agent))
            for name, value in flat_items(hp).items():
                if name in row:
                    assert math.isclose(float(value), row[name], rel_tol=1e-6), (path, name)
            validate(hp)


def test_a_config_reads_back():
    cfg = TrainConfig(agent=parse_agent("LfD"), snapshot_episodes=(10,))
    assert train_config_from_dict(json.loads(json.dumps(dataclasses.asdict(cfg)))) == cfg
    with pytest.raises(ValueError, match="not a training configuration"):
        train_config_from_dict({"episodes": 3})
