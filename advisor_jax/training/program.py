"""How a population's training program is built and compiled: the one home of those choices.

``population_functions(cfg, placement)`` returns ``(trainer, jit(vmap(init)),
jit(vmap(chunk)))``, the program ``host_loop.run_training`` runs. It decides, from the
config and the devices, what the pure functions of ``agent/`` and ``training/train.py``
leave open:

* which trainer: the paper's agents' (``train.make_train``) or a baseline's, whose prior
  phases wrap the same core (``training/prior/``);
* the chunk's program (``PROGRAMS``, ``choose_program``): the general program, the steady
  one (``train.make_train``'s ``steady``: sharded populations on GPUs, and bf16 populations
  on one GPU whose memory holds it) or the latency-bound one (the steady program with
  overlapping kernels, for at most ``latency_bound_agents(precision)`` agents per GPU);
* how the learner's networks are computed (``networks.Layout``: ``network_layout``,
  ``program_layout``): the twin critics' inputs, each hidden layer one GEMM
  (``agent/gemm_layers.py``), held target networks (``holds_networks``) and critics
  (``holds_critics``), summed heads (``sums_heads``), the widths' alignment
  (``ALIGNED_WIDTHS``) and the critic's first-layer kernel (``agent/masked_wgrad.py``);
* the XLA options of the compiled chunk (``training/compiler.py``: ``compiler_options``),
  which depend on the learner's precision (``AgentConfig.precision``), on the latency-bound
  program and on ``separates_outputs``.

CPUs get XLA's defaults and the shared twin layout, so that CPU results stay bit for bit
what they were. The measurements behind each choice are in ``results/`` (linked below).
"""

from __future__ import annotations

import jax

from advisor_jax.agent.config import TrainConfig
from advisor_jax.agent.networks import Layout
from advisor_jax.training.compiler import compiler_options
from advisor_jax.training.devices import AXIS, Placement
from advisor_jax.training.prior.trainer import make_prior_program
from advisor_jax.training.train import make_train

LATENCY_BOUND_AGENTS = 32
"""Populations of fp32 learners of at most this many agents per device run, on GPUs, the
latency-bound program: the chunk's steady program compiled with overlapping kernels and
whole-loop graphs (``compiler_options``). Its kernels are too small to fill a GPU one at a
time; larger populations fill it (``results/bench_train_steady/``)."""

LATENCY_BOUND_BF16_AGENTS = 64
"""``LATENCY_BOUND_AGENTS`` for bf16 learners: since the draw-first store
(``training/draws.py``) the collection's kernels may run beside the update's, and at 40-64
bf16 agents the latency-bound program (heads summed, ``sums_heads``) ran 1.02-1.08× the
steady one on an H200, 64 seeds training every episode the same; 128 agents ran 0.99×
(``results/bench_latency_bound_64/``)."""

STEADY_BF16_BYTES_PER_AGENT = int(1.25 * 45.84 / 512 * 2**30)
"""A ``paper``-size bf16 agent's share of a GPU's memory in the steady program on one GPU
(``steady_fits``): the peak at 512 agents on an H100, 45.84 GiB (the general program's: 32.44),
per agent, with a quarter more as margin (``results/bench_train_programs/``)."""


def twin_inputs_per_critic(backend: str | None = None) -> bool:
    """The twin critics' input layout (``networks.apply_critics``): per critic on a GPU, shared
    otherwise (``backend``: JAX's default when None; other accelerators are not measured),
    whatever the learner's precision. On GPUs each layer is then one GEMM per critic with no
    transposing pass (``results/bench_learner_twin_inputs/``, ``results/bench_learner_cublas/``).
    On CPUs the per-critic GEMMs sum in another order, changing fixed-seed trajectories in
    their last bits, so CPU runs keep the shared layout and their results."""
    backend = jax.default_backend() if backend is None else backend
    return backend == "gpu"


