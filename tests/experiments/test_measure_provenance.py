"""Every benchmark report records where it was measured (``bench.measure.provenance``),
including settings that change what the number means."""

from __future__ import annotations

from advisor_jax.bench import measure


def test_provenance_records_the_gpu_memory_share_when_set(monkeypatch):
    for name in measure.MEMORY_SETTINGS:
        monkeypatch.delenv(name, raising=False)
    assert "memory_settings" not in measure.provenance()
    monkeypatch.setenv("XLA_PYTHON_CLIENT_MEM_FRACTION", "0.95")
    record = measure.provenance()
    assert record["memory_settings"] == {"XLA_PYTHON_CLIENT_MEM_FRACTION": "0.95"}
    assert {"date", "device", "jax"} <= set(record)
