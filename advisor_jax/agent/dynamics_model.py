"""Neural network dynamics model of the MCP + model-free baseline (Nagabandi et al., ICRA 2018).

docs/baselines.md, "MCP + model-free". An MLP f predicts the normalised change of the 20-d
observation from the normalised observation and action; the next observation is the
current one plus the de-normalised change (``do_forward_sim`` of ``anagabandi/nn_dynamics``)::

    x      = [(s − μ_s) / σ_s,  (a − μ_a) / σ_a]                   # [22]
    Δs     = wrap_δ(s' − s)                                         # δ change in [−π, π)
    target = (Δs − μ_Δ) / σ_Δ                                       # [20]
    ŝ'     = wrap_δ(s + μ_Δ + σ_Δ · f(x))                           # δ back in [−π, π)

    f: 22 → 500 → 500 → 20, ReLU, linear head (272,020 parameters; He init, zero biases)

    normaliser: mean / std of s, a, Δs over the valid rows of the data (std floored at
                ``std_floor`` = 0.01), computed once from the random phase and then frozen.
                The floor is ours (the source adds 1e-6-scale epsilons): a component that
                never varied in the random episodes (a zone that never saw an obstacle)
                would otherwise blow its later inputs up by 10^6 (the model loss reached
                1e8 in the MCP+MF phase test); 0.01 is 1 % of the components' unit ranges
    fit step:   B ~ U{0, …, count − 1}^n  (the replay buffer's valid slots)
                x ← x + N(0, σ_noise²)     (input noise in normalised units, σ_noise = 0.01)
                L = mean_{i,j} (f(x_i)_j − target_ij)²;  Adam(lr) on L
    rollout:    ŝ_0 = s;  ŝ_{k+1} = predict(ŝ_k, a_k)  (open loop, lax.scan over k)

Only δ (index 16) is wrapped; ŝ' is not clipped to the contract's ranges (P ∈ [0, 1],
d ≥ 0): ``envs/reward.py`` clips where it scores, and an unclipped model stays a plain
function that the tests can check on a linear system.

Everything is a pure function of one model; the caller jits and vmaps (over agents, and
over candidates or start states). Learning rate and noise may be traced (vmapped
hyperparameters); the hidden widths, ``steps`` and ``batch_size`` are static.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from advisor_jax.agent.networks import he_init
from advisor_jax.contract import spec

ANGLE = spec.OBS_GOAL_ANGLE  # δ, the one periodic entry of the observation


class DynamicsMLP(nn.Module):
    """f(x): normalised [observation, action] → normalised observation change."""

    hidden: Sequence[int] = (500, 500)

    @nn.compact
    def __call__(self, obs_n: jax.Array, action_n: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs_n, action_n], axis=-1)
        for i, width in enumerate(self.hidden):
            x = nn.relu(nn.Dense(width, kernel_init=he_init, name=f"hidden_{i}")(x))
        return nn.Dense(spec.OBS_SIZE, kernel_init=he_init, name="head")(x)


@struct.dataclass
class Normalizer:
    """Statistics that map s, a and Δs to zero mean and unit std (all float32)."""

    obs_mean: jax.Array  # [20]
    obs_std: jax.Array  # [20]
    action_mean: jax.Array  # [2]
    action_std: jax.Array  # [2]
    delta_mean: jax.Array  # [20]
    delta_std: jax.Array  # [20]


@struct.dataclass
class DynamicsState:
    """One model: weights, Adam state and (frozen) normaliser."""

    params: Any
    opt_state: Any
    norm: Normalizer


class DynamicsModel(NamedTuple):
    """Pure functions of one dynamics model (built by ``make_dynamics_model``)."""

    module: DynamicsMLP
    init: Callable[[jax.Array], DynamicsState]
    """(key) -> DynamicsState with an identity normaliser (set it with ``normalizer_from_data``)."""
    predict: Callable[..., jax.Array]
    """(params, norm, obs [..., 20], action [..., 2]) -> predicted next obs [..., 20]."""
    rollout: Callable[..., jax.Array]
    """(params, norm, obs [20], actions [k, 2]) -> [k, 20]: ŝ after each action, open loop."""
    loss: Callable[..., jax.Array]
    """(params, norm, obs [n, 20], action [n, 2], next_obs [n, 20]) -> MSE of normalised Δs."""
    fit_step: Callable[..., tuple[DynamicsState, jax.Array]]
    """(state, data, count, key, lr, noise, batch_size) -> (state, loss): one Adam step."""
    fit: Callable[..., tuple[DynamicsState, jax.Array]]
    """(state, data, count, key, lr, noise, steps, batch_size) -> (state, losses [steps])."""


def wrap_angle(x: jax.Array) -> jax.Array:
    """Angle(s) in radians wrapped to [−π, π) (the env's ``observe`` rule)."""
    return jnp.mod(x + jnp.pi, 2.0 * jnp.pi) - jnp.pi


def observation_delta(obs: jax.Array, next_obs: jax.Array) -> jax.Array:
    """Δs = s' − s [..., 20] with the δ change wrapped to [−π, π)."""
    delta = jnp.asarray(next_obs) - jnp.asarray(obs)
    return delta.at[..., ANGLE].set(wrap_angle(delta[..., ANGLE]))


def apply_delta(obs: jax.Array, delta: jax.Array) -> jax.Array:
    """s + Δs [..., 20] with δ wrapped back to [−π, π)."""
    nxt = jnp.asarray(obs) + delta
    return nxt.at[..., ANGLE].set(wrap_angle(nxt[..., ANGLE]))


def identity_normalizer() -> Normalizer:
    """Zero means and unit stds: the normaliser before any data."""
    z, o = jnp.zeros, jnp.ones
    obs, act = spec.OBS_SIZE, spec.ACTION_SIZE
    return Normalizer(z(obs), o(obs), z(act), o(act), z(obs), o(obs))


def _masked_mean_std(x: jax.Array, mask: jax.Array, count: jax.Array, floor: float):
    w = mask[:, None].astype(x.dtype)
    mean = jnp.sum(w * x, axis=0) / count
    var = jnp.sum(w * jnp.square(x - mean), axis=0) / count
    return mean, jnp.maximum(jnp.sqrt(var), floor)


def normalizer_from_data(data: Any, count: jax.Array | int, std_floor: float = 0.01) -> Normalizer:
    """Mean / std of s, a and Δs over the first ``count`` rows of ``data``.

    ``data``: anything with ``obs`` [N, 20], ``action`` [N, 2] and ``next_obs`` [N, 20]
    (a ``replay_buffer.Transition``: pass ``replay.data, replay.size``). ``count`` may be
    traced; with ``count == 0`` it returns zero means and stds of ``std_floor`` (a total
    function under jit; the trainer only calls it once the random phase has filled data).
    """
    n = data.obs.shape[0]
    count = jnp.asarray(count)
    mask = jnp.arange(n) < count
    c = jnp.maximum(count, 1).astype(jnp.float32)
    delta = observation_delta(data.obs, data.next_obs)
    obs_mean, obs_std = _masked_mean_std(data.obs, mask, c, std_floor)
    act_mean, act_std = _masked_mean_std(data.action, mask, c, std_floor)
    d_mean, d_std = _masked_mean_std(delta, mask, c, std_floor)
    return Normalizer(obs_mean, obs_std, act_mean, act_std, d_mean, d_std)


def _check_positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return value


def make_dynamics_model(hidden: Sequence[int] = (500, 500)) -> DynamicsModel:
    """The dynamics model with these hidden widths (docs/baselines.md: (500, 500))."""
    hidden = tuple(hidden)
    if not hidden:
        raise ValueError("model hidden widths must name at least one layer, got ()")
    for width in hidden:
        _check_positive_int("every model hidden width", width)
    module = DynamicsMLP(hidden=hidden)

    def init(key: jax.Array) -> DynamicsState:
        params = module.init(key, jnp.zeros((1, spec.OBS_SIZE)), jnp.zeros((1, spec.ACTION_SIZE)))
        # Adam's state does not depend on the learning rate: any value builds it.
        return DynamicsState(params, optax.adam(1e-3).init(params), identity_normalizer())

    def normalise_inputs(norm: Normalizer, obs, action):
        return (obs - norm.obs_mean) / norm.obs_std, (action - norm.action_mean) / norm.action_std

    def predict(params, norm: Normalizer, obs: jax.Array, action: jax.Array) -> jax.Array:
        out = module.apply(params, *normalise_inputs(norm, obs, action))
        return apply_delta(obs, norm.delta_mean + norm.delta_std * out)

    def rollout(params, norm: Normalizer, obs: jax.Array, actions: jax.Array) -> jax.Array:
        def body(s, a):
            s = predict(params, norm, s, a)
            return s, s

        return jax.lax.scan(body, obs, actions)[1]

    def loss(params, norm, obs, action, next_obs, noise_key=None, noise=0.0) -> jax.Array:
        obs_n, act_n = normalise_inputs(norm, obs, action)
        if noise_key is not None:
            k_obs, k_act = jax.random.split(noise_key)
            obs_n = obs_n + noise * jax.random.normal(k_obs, obs_n.shape)
            act_n = act_n + noise * jax.random.normal(k_act, act_n.shape)
        target = (observation_delta(obs, next_obs) - norm.delta_mean) / norm.delta_std
        return jnp.mean(jnp.square(module.apply(params, obs_n, act_n) - target))

    def fit_step(state: DynamicsState, data, count, key, lr, noise, batch_size: int):
        batch_size = _check_positive_int("model batch_size", batch_size)
        k_idx, k_noise = jax.random.split(key)
        idx = jax.random.randint(k_idx, (batch_size,), 0, jnp.maximum(count, 1))
        obs, action, next_obs = data.obs[idx], data.action[idx], data.next_obs[idx]
        value, grads = jax.value_and_grad(loss)(
            state.params, state.norm, obs, action, next_obs, k_noise, noise
        )
        updates, opt_state = optax.adam(lr).update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return state.replace(params=params, opt_state=opt_state), value

    def fit(state: DynamicsState, data, count, key, lr, noise, steps: int, batch_size: int):
        steps = _check_positive_int("model steps", steps)

        def body(state, k):
            return fit_step(state, data, count, k, lr, noise, batch_size)

        return jax.lax.scan(body, state, jax.random.split(key, steps))

    return DynamicsModel(module, init, predict, rollout, loss, fit_step, fit)
