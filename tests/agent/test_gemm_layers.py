"""Each hidden layer one GEMM (agent/gemm_layers.py, ``networks.Layout.layers_in_gemm``).

The same function as the flax modules on the same parameters: values, parameter gradients
and ∇_a Q agree to fp32 rounding; in bf16 the layout is as close to fp32 as the modules'
bf16. The augmented matrices hold the kernel, the bias row and the ones column where the
docstring says; every GEMM width is a multiple of ``ALIGN``. A learner computing with them
takes the same updates as one computing with the modules. GPUs get the layout, CPUs not.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from advisor_jax.agent import gemm_layers, networks
from advisor_jax.agent.config import HParams, parse_agent
from advisor_jax.agent.learner import make_learner
from advisor_jax.bench.learner_loop import SMALL, fill_replay
from advisor_jax.contract import spec
from advisor_jax.training.program import network_layout
from tests.compare import max_relative_difference

BATCH = 16


def _with_biases(params, key):
    """The modules initialise biases to 0; shifted, every bias row matters."""
    leaves, tree = jax.tree.flatten(params)
    keys = jax.random.split(key, len(leaves))
    return tree.unflatten(
        [x + 0.1 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys, strict=True)]
    )


@pytest.fixture(scope="module")
def nets():
    actor, critic = networks.Actor(hidden=(24, 12)), networks.Critic(30, (20, 12))
    k_a, k_c, k_o, k_u = jax.random.split(jax.random.key(3), 4)
    actor_params = _with_biases(jax.jit(partial(networks.init_actor, actor))(k_a), k_a)
    init_critic = jax.jit(lambda k: critic.init(k, jnp.zeros((1, 20)), jnp.zeros((1, 2))))
    critic_params = _with_biases(init_critic(k_c), k_c)
    obs = jax.random.normal(k_o, (BATCH, spec.OBS_SIZE))
    action = jax.random.uniform(k_u, (BATCH, spec.ACTION_SIZE), minval=-1.0)
    return actor, critic, actor_params, critic_params, obs, action


def test_fp32_values_and_gradients_match_the_modules(nets):
    actor, critic, actor_params, critic_params, obs, action = nets

    def q_loss(apply):
        return lambda p, a: jnp.sum(apply(p, obs, a) ** 2)

    def pi_loss(apply):
        return lambda p: jnp.sum(apply(p, obs) ** 2)

    q_mod, q_gemm = jax.jit(critic.apply), jax.jit(gemm_layers.critic_apply)
    q_both = q_mod(critic_params, obs, action), q_gemm(critic_params, obs, action)
    assert max_relative_difference(*q_both) < 1e-5
    grads_mod = jax.jit(jax.grad(q_loss(q_mod), argnums=(0, 1)))(critic_params, action)
    grads_gemm = jax.jit(jax.grad(q_loss(q_gemm), argnums=(0, 1)))(critic_params, action)
    assert jax.tree.structure(grads_mod) == jax.tree.structure(grads_gemm)
    assert max_relative_difference(grads_mod, grads_gemm) < 1e-5  # θ and ∇_a Q
    pi_mod, pi_gemm = jax.jit(actor.apply), jax.jit(gemm_layers.actor_apply)
    assert max_relative_difference(pi_mod(actor_params, obs), pi_gemm(actor_params, obs)) < 1e-5
    assert (
        max_relative_difference(
            jax.jit(jax.grad(pi_loss(pi_mod)))(actor_params),
            jax.jit(jax.grad(pi_loss(pi_gemm)))(actor_params),
        )
        < 1e-5
    )


def test_bf16_is_as_close_to_fp32_as_the_modules_bf16(nets):
    actor, critic, actor_params, critic_params, obs, action = nets
    q32 = critic.apply(critic_params, obs, action)
    q_mod = jax.jit(networks.Critic(30, (20, 12), dtype=jnp.bfloat16).apply)
    q_mod = q_mod(critic_params, obs, action)
    q_gemm = jax.jit(partial(gemm_layers.critic_apply, dtype=jnp.bfloat16))
    q_gemm = q_gemm(critic_params, obs, action)
    scale = float(jnp.max(jnp.abs(q32)))
    assert (
        float(jnp.max(jnp.abs(q_gemm - q32)))
        <= 2 * float(jnp.max(jnp.abs(q_mod - q32))) + 0.01 * scale
    )
    a32 = actor.apply(actor_params, obs)
    a_gemm = jax.jit(partial(gemm_layers.actor_apply, dtype=jnp.bfloat16))(actor_params, obs)
    assert float(jnp.max(jnp.abs(a_gemm - a32))) < 0.05


def test_the_augmented_matrix_holds_kernel_bias_and_the_ones_column():
    kernel = jnp.arange(6.0).reshape(3, 2) + 1
    bias = jnp.asarray([7.0, 8.0])
    m = gemm_layers.layer_matrix([(kernel, 0)], bias, 8, jnp.float32)
    expected = np.zeros((8, 8))
    expected[:3, :2], expected[3, :2], expected[3, 2] = kernel, bias, 1.0
    np.testing.assert_array_equal(m, expected)
    x = jnp.asarray([[1.0, -2.0, 0.5]])
    y = gemm_layers.relu(gemm_layers.with_ones(x, jnp.float32) @ m)  # one hidden layer
    np.testing.assert_allclose(y[0, :2], jax.nn.relu(x @ kernel + bias)[0], rtol=1e-6)
    np.testing.assert_array_equal(y[0, 2:], [1.0, 0, 0, 0, 0, 0])  # ones column, padding


@pytest.mark.parametrize("n_out", [1, 2])
def test_the_head_from_bf16_sums_what_the_fp32_dot_sums(n_out):
    """From bf16 activations the head is products summed per output, with the fp32 dot's
    value and gradients (the activations' in bf16, as the dot's cast returns them)."""
    x = jax.random.normal(jax.random.key(1), (5, 40)).astype(jnp.bfloat16)
    m = jax.random.normal(jax.random.key(2), (40, n_out))
    dot = lambda x, m: x.astype(jnp.float32) @ m  # noqa: E731
    sums = partial(gemm_layers._head, sums=True)
    np.testing.assert_allclose(sums(x, m), dot(x, m), rtol=1e-5, atol=1e-5)
    loss = lambda f: lambda x, m: jnp.sum(jnp.sin(f(x, m)))  # noqa: E731
    got = jax.grad(loss(sums), argnums=(0, 1))(x, m)
    want = jax.grad(loss(dot), argnums=(0, 1))(x, m)
    assert got[0].dtype == jnp.bfloat16
    np.testing.assert_allclose(got[0].astype(jnp.float32), want[0].astype(jnp.float32),
                               rtol=1e-2, atol=1e-2)  # fmt: skip
    np.testing.assert_allclose(got[1], want[1], rtol=1e-5, atol=1e-5)
    uses_dot = lambda f, x: "dot_general" in str(jax.make_jaxpr(f)(x, m))  # noqa: E731
    assert uses_dot(gemm_layers._head, x) and not uses_dot(sums, x)
    assert uses_dot(sums, x.astype(jnp.float32))  # fp32 activations keep the dot


def test_relu_gradient_is_the_modules_relu_gradient():
    x = jnp.asarray([-1.0, 0.0, 2.0, -0.0, 3.5])
    g = jax.grad(lambda v: jnp.sum(gemm_layers.relu(v) * jnp.arange(5.0)))(x)
    np.testing.assert_array_equal(
        g, jax.grad(lambda v: jnp.sum(jax.nn.relu(v) * jnp.arange(5.0)))(x)
    )


def test_every_gemm_width_is_aligned_at_the_paper_sizes():
    cfg = parse_agent("ATD3+AfDP")
    critic = networks.make_critic(cfg)
    params = jax.eval_shape(
        lambda k: critic.init(k, jnp.zeros((1, 20)), jnp.zeros((1, 2))), jax.random.key(0)
    )
    obs, action = jnp.zeros((1000, 20)), jnp.zeros((1000, 2))
    jaxpr = jax.make_jaxpr(gemm_layers.critic_apply)(params, obs, action)
    dots = [e for e in jaxpr.eqns if e.primitive.name == "dot_general"]
    shapes = [tuple(e.invars[1].aval.shape) for e in dots]
    assert shapes[:3] == [(24, 1008), (1008, 504), (504, 608)]  # 22 → 1004 → 500 → 600, padded
    assert all(k % gemm_layers.ALIGN == 0 for k, _ in shapes)


def test_a_learner_on_gemm_layers_takes_the_modules_updates():
    sizes = dict(actor_hidden=(16, 16), critic_state_hidden=24, critic_hidden=(16, 16))
    cfg = parse_agent("ATD3+AfDP", **{**SMALL, **sizes, "batch_size": 32, "buffer_size": 256})
    replay = fill_replay(cfg.buffer_size, jax.random.key(1))
    states = {}
    for name, layout in (("modules", networks.MODULES), ("gemm", networks.Layout(True, True))):
        learner = make_learner(cfg, layout=layout)
        state, update = learner.init(jax.random.key(0)), jax.jit(learner.update)
        for u in range(cfg.delay + 1):  # critic steps and one actor step
            keys = jax.random.split(jax.random.key(10 + u))
            state, metrics, nonfinite = update(
                state, learner.sample(replay, keys[0]), keys[1], HParams(), u
            )
            assert not bool(nonfinite)
        states[name] = state
    assert max_relative_difference(states["modules"].critic, states["gemm"].critic) < 1e-4
    assert max_relative_difference(states["modules"].actor, states["gemm"].actor) < 1e-4


def test_gpus_get_the_layout_and_cpus_the_modules():
    assert network_layout("gpu") == networks.Layout(
        inputs_per_critic=True, layers_in_gemm=True, first_layer_kernel=True,
        bf16_first_moment=True, bf16_second_moment=True, bf16_critic_weights=True,
    )  # fmt: skip
    assert network_layout("cpu") == networks.MODULES


def test_gpu_programs_sum_their_heads_but_the_smallest_latency_bound_ones():
    from advisor_jax.training import program

    small, large = program.LATENCY_BOUND_AGENTS, program.LATENCY_BOUND_BF16_AGENTS
    for name in program.PROGRAMS:
        for precision in ("fp32", "bf16"):
            for agents in (1, small, large, None):
                layout = program.program_layout(name, precision, "gpu", agents_per_device=agents)
                unsummed = name == "latency-bound" and (agents is None or agents <= small)
                assert layout.head_sums == (not unsummed), (name, precision, agents)
            assert not program.program_layout(name, precision, "cpu").head_sums


def test_a_learner_with_summed_heads_is_the_same_function(nets):
    """``Layout.head_sums`` reaches both heads through ``learner_functions``: in bf16 the same
    Q and π but for the heads' fp32 sums' order, with one GEMM fewer each."""
    _, _, actor_params, critic_params, obs, action = nets
    actor = networks.Actor(hidden=(24, 12), dtype=jnp.bfloat16)
    critic = networks.Critic(30, (20, 12), dtype=jnp.bfloat16)
    gemm = networks.Layout(layers_in_gemm=True)
    plain = networks.learner_functions(actor, critic, gemm)
    summed = networks.learner_functions(actor, critic, gemm._replace(head_sums=True))
    cases = [(0, actor_params, (obs,)), (1, critic_params, (obs, action))]
    for i, params, inputs in cases:
        dots = [str(jax.make_jaxpr(f[i].apply)(params, *inputs)).count("dot_general")
                for f in (plain, summed)]  # fmt: skip
        assert dots[1] == dots[0] - 1
        np.testing.assert_allclose(
            summed[i].apply(params, *inputs), plain[i].apply(params, *inputs), rtol=1e-5, atol=1e-5
        )


def test_wider_hidden_alignment_pads_the_wide_layers_and_keeps_the_function(nets):
    """``Layout.hidden_align`` pads hidden widths of at least 8 × align to its multiples (the
    others and the inputs to ``ALIGN``): more zero columns, the same Q and π and the same
    parameter gradients in fp32."""
    _, _, _, _, obs, action = nets
    actor, critic = networks.Actor(hidden=(260, 12)), networks.Critic(300, (200, 12))
    k_a, k_c = jax.random.split(jax.random.key(4))
    actor_params = _with_biases(networks.init_actor(actor, k_a), k_a)
    critic_params = _with_biases(critic.init(k_c, jnp.zeros((1, 20)), jnp.zeros((1, 2))), k_c)
    narrow = networks.learner_functions(actor, critic, networks.Layout(layers_in_gemm=True))
    wide = networks.learner_functions(
        actor, critic, networks.Layout(layers_in_gemm=True, hidden_align=32)
    )
    # 300 + 4 + 1 = 305 ≥ 256 columns pad to 320; 201 and 13 to multiples of 8; the input 24
    assert [m.shape for m in wide[1].build(critic_params)] == [(24, 320), (320, 208),
                                                               (208, 16), (16, 1)]  # fmt: skip
    assert [m.shape for m in narrow[1].build(critic_params)][0] == (24, 312)
    assert [m.shape for m in wide[0].build(actor_params)] == [(24, 288), (288, 16), (16, 2)]
    cases = [(0, actor_params, (obs,)), (1, critic_params, (obs, action))]
    for i, params, inputs in cases:

        def loss(p, fns, inputs=inputs):
            return jnp.sum(fns.apply(p, *inputs) ** 2)

        want, want_grad = jax.value_and_grad(loss)(params, narrow[i])
        got, got_grad = jax.value_and_grad(loss)(params, wide[i])
        np.testing.assert_allclose(got, want, rtol=1e-5)
        assert max_relative_difference(got_grad, want_grad) < 1e-4


def test_bf16_latency_bound_populations_of_16_agents_or_more_align_their_widths_to_32():
    from advisor_jax.training import program

    for name in program.PROGRAMS:
        for precision in ("fp32", "bf16"):
            for agents in (1, 2, 15, 16, 32, 33, 64, None):
                got = program.program_layout(name, precision, "gpu", agents_per_device=agents)
                wide = (name, precision) == ("latency-bound", "bf16") and (agents or 0) >= 16
                assert got.hidden_align == (program.ALIGNED_WIDTHS if wide else 8), (name, agents)
            assert program.program_layout(name, precision, "cpu", 64).hidden_align == 8
    assert (program.ALIGNED_WIDTHS, program.ALIGNED_FROM_AGENTS) == (32, 16)
