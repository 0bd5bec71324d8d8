"""One seed of brax SAC or PPO under the paper's episode budget (``episodes.py``).

    result = train_seed("brax-SAC", settings, env, seed=0, budget=Budget(500, 8, 300))

brax's trainer runs in epochs (a jitted scan of env steps and updates) and calls back on the
host after each: ``progress_fn(step, metrics)``, and for PPO ``policy_params_fn(step, ...,
params)``; SAC instead saves its policy at each epoch (``checkpoint_logdir``). After every
epoch the host counts the episodes completed so far; once they reach N_total it stops brax
(``BudgetReached``) and keeps the policy of the last epoch that ended within N_total
episodes: the agent never learns from more than N_total episodes, and from at least
N_total minus one epoch's (the epochs are short: ``EPOCHS`` per ceiling, docs/baselines.md).
"""

from __future__ import annotations

import dataclasses
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from brax.envs.base import Wrapper

from advisor_jax.agent.brax_agents import (
    BRAX_SEED_MAX,
    PpoSettings,
    SacSettings,
    network_factory,
    stored_params,
)
from advisor_jax.training.brax_baselines.episodes import (
    Budget,
    BudgetReached,
    EpisodeLog,
    RecordingWrapper,
)
from envs.brax_env import BraxNavEnv, wrap_for_training

EPOCHS = 200  # SAC: epochs per ceiling of env steps (PPO: one update per epoch)


class NoEvaluation(Wrapper):
    """The environment brax SAC's own evaluator steps after every epoch: one episode of
    ``episode_length`` steps that nothing here uses (the run is evaluated by ours afterwards,
    on the paper's arenas). Every episode ends at its first step and then stands still, so
    that unroll costs its loop and not ``episode_length`` steps of the arena (on the 2-core
    CPU, 29 of a quick run's 82 s). Its metrics (``eval/...``) are dropped."""

    def step(self, state, action):
        return state.replace(done=jax.numpy.ones_like(state.done))


@dataclasses.dataclass
class SeedResult:
    """What one seed's training leaves: the policy and the episodes behind it."""

    params: dict  # ``stored_params``: the policy after the last epoch within the budget
    episodes: dict[str, np.ndarray]  # per episode [n_total] (``EpisodeLog.arrays``)
    env_steps: int  # env steps behind ``params``
    episodes_completed: int  # episodes completed within ``env_steps`` (<= n_total)
    seconds: float  # wall time of the call, compiles included
    progress: list[dict]  # per epoch: step, episodes, seconds and brax's metrics


def train_seed(
    agent: str,
    settings: SacSettings | PpoSettings,
    env: BraxNavEnv,
    seed: int,
    budget: Budget,
    on_epoch: Callable[[dict], None] = lambda row: None,
) -> SeedResult:
    """Trains one agent with brax's own trainer until ``budget.n_total`` episodes."""
    if not 0 <= seed <= BRAX_SEED_MAX:
        raise ValueError(f"brax agents take seeds 0 .. {BRAX_SEED_MAX}, got {seed}")
    log = EpisodeLog(settings.num_envs)
    eval_env = NoEvaluation(env)  # brax's own evaluator steps this one
    kept: dict[int, dict] = {}  # epoch step -> policy (PPO), the last two
    progress: list[dict] = []
    started = time.perf_counter()

    def wrap_env_fn(inner, episode_length, action_repeat=1, randomization_fn=None):
        wrapped = wrap_for_training(inner, episode_length, action_repeat, randomization_fn)
        return RecordingWrapper(wrapped, log.add) if inner is env else wrapped

    def progress_fn(step: int, metrics: dict) -> None:
        jax.effects_barrier()  # every callback of the epoch has landed
        row = {"step": int(step), "episodes": log.count(int(step)),
               "seconds": round(time.perf_counter() - started, 3)}  # fmt: skip
        row |= {k: float(v) for k, v in metrics.items()
                if np.size(v) == 1 and not k.startswith("eval/")}  # fmt: skip
        progress.append(row)
        on_epoch(row)
        if row["episodes"] >= budget.n_total:
            raise BudgetReached

    def policy_params_fn(step, make_policy, params) -> None:  # PPO only
        kept[int(step)] = jax.device_get(stored_params(params))
        for old in sorted(kept)[:-2]:
            del kept[old]

    workdir = Path(tempfile.mkdtemp(prefix="brax-sac-"))
    try:
        try:
            _call_brax(agent, settings, env, eval_env, seed, budget, wrap_env_fn,
                       progress_fn, policy_params_fn, workdir)  # fmt: skip
        except BudgetReached:
            pass
        seconds = time.perf_counter() - started
        within = [r["step"] for r in progress if r["episodes"] <= budget.n_total]
        step = max(within) if within else progress[0]["step"]
        params = kept[step] if kept else _sac_policy(workdir, step)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    completed = min(log.count(step), budget.n_total)
    return SeedResult(params, log.arrays(step, budget.n_total), step, completed, seconds, progress)


def _call_brax(agent, settings, env, eval_env, seed, budget, wrap_env_fn, progress_fn,
               policy_params_fn, workdir) -> None:  # fmt: skip
    """brax's trainer with ``settings``; stops by raising from ``progress_fn``."""
    common = dict(
        environment=env,
        num_timesteps=budget.ceiling_steps,
        episode_length=env.episode_length,
        wrap_env_fn=wrap_env_fn,
        num_envs=settings.num_envs,
        num_eval_envs=1,  # brax's own evaluation is not used: ours runs afterwards
        eval_env=eval_env,
        learning_rate=settings.learning_rate,
        discounting=settings.discounting,
        seed=int(seed),
        batch_size=settings.batch_size,
        normalize_observations=settings.normalize_observations,
        reward_scaling=settings.reward_scaling,
        max_devices_per_host=1,
        network_factory=network_factory(settings),
        progress_fn=progress_fn,
    )
    if agent == "brax-SAC":
        from brax.training.agents.sac import train as sac

        sac.train(
            **common,
            num_evals=EPOCHS + 1,
            tau=settings.tau,
            min_replay_size=settings.min_replay_size,
            max_replay_size=settings.max_replay_size,
            grad_updates_per_step=settings.grad_updates_per_step,
            deterministic_eval=True,
            checkpoint_logdir=str(workdir),
        )
        return
    from brax.training.agents.ppo import train as ppo

    per_update = settings.batch_size * settings.unroll_length * settings.num_minibatches
    ppo.train(
        **common,
        num_evals=-(-budget.ceiling_steps // per_update) + 1,  # one update per epoch
        run_evals=False,
        policy_params_fn=policy_params_fn,
        entropy_cost=settings.entropy_cost,
        unroll_length=settings.unroll_length,
        num_minibatches=settings.num_minibatches,
        num_updates_per_batch=settings.num_updates_per_batch,
        clipping_epsilon=settings.clipping_epsilon,
        gae_lambda=settings.gae_lambda,
    )


def _sac_policy(workdir: Path, step: int) -> dict:
    """The policy brax SAC saved after the epoch that ended at ``step``."""
    from brax.training import checkpoint

    path = workdir / f"{step:012d}"
    if not path.is_dir():
        raise RuntimeError(f"brax SAC saved no policy at step {step} (in {workdir})")
    return jax.tree.map(np.asarray, stored_params(checkpoint.load(str(path))))
