"""The HLO reading of ``advisor_jax.bench.hlo_scopes`` on a small hand-written module, and the
script on a CPU compile of the training chunk."""

import gzip

from advisor_jax.bench import hlo_scopes

SCOPE = "jit(chunk)/vmap()/while/body/eval_jaxpr"
HLO = f"""HloModule chunk

%fused_joined (param_0: f32[2,608], param_1: f32[608]) -> (f32[2], f32[608]) {{
  %param_0 = f32[2,608]{{1,0}} parameter(0)
  %param_1 = f32[608]{{0}} parameter(1)
  %q = f32[2]{{0}} reduce(%param_0, %param_1), metadata={{op_name="{SCOPE}/collect/vmap()/dot_general"}}
  %adam = f32[608]{{0}} multiply(%param_1, %param_1), metadata={{op_name="{SCOPE}/learn/while/body/critic_step/mul"}}
  ROOT %t = (f32[2]{{0}}, f32[608]{{0}}) tuple(%q, %adam)
}}

%fused_keys (param_0: u32[2]) -> u32[2] {{
  %param_0 = u32[2]{{0}} parameter(0)
  ROOT %k = u32[2]{{0}} add(%param_0, %param_0), metadata={{op_name="{SCOPE}/collect/unstack"}}
}}

%body (p: (f32[2,608], f32[608], f32[100000,20])) -> (f32[2,608], f32[608], f32[100000,20]) {{
  %p = (f32[2,608]{{1,0}}, f32[608]{{0}}, f32[100000,20]{{1,0}}) parameter(0)
  %a = f32[2,608]{{1,0}} get-tuple-element(%p), index=0
  %b = f32[608]{{0}} get-tuple-element(%p), index=1
  %buf = f32[100000,20]{{1,0}} get-tuple-element(%p), index=2
  %joined = (f32[2]{{0}}, f32[608]{{0}}) fusion(%a, %b), kind=kInput, calls=%fused_joined
  %keys = u32[2]{{0}} fusion(%c), kind=kLoop, calls=%fused_keys
  %copy.1 = f32[100000,20]{{1,0}} copy(%buf)
  %copy.2 = u32[2]{{0}} copy(%keys)
  ROOT %out = (f32[2,608]{{1,0}}, f32[608]{{0}}, f32[100000,20]{{1,0}}) tuple(%a, %b, %copy.1)
}}

ENTRY %main (x: (f32[2,608], f32[608], f32[100000,20])) -> (f32[2,608], f32[608], f32[100000,20]) {{
  %x = (f32[2,608]{{1,0}}, f32[608]{{0}}, f32[100000,20]{{1,0}}) parameter(0)
  ROOT %w = (f32[2,608]{{1,0}}, f32[608]{{0}}, f32[100000,20]{{1,0}}) while(%x), condition=%cond, body=%body
}}
"""  # noqa: E501


def test_a_fusion_of_the_selector_product_and_adam_joins_the_halves_a_key_fusion_does_not():
    comps = hlo_scopes.computations(HLO)
    assert hlo_scopes.loop_bodies(HLO) == ["body"]
    assert hlo_scopes.kernels(comps, "body") == 4  # two fusions, two copies
    assert hlo_scopes.longest_kernel_chain(comps, "body") == 2  # keys, then its copy
    joined = hlo_scopes.joined_fusions(comps, "body")
    assert [(j.name, j.collect_ops, j.update_ops) for j in joined] == [("joined", 1, 1)]


def test_only_copies_of_at_least_the_size_asked_are_listed():
    comps = hlo_scopes.computations(HLO)
    buffer = ("f32[100000,20]{1,0}", 100000 * 20 * 4)
    assert hlo_scopes.large_copies(comps, "body", 256 * 1024) == [buffer]
    assert len(hlo_scopes.large_copies(comps, "body", 8)) == 2


def test_the_script_reads_a_saved_text_and_compiles_the_chunk(tmp_path, capsys, monkeypatch):
    import sys

    from tests.experiments.scripts import load_script

    script = load_script("hlo_fusion_scopes")
    saved = tmp_path / "chunk.hlo.gz"
    with gzip.open(saved, "wt") as f:
        f.write(HLO)
    assert script.report(script.read_hlo(saved), 256 * 1024, listing=True) == [
        "body: 4 kernels, 2 on its longest chain of data dependence, 1 joining the collection and "
        "the update, 1 copies of ≥ 256 KiB (7.6 MiB)",
        "  joined (f32[2]{0}, f32[608]{0}) (collect ops 1, update ops 1)",
        "  longest chain by half: collect 1, other 1",  # the key fusion, then its copy
    ]
    # the chunk as training compiles it on this CPU: its scan is the largest loop body
    argv = ["hlo_fusion_scopes.py", "--agents", "1", "--chunk", "4", "--top", "1"]
    monkeypatch.setattr(sys, "argv", argv)
    script.main()
    (line,) = capsys.readouterr().out.strip().splitlines()
    assert "joining the collection and the update" in line
    kernels = int(line.split(": ")[1].split(" kernels")[0])
    chain = int(line.split("kernels, ")[1].split(" on its")[0])
    assert kernels > 50  # a whole training step: the env, the advisor, the update
    assert 0 < chain <= kernels
