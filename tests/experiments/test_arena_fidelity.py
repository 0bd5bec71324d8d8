"""experiments/arena_fidelity.py rebuilds results/arena_fidelity.json from the kept run data."""

from __future__ import annotations

import json
from pathlib import Path

from tests.experiments.scripts import load_script

RESULTS = Path(__file__).resolve().parents[2] / "results"


def test_the_summary_is_made_from_the_kept_runs(tmp_path):
    record = load_script("arena_fidelity").main(tmp_path)
    cells = {(c["arena"], c["settings"]): c for c in record["cells"]}
    assert set(cells) == {(a, s) for a in ("kinematic", "mjx") for s in ("stable", "paper")}
    for cell in cells.values():  # every type in every cell (MCP+MF at `paper`: ordering_mcp)
        assert set(cell["rows"]) == {"ATD3+AfDP", "LfD", "MCP+MF", "DDPG"}
    seeds = {(*key, t): row["seeds"] for key, c in cells.items() for t, row in c["rows"].items()}
    assert seeds.pop(("kinematic", "stable", "ATD3+AfDP")) == 32  # Table 1's runs
    assert set(seeds.values()) == {16}
    mjx = cells["mjx", "stable"]
    pair = mjx["pairs"]["ATD3+AfDP - LfD"]["training"]
    assert pair["seeds"] == 16
    committed = json.loads((RESULTS / "arena_fidelity.json").read_text())
    assert json.loads(json.dumps(record["cells"])) == committed["cells"]  # the file is current
