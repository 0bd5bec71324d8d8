"""Random-shooting model-predictive control (Nagabandi et al., ICRA 2018; docs/baselines.md).

At every control step, for one robot::

    A ~ U(action box)^{K × H}                      # K i.i.d. candidate sequences (sampler)
    for each candidate k (vmap):                   # lax.scan over the horizon
        ŝ_0 = s;  alive = 1;  R_k = 0
        for t < H:  ŝ_{t+1} = model(ŝ_t, A_kt)
                    r, goal, collision = Eq. 8 from (ŝ_t, ŝ_{t+1})   (envs/reward.py)
                    R_k += alive · r;  alive &= not (goal or collision)
    execute A_{k*, 0},  k* = argmax_k R_k          # the clean first action; replan next step

The score is the undiscounted sum of the task's reward (source: ``mpc_controller.py``); a
candidate that reaches the goal or collides in the prediction is done, so later steps add
nothing (a sequence that reaches the goal and would then crash still scores +c1). What the
observation cannot show (footprint collisions between rays) the controller cannot see:
``envs/reward.py`` lists the differences from the env's reward.

The model is any ``step_fn(obs [..., 20], action [..., 2]) -> obs [..., 20]``: the neural
model (``make_mpc_policy``), or a hand-written one in the tests. Candidates come from
``sample_candidates`` unless the caller passes its own to ``plan``. K and H are static
(Python ints); a non-finite return (a diverged model) ranks last. Everything is pure: vmap
``plan`` / the policy over environments and agents at the call site.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from advisor_jax.agent.dynamics_model import DynamicsModel, Normalizer
from advisor_jax.contract import spec
from envs.reward import eq8_from_obs
from envs.state import EnvConfig

StepFn = Callable[[jax.Array, jax.Array], jax.Array]  # (obs [..., 20], action [..., 2]) -> obs


def check_mpc_sizes(n_candidates, horizon) -> tuple[int, int]:
    """``(K, H)`` as ints, or a ValueError naming the bad one (both must be positive ints)."""
    for name, value in (("mpc_candidates (K)", n_candidates), ("mpc_horizon (H)", horizon)):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return n_candidates, horizon


def sample_candidates(key: jax.Array, n_candidates: int, horizon: int) -> jax.Array:
    """[K, H, 2] actions i.i.d. uniform in the action box (V ∈ [0, 1], ω ∈ [−1, 1])."""
    n_candidates, horizon = check_mpc_sizes(n_candidates, horizon)
    low = jnp.asarray(spec.ACTION_LOW, jnp.float32)
    high = jnp.asarray(spec.ACTION_HIGH, jnp.float32)
    shape = (n_candidates, horizon, spec.ACTION_SIZE)
    return jax.random.uniform(key, shape, jnp.float32, low, high)


def candidate_returns(
    step_fn: StepFn, obs: jax.Array, candidates: jax.Array, cfg: EnvConfig
) -> jax.Array:
    """[K] summed Eq. 8 reward of each candidate [K, H, 2] from observation ``obs`` [20]."""

    def one(actions: jax.Array) -> jax.Array:  # [H, 2] -> ()
        def body(carry, action):
            s, alive, total = carry
            s_next = step_fn(s, action)
            reward, goal, collision = eq8_from_obs(s, s_next, cfg)
            total = total + jnp.where(alive, reward, 0.0)
            return (s_next, alive & ~(goal | collision), total), None

        start = (obs, jnp.bool_(True), jnp.float32(0.0))
        return jax.lax.scan(body, start, actions)[0][2]

    return jax.vmap(one)(candidates)


def plan(
    step_fn: StepFn, obs: jax.Array, candidates: jax.Array, cfg: EnvConfig
) -> tuple[jax.Array, jax.Array]:
    """``(first action [2] of the best candidate, returns [K])`` for candidates [K, H, 2]."""
    if candidates.ndim != 3 or candidates.shape[-1] != spec.ACTION_SIZE:
        raise ValueError(f"candidates must have shape [K, H, 2], got {candidates.shape}")
    check_mpc_sizes(candidates.shape[0], candidates.shape[1])
    returns = candidate_returns(step_fn, obs, candidates, cfg)
    best = jnp.argmax(jnp.where(jnp.isfinite(returns), returns, -jnp.inf))
    return candidates[best, 0], returns


def mpc_action(
    step_fn: StepFn, obs: jax.Array, key: jax.Array, n_candidates: int, horizon: int,
    cfg: EnvConfig,
) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """Random shooting: ``plan`` on ``sample_candidates(key, K, H)``."""
    return plan(step_fn, obs, sample_candidates(key, n_candidates, horizon), cfg)


def make_mpc_policy(
    model: DynamicsModel, n_candidates: int, horizon: int, cfg: EnvConfig
) -> Callable[[Any, Normalizer, jax.Array, jax.Array], jax.Array]:
    """``policy(params, norm, obs [20], key) -> action [2]``: random shooting through the
    neural model. K and H are checked here; vmap the policy over envs and agents."""
    n_candidates, horizon = check_mpc_sizes(n_candidates, horizon)

    def policy(params: Any, norm: Normalizer, obs: jax.Array, key: jax.Array) -> jax.Array:
        def step_fn(s, a):
            return model.predict(params, norm, s, a)

        return mpc_action(step_fn, obs, key, n_candidates, horizon, cfg)[0]

    return policy
