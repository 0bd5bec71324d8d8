"""Comparing one agent trained along two code paths (vmapped vs lone, sharded vs not)."""

from __future__ import annotations

import jax
import numpy as np

# How far apart two float leaves of the same agent may end up, as a fraction of how far
# training moved the leaf (see ``assert_same_training``): parameters and targets, then
# Adam's moments, which hold the last gradients' summation noise undamped.
PARAM_REL, MOMENT_REL = 1e-2, 1e-1


def max_relative_difference(a, b) -> float:
    """The largest |a - b| of two pytrees' leaves, each relative to its leaf's largest |a|."""
    return max(
        float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64))))
        / max(float(np.max(np.abs(np.asarray(x, np.float64)))), 1e-30)
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True)
    )


def assert_same_training(got, want, start, what: str) -> None:
    """``got`` and ``want`` are the same agent trained along two code paths from ``start``.

    Integer leaves (counters, outcomes, lengths, firing counts) must be identical: they are
    only if every selector, noise and environment decision agreed. Float leaves may not be:
    a vmapped matmul sums in another order than a lone one, and which order depends on the
    CPU's vector width and XLA's tiling for it (an AMD EPYC and an Intel Xeon differ).
    Adam's g / (√v + ε) then turns a last-bit difference of a near-zero gradient into a
    visible fraction of a learning-rate step for that element, so no fixed absolute or
    elementwise tolerance holds on every CPU. What does not depend on the CPU is the
    *scale*: per leaf, ``‖got - want‖₂ ≤ rel · ‖want - start‖₂``, with rel = 1 % for
    parameters and targets and 10 % for Adam's moments (which start at 0 and carry the last
    gradients' summation noise undamped). Measured on the tiny population (2026-11-23):
    at most 0.06 % (parameters) and 0.5 % (moments) on an AMD EPYC, 0.0007 % on Intel, and
    240 % when two agents' β are swapped, a bug the discrete trajectory does not reveal
    (``test_the_check_catches_a_broken_vmap``). A leaf that training did not move must
    match to 1e-6 absolutely.
    """
    flat_got, tree_got = jax.tree_util.tree_flatten_with_path(got)
    flat_want, tree_want = jax.tree_util.tree_flatten(want)
    flat_start = jax.tree_util.tree_leaves(start)
    assert tree_got == tree_want, f"{what}: different structures"
    for (path, x), y, x0 in zip(flat_got, flat_want, flat_start, strict=True):
        x, y, x0 = np.asarray(x), np.asarray(y), np.asarray(x0)
        name = f"{what}{jax.tree_util.keystr(path)}"
        if not np.issubdtype(x.dtype, np.floating):
            np.testing.assert_array_equal(x, y, err_msg=name)
            continue
        np.testing.assert_array_equal(np.isnan(x), np.isnan(y), err_msg=f"{name}: NaNs differ")
        x, y, x0 = (np.nan_to_num(v.astype(np.float64)) for v in (x, y, x0))  # NaN: not played
        rel = MOMENT_REL if (".mu" in name or ".nu" in name) else PARAM_REL
        moved = np.linalg.norm((y - x0).ravel())
        gap = np.linalg.norm((x - y).ravel())
        bound = rel * moved + 1e-6 * np.sqrt(x.size)
        assert gap <= bound, (
            f"{name}: ‖Δ‖ = {gap:.3g} exceeds {rel:g} × the {moved:.3g} training moved it"
        )


def assert_same_agent(got, want, start, i: int) -> None:
    """Agent ``i``'s training state along two code paths: episode log and learner by
    ``assert_same_training``, completed episodes and counted env steps exactly."""
    assert_same_training(got.log, want.log, start.log, f"episode log of agent {i}")
    assert_same_training(got.learner, want.learner, start.learner, f"learner of agent {i}")
    assert int(got.episodes) == int(want.episodes)
    assert int(got.env_steps) == int(want.env_steps)