def layers_in_gemm(backend: str | None = None) -> bool:
    """Whether the learner's hidden layers run as one GEMM each, bias and ReLU inside
    (``agent/gemm_layers.py``): on a GPU (``backend``: JAX's default when None), where the bias
    add, the bias gradient's reduction and the ReLU were passes of their own over every
    activation (``results/bench_learner_gemm_layers/``). CPUs keep the flax modules and their
    results bit for bit."""
    backend = jax.default_backend() if backend is None else backend
    return backend == "gpu"


def network_layout(backend: str | None = None) -> Layout:
    """How the learner's networks are computed on ``backend`` (JAX's default when None):
    ``networks.Layout`` from ``twin_inputs_per_critic`` and ``layers_in_gemm``, and with the
    GEMM layers the critic's first-layer kernel (``agent/masked_wgrad.py``; the 128-agent
    learner 1.03-1.04×, the same updates: ``results/bench_first_layer_kernel/``), which a
    population split over several GPUs runs on each device's agents. A GPU's bf16 learner
    also keeps Adam's first and second moments in bf16 (``agent/adam.py``; 1.035× and
    1.018×) and the held critics' hidden matrices in bf16 only, updated by stochastic
    rounding (14 bytes per parameter in Adam's pass instead of 20), each measured on an H100
    with training unmoved over 16 seeds (``results/bench_bf16_first_moment/``,
    ``results/bench_bf16_second_moment/``, ``results/bench_bf16_critic_weights/``)."""
    gemm = layers_in_gemm(backend)
    return Layout(twin_inputs_per_critic(backend), gemm, first_layer_kernel=gemm,
                  bf16_first_moment=gemm, bf16_second_moment=gemm,
                  bf16_critic_weights=gemm)  # fmt: skip


HELD_STEADY_BF16_AGENTS = 256
"""The most agents per device whose bf16 critics the steady program holds (``holds_critics``).
One H100, jax 0.11.2, held against not held in one command: 1.02× at 64 agents (three
commands) and 1.01× at 256, peak 6.18 / 25.21 GiB against 5.69 / 22.61; 0.98× at 384; at 512
agents 0.93× (the compiler wanted 82.5 GiB and rematerialized), peak 48.88 GiB against 45.84
(``results/bench_held_critics/``)."""


def holds_critics(program: str, precision: str, agents_per_device: int | None = None) -> bool:
    """Whether the chunk's ``program`` holds its ``precision`` learners' critics as their GEMM
    layers' matrices (``Layout.held_critics``, ``agent/held_critics.py``): no matrix build in
    the loop, Adam and the soft update on the matrices; a 16-seed bf16 population trained the
    same, episode for episode. Where it paid, each measured on one H100 (jax 0.11.2) against
    the tree before in one command (``results/bench_held_critics/``,
    ``results/bench_latency_bound_held/``): fp32 learners in the general program (the
    128-agent learner 1.04-1.05×), bf16 learners in the steady program with at most
    ``HELD_STEADY_BF16_AGENTS`` agents per device (``agents_per_device``; None: unknown, not
    held) and in the latency-bound program (with their targets, ``holds_networks``). Not
    measured to pay, so not held: fp32's steady and latency-bound programs, bf16's general
    program (one GPU gives it only to populations too large for the steady one)."""
    if (program, precision) == ("general", "fp32"):
        return True
    if program == "latency-bound":
        return holds_networks(program, precision)
    small = agents_per_device is not None and agents_per_device <= HELD_STEADY_BF16_AGENTS
    return (program, precision) == ("steady", "bf16") and small


def sums_heads(program: str, agents_per_device: int | None = None) -> bool:
    """Whether the chunk's ``program`` computes a bf16 learner's fp32 output heads from its bf16
    activations as products summed per output (``Layout.head_sums``), not a cast and an fp32
    GEMM. One H100, jax 0.11.2, against the tree before: the 128-agent bf16 learner 1.022×
    (steady, two commands), the 64-agent step 1.024×; the 1-agent latency-bound step 0.98× and
    0.963×, so not in the latency-bound program of at most ``LATENCY_BOUND_AGENTS`` agents per
    device (``agents_per_device``; None: unknown, as there) (``results/bench_head_sums/``);
    above that, 64 agents 1.022× on one H200 (``results/bench_latency_bound_64/``)."""
    if program != "latency-bound":
        return True
    return agents_per_device is not None and agents_per_device > LATENCY_BOUND_AGENTS


