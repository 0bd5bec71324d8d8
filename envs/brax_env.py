"""Every arena as a ``brax.envs.Env``, so brax's wrappers and trainers take it as it is.

    env = envs.make_brax_env("training")        # envs/__init__.py: the arguments of make_env
    env = brax.envs.training.wrap(env, episode_length=env.episode_length)
    make_policy, params, _ = brax.training.agents.sac.train.train(env, ...)

``BraxNavEnv`` holds a ``NavEnv`` and calls its own ``reset`` and ``step`` (no copy of the
arena), adapting them to brax's conventions (those of brax's own and MuJoCo Playground's
environments)::

    reset(key)      -> State(pipeline_state=NavState, obs [20], reward 0, done 0, metrics, info)
    step(s, a)      a ∈ [-1, 1]² (what brax's tanh policies emit) -> the arena's action
                    (V, ω) = ((a0 + 1) / 2, a1), so V ∈ [0, 1] as the paper's forward-only robot
    done            goal or collision: a *termination*. The time limit h_max is brax's
                    EpisodeWrapper's (``episode_length``), which marks it ``truncation``; the
                    NavEnv inside therefore runs without a time limit of its own
    metrics         goal, collision (1 on the step that ends an episode so) and
                    collision_speed (mean |V| of its last 3 steps, on that step)

Resets: after a goal or a collision the NavEnv has already drawn a fresh start and goal
(its auto-reset). brax's ``AutoResetWrapper`` then puts back each env's *first* state, as it
does for every brax env, so an env replays one start and goal. ``wrap_for_training`` (brax's
``wrap_env_fn`` signature) keeps fresh starts instead: brax's VmapWrapper and EpisodeWrapper,
then ``FreshAutoResetWrapper``, which keeps the NavEnv's own fresh start after a termination
and draws one (``NavEnv.reset`` of the env's own key) after a truncation.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State, Wrapper
from brax.envs.wrappers.training import EpisodeWrapper, VmapWrapper

from envs import brax_compat
from envs.navigation import COLLISION, GOAL, NavEnv

brax_compat.install()  # brax 0.14's trainers on jax >= 0.10 (brax issue 671)

NO_TIME_LIMIT = 2**31 - 1  # the NavEnv's h_max inside the view: brax's EpisodeWrapper ends episodes


class BraxNavEnv(Env):
    """A ``NavEnv`` behind brax's ``Env`` interface (module docstring)."""

    def __init__(self, nav: NavEnv, episode_length: int):
        if nav.max_episode_steps != NO_TIME_LIMIT:
            raise ValueError("BraxNavEnv needs a NavEnv without a time limit: use make_brax_env")
        self.nav = nav
        self.episode_length = int(episode_length)  # h_max, for brax's EpisodeWrapper

    @property
    def observation_size(self) -> int:
        return self.nav.observation_size

    @property
    def action_size(self) -> int:
        return self.nav.action_size

    @property
    def backend(self) -> str:
        return "mjx"

    def reset(self, rng: jax.Array) -> State:
        nav = self.nav.reset(rng)
        zero = jnp.float32(0.0)
        return State(
            pipeline_state=nav,
            obs=nav.obs,
            reward=zero,
            done=zero,
            metrics={"goal": zero, "collision": zero, "collision_speed": zero},
            info={},
        )

    def step(self, state: State, action: jax.Array) -> State:
        nav = self.nav.step(state.pipeline_state, to_nav_action(action))
        goal = (nav.outcome == GOAL).astype(jnp.float32)
        collision = (nav.outcome == COLLISION).astype(jnp.float32)
        metrics = {  # keys that wrappers added (brax's EvalWrapper: "reward") stay
            **state.metrics,
            "goal": goal,
            "collision": collision,
            "collision_speed": collision * nav.collision_speed,
        }
        return state.replace(
            pipeline_state=nav,
            obs=nav.obs,
            reward=nav.reward,
            done=nav.terminal.astype(jnp.float32),
            metrics=metrics,
        )


def to_nav_action(action: jax.Array) -> jax.Array:
    """brax's action a ∈ [-1, 1]² -> the arena's normalised (V ∈ [0, 1], ω ∈ [-1, 1])."""
    action = jnp.asarray(action, jnp.float32)
    return jnp.stack([(action[..., 0] + 1.0) / 2.0, action[..., 1]], axis=-1)


class FreshAutoResetWrapper(Wrapper):
    """brax's AutoResetWrapper with a fresh start and goal for every episode (batched env,
    under brax's VmapWrapper and EpisodeWrapper): after a termination the NavEnv's own fresh
    start stays; after a truncation ``NavEnv.reset`` draws one from the env's own key (only
    when some env truncated: a ``lax.cond`` on the batch)."""

    def step(self, state: State, action: jax.Array) -> State:
        if "steps" in state.info:  # the EpisodeWrapper's count restarts after an episode
            steps = jnp.where(state.done, jnp.zeros_like(state.info["steps"]), state.info["steps"])
            state.info.update(steps=steps)
        state = self.env.step(state.replace(done=jnp.zeros_like(state.done)), action)
        truncated = state.info["truncation"] > 0

        def fresh(state: State) -> State:
            nav = state.pipeline_state
            first = jax.vmap(self.env.unwrapped.nav.reset)(nav.key)
            keep = lambda new, old: jnp.where(  # noqa: E731
                truncated.reshape(truncated.shape + (1,) * (old.ndim - 1)), new, old
            )
            nav = jax.tree.map(keep, first, nav)
            return state.replace(pipeline_state=nav, obs=nav.obs)

        return jax.lax.cond(jnp.any(truncated), fresh, lambda s: s, state)


def wrap_for_training(
    env: Env,
    episode_length: int = 1000,
    action_repeat: int = 1,
    randomization_fn: Callable | None = None,
) -> Wrapper:
    """brax's ``wrap_env_fn``: VmapWrapper, EpisodeWrapper, then ``FreshAutoResetWrapper``."""
    if randomization_fn is not None:
        raise ValueError("the navigation arenas take no brax randomization_fn")
    return FreshAutoResetWrapper(EpisodeWrapper(VmapWrapper(env), episode_length, action_repeat))
