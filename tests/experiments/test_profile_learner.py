"""``profile_learner.py``'s join of a trace to its HLO: each XLA kernel's bytes per launch
(``trace.instruction_bytes``), the rate they give, and the role of a memory-bound pass."""

from __future__ import annotations

import pytest

from advisor_jax.bench import trace
from tests.experiments.scripts import load_script

FUSION = (
    "%loop_add_convert_fusion.7 = (bf16[4,8]{1,0}, f32[4,8]{1,0}) fusion(%p.1, %g.2, "
    '/*index=2*/%mask.3), kind=kLoop, calls=%fused, metadata={op_name="jit(f)/critic_step/'
    'convert_element_type"}'
)
HLO = f"""
ENTRY %main {{
  %p.1 = f32[4,8]{{1,0}} parameter(0)
  %g.2 = bf16[4,8]{{1,0}} parameter(1)
  %mask.3 = pred[8]{{0}} parameter(2)
  {FUSION}
  ROOT %t = (bf16[4,8]{{1,0}}, f32[4,8]{{1,0}}) tuple(%loop_add_convert_fusion.7)
}}
"""


def test_a_kernels_bytes_are_its_operands_and_outputs():
    moved = trace.instruction_bytes(HLO)
    # operands f32 4x8 (128) + bf16 (64) + pred[8] (8); outputs bf16 (64) + f32 (128)
    assert moved["loop_add_convert_fusion.7"] == 128 + 64 + 8 + 64 + 128
    assert trace.hlo_name("loop_add_convert_fusion_7", moved) == "loop_add_convert_fusion.7"
    assert trace.hlo_name("nvjet_sm90_gemm", moved) == "nvjet_sm90_gemm"


def test_the_join_gives_xla_kernels_a_rate_and_library_calls_none():
    script = load_script("profile_learner")
    events = [dict(name="loop_add_convert_fusion_7", dur=0.1) for _ in range(4)]
    events += [dict(name="nvjet_sm90_gemm", dur=5.0)]
    rows = {r["kernel"]: r for r in script.attribute(events, HLO, n_updates=2)}
    fusion = rows["loop_add_convert_fusion_7"]
    assert fusion["mb_per_launch"] == pytest.approx(392e-6)
    assert fusion["gb_per_s"] == pytest.approx(392 * 4 / 0.4e-6 / 1e9)  # 4 launches in 0.4 µs
    assert fusion["role"] == script.ADAM and fusion["calls_per_update"] == 2
    assert "gb_per_s" not in rows["nvjet_sm90_gemm"]


@pytest.mark.parametrize(
    "shape, op_name, role",
    [
        ("(bf16[2,8]{1,0}, f32[2,8]{1,0})", "critic_step/convert_element_type", "ADAM"),
        ("(bf16[2,8]{1,0}, bf16[2,8]{1,0}, bf16[2,8]{1,0})", "critic_step/jit(_where)/select_n",
         "ADAM"),
        ("(f32[2,9]{1,0}, f32[2,9]{1,0}, f32[2,9]{1,0})", "critic_step/vmap()/reduce_sum", ""),
        ("(f32[9,1]{1,0}, f32[9,1]{1,0})", "actor_step/transpose(jvp())/unstack", ""),
        ("bf16[2,9]{1,0}", "critic_step/transpose(critic_step)/jvp(jit(_where))/select_n",
         "ReLU's backward mask"),
    ],
)  # fmt: skip
def test_roles_of_memory_bound_passes(shape, op_name, role):
    script = load_script("profile_learner")
    assert script.role_of(shape, op_name) == (script.ADAM if role == "ADAM" else role)
