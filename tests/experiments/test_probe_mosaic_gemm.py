"""experiments/probe_mosaic_gemm.py: JAX's Mosaic GPU matmul, as the probe calls it, computes
XLA's product (the Mosaic GPU interpreter on the CPU)."""

from __future__ import annotations

from tests.experiments.scripts import load_script


def test_the_probe_calls_the_matmul_kernel_right(tmp_path):
    script = load_script("probe_mosaic_gemm")
    result = script.main(["--out", str(tmp_path)])
    # within one bf16 unit of the largest entry: both round fp32 sums of the same products
    assert result["check_small"]["matmul"] <= 2**-8
    assert result["rows"] == []  # no timing off a GPU
    assert "Mosaic GPU GEMMs" in (tmp_path / "probe_mosaic_gemm.md").read_text()


def test_a_wrong_operand_order_is_caught():
    script = load_script("probe_mosaic_gemm")
    a, b = script.operands((128, 128), (128, 128), seed=1)
    wrong = script.mosaic_matmul(b, a, (64, 64, 2, "N"), cores=2)
    assert script.relative_error(wrong, a @ b) > 0.1