ALIGNED_WIDTHS = 32
"""``Layout.hidden_align`` of bf16 learners in the latency-bound program of at least
``ALIGNED_FROM_AGENTS`` agents per device (paper sizes: critic 24 → 1024 → 512 → 608, actor
24 → 608 → 320). One H100, jax 0.11.2, a process each, align 8 against 32 in agent env-steps/s
(``results/bench_width_align/``): 64 agents (8, 64, 32, 8) 17,256, 18,256, 18,209, 17,253; 32
agents 16,093 → 16,911 (1.051×); 16 agents 15,180 → 16,006 (1.054×). 48 seeds of ``stable``
trained every episode the same at 8 and at 32; 32 seeds moved no more than one program moves
between two processes (``results/precision_study/width_align/``)."""

ALIGNED_FROM_AGENTS = 16
"""The fewest agents per device whose widths are aligned to ``ALIGNED_WIDTHS``: the smallest
population measured (fewer keep 8 until measured)."""


def program_layout(
    program: str, precision: str, backend: str | None = None, agents_per_device: int | None = None
) -> Layout:
    """``network_layout`` for the chunk's ``program`` and the learners' ``precision``: with the
    critics held where ``holds_critics`` says for ``agents_per_device``, the heads summed
    where ``sums_heads`` says and the widths aligned as ``ALIGNED_WIDTHS`` says (all only with
    ``layers_in_gemm``)."""
    layout = network_layout(backend)
    gemm = layout.layers_in_gemm
    held = gemm and holds_critics(program, precision, agents_per_device)
    heads = gemm and sums_heads(program, agents_per_device)
    wide = agents_per_device is not None and agents_per_device >= ALIGNED_FROM_AGENTS
    wide = gemm and wide and (program, precision) == ("latency-bound", "bf16")
    align = ALIGNED_WIDTHS if wide else layout.hidden_align
    return layout._replace(held_critics=held, head_sums=heads, hidden_align=align)


def holds_networks(program: str, precision: str = "fp32") -> bool:
    """Whether the chunk's ``program`` (one of ``PROGRAMS``) has its ``precision`` learners
    hold the target networks built (``Learner.hold``; only with ``layers_in_gemm``): once per
    soft update instead of once per critic step, the same updates. Every program but the
    latency-bound one, which holds them (and then its critics, ``holds_critics``) for bf16
    learners only. One H100, jax 0.11.2, the full step against the tree before in one command:
    the 64-agent bf16 step 1.05× (``results/bench_held_targets/``), the latency-bound bf16
    step 1.03-1.09× from 1 to 32 agents (``results/bench_latency_bound_held/``,
    ``results/bench_bf16_critic_weights/``); its fp32 learners ran 1.07× unheld at 32 agents."""
    if program != "latency-bound":
        return True
    return precision == "bf16"


def stores_free(program: str, agents_per_device: int | None = None) -> bool:
    """Whether the chunk's ``program`` stores each step's transition with no barrier
    (``train.make_train``'s ``free_store``, ``draws.store_free``), not once the step's update
    is computed (``draws.store_after``): the latency-bound program of one agent per device
    (``agents_per_device``; None: unknown, not free). One H100, jax 0.11.2, the full step
    against the store after the update in one command (``results/bench_draw_first/``): 1
    agent 1.05×, but 2 agents 0.87×. An earlier round agrees at 1 agent: the same store (commit
    9622059) ran 1.11× the store-first order where the store after the update runs 1.05×."""
    return program == "latency-bound" and agents_per_device == 1


