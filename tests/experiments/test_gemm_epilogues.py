"""experiments/gemm_epilogues.py: counting GEMM library calls, epilogues and fusions."""

from __future__ import annotations

import json

from tests.experiments.scripts import load_script

gemm_epilogues = load_script("gemm_epilogues")

GEMM = (
    "  %custom-call.{i} = (bf16[2,1000,504]{{2,1,0}}, s8[8]{{0}}) custom-call(%a, %b), "
    'custom_call_target="__cublas$lt$matmul", '
    'backend_config={{"gemm_backend_config":{{"epilogue":"{epilogue}"}}}}'
)
HLO = "\n".join(  # lines of an HLO dump
    [
        GEMM.format(i=1, epilogue="RELU"),
        GEMM.format(i=2, epilogue="DEFAULT"),
        "  %loop_select_fusion.5 = bf16[2,1000,1008]{2,1,0} fusion(%e, %f), kind=kLoop",
        "  %dot.3 = f32[4,4]{1,0} dot(%g, %h), lhs_contracting_dims={1}",
    ]
)


def test_counts_of_a_known_hlo():
    assert gemm_epilogues.count(HLO) == dict(
        library_calls={"__cublas$lt$matmul": 2},
        epilogues={"RELU": 1, "DEFAULT": 1},
        fusions=1,
        dots=1,
    )


def test_cpu_smoke_run_keeps_dots_and_writes_its_report(tmp_path):
    assert gemm_epilogues.main(["--small", "--precision", "fp32", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "gemm_epilogues.json").read_text())
    row = report["rows"]["fp32"]
    assert report["backend"] == "cpu" and row["library_calls"] == {} and row["dots"] > 0
    assert (tmp_path / "hlo_fp32.txt").read_text().startswith("HloModule")