def separates_outputs(program: str, precision: str, agents_per_device: int | None = None) -> bool:
    """Whether the chunk's ``program`` compiles without XLA's multi-output fusion
    (``compiler.SEPARATE_OUTPUTS``): the latency-bound program of one or two bf16 agents per
    device (``agents_per_device``; None: unknown, not separate). One H100, jax 0.11.2, A B A (B): 1
    agent 1.13× (4,741 -> 5,370 / 5,385; 1.14× in another command), 2 agents 1.15× (7,252 /
    7,294 -> 8,334 / 8,388; 1.14× in another); 8 agents 0.95×, 64 agents 0.90×."""
    return program == "latency-bound" and precision == "bf16" and agents_per_device in (1, 2)


PROGRAMS = ("general", "steady", "latency-bound")
"""The chunk's programs (``population_functions``' ``program``):

* ``general``: one ``lax.cond`` per step for warm-up and TD3's delayed actor step, XLA's
  scheduling;
* ``steady``: past warm-up, blocks of d steps written out, the first with the actor step, no
  conditional in the loop (``train.make_train``'s ``steady``), XLA's scheduling;
* ``latency-bound``: the steady program compiled with overlapping kernels and whole-loop
  graphs (``compiler_options``): faster for small populations (``latency_bound_agents``).

Where a config has no steady program (``make_train``) the steady ones run the general one."""


def latency_bound_agents(precision: str) -> int:
    """The most agents per GPU of ``precision`` learners that get the latency-bound program."""
    return LATENCY_BOUND_BF16_AGENTS if precision == "bf16" else LATENCY_BOUND_AGENTS


def latency_bound(
    placement: Placement | None, backend: str | None = None, precision: str = "fp32"
) -> bool:
    """Whether ``placement``'s population of ``precision`` learners gets the latency-bound
    program on ``backend`` (JAX's default when None): at most ``latency_bound_agents(precision)``
    agents per GPU. An unknown population (None) does not."""
    backend = jax.default_backend() if backend is None else backend
    if backend != "gpu" or placement is None:
        return False
    return placement.n_padded // placement.n_devices <= latency_bound_agents(precision)


def steady_fits(placement: Placement, memory_bytes: int | None = None) -> bool:
    """Whether one device holds ``placement``'s population in the steady program at
    ``STEADY_BF16_BYTES_PER_AGENT`` per agent within ``memory_bytes`` (None: what JAX may
    allocate on the first device, its ``memory_stats()["bytes_limit"]``; unknown: no)."""
    if memory_bytes is None:
        stats = jax.devices()[0].memory_stats() or {}
        memory_bytes = stats.get("bytes_limit")
    if not memory_bytes:
        return False
    return placement.n_padded * STEADY_BF16_BYTES_PER_AGENT <= memory_bytes


def choose_program(
    placement: Placement | None,
    backend: str | None = None,
    precision: str = "fp32",
    memory_bytes: int | None = None,
) -> str:
    """The chunk's program (``PROGRAMS``) for ``placement``'s population of ``precision``
    learners (``AgentConfig.precision``) on ``backend`` (JAX's default when None):

    * latency-bound where it pays (``latency_bound``: at most 32 fp32 or 64 bf16 agents per
      GPU, ``latency_bound_agents``);
    * steady for a larger population sharded over several GPUs. XLA's GPU compile (jax
      0.11.2, its default partitioner Shardy) puts 20 all-gathers into the general
      program's loop, all in the conditional of TD3's delayed actor step; the steady loop
      has no conditional and none of them. 256 bf16 agents on two / four H200s then run
      1.95× / 3.70× one GPU instead of 1.26× / 1.70× (``results/multigpu_hlo.md``,
      ``results/bench_multigpu/``). It costs memory: 46 GiB for 512 agents on one GPU
      against the general program's 34;
    * steady for a larger bf16 population on one GPU whose memory holds it (``steady_fits``,
      ``memory_bytes`` as there): on one H100 (jax 0.11.2, two commands each, alternating)
      the steady program ran 1.02–1.03× the general one at 64 bf16 agents, 1.04× at 256 and
      1.03× at 512 (``results/bench_train_programs/``), with that third more memory;
    * else the general program: CPUs (whose results stay bit for bit what they were), fp32
      learners on one GPU (the steady program was 0.96× at 64 fp32 agents on an H200 before
      the held target networks, ``results/bench_train_programs/``), and populations too
      large for the steady program's memory, so that the largest population that fits
      stays as large."""
    backend = jax.default_backend() if backend is None else backend
    if latency_bound(placement, backend, precision):
        return "latency-bound"
    if backend != "gpu" or placement is None:
        return "general"
    if placement.n_devices > 1:
        return "steady"
    if precision == "bf16" and steady_fits(placement, memory_bytes):
        return "steady"
    return "general"


def resolve_program(
    program: str | None, placement: Placement | None, precision: str = "fp32"
) -> str:
    """The program that runs for a request of ``program`` (None or "auto": ``choose_program``'s
    pick for ``placement`` and ``precision``); a name not in ``PROGRAMS`` is refused."""
    if program in (None, "auto"):
        program = choose_program(placement, precision=precision)
    if program not in PROGRAMS:
        raise ValueError(f"program {program!r}: not one of {PROGRAMS}")
    return program


def population_functions(
    cfg: TrainConfig, placement: Placement | None = None, program: str | None = None
):
    """(trainer, jit(vmap(init)), jit(vmap(chunk))) for ``cfg``: the population's program.

    ``program``: one of ``PROGRAMS``; None or "auto": as ``choose_program`` picks it for
    ``placement`` and the learner's precision.

    With a multi-device ``placement`` the agent axis of keys, state, hyperparameters and
    metrics is sharded over its mesh and the step index replicated (``devices``); inputs
    must then be padded to ``placement.n_padded`` agents. Each call builds new jitted
    functions (jit compiles on their first call); callers that train several populations
    of one config keep and reuse them."""
    program = resolve_program(program, placement, cfg.agent.precision)
    overlap = program == "latency-bound"
    per_device = None if placement is None else placement.n_padded // placement.n_devices
    layout = program_layout(program, cfg.agent.precision, agents_per_device=per_device)
    # The agent axis carries the mesh axis's name: a collective over it inside the step
    # (``lax.pmin(x, AXIS)``) would be an all-reduce between devices at every step. None is
    # written; tests/training/test_collectives.py injects one to show that its check of the
    # compiled chunk (no collective inside the scan) catches it.
    if cfg.agent.baseline is None:
        hold = holds_networks(program, cfg.agent.precision)
        free = stores_free(program, per_device)
        trainer = make_train(cfg, program != "general", layout, hold, free)
        chunk = jax.vmap(trainer.chunk, in_axes=(0, 0, None), axis_name=AXIS)
    else:  # LfD, MCP+MF: the gate from every agent but the padding ones, unbatched
        baseline = make_prior_program(cfg, layout)
        n_real = None if placement is None else placement.n_agents
        trainer, chunk = baseline.trainer, baseline.population_chunk(n_real, AXIS)
    init = jax.vmap(trainer.init)
    # A baseline (no steady program) still overlaps its kernels when latency-bound.
    separate = separates_outputs(program, cfg.agent.precision, per_device)
    options = compiler_options(cfg.agent.precision, overlap=overlap, steady=trainer.steady,
                               separate=separate)  # fmt: skip
    if placement is None or placement.mesh is None:
        return trainer, jax.jit(init), jax.jit(chunk, donate_argnums=0, compiler_options=options)
    agents, replicated = placement.agents(), placement.replicated()
    init_fn = jax.jit(init, in_shardings=agents, out_shardings=agents)
    chunk_fn = jax.jit(
        chunk,
        in_shardings=(agents, agents, replicated),
        out_shardings=agents,
        donate_argnums=0,
        compiler_options=options,
    )
    return trainer, init_fn, chunk_fn
