"""Hidden widths padded to multiples of 16, 32 or 64 instead of 8: does the full step run faster?

``gemm_layers`` pads every GEMM width with zero columns to a multiple of ``ALIGN`` (8: the
tensor cores' 16 bytes at bf16), so the paper's critic runs [24 → 1008 → 504 → 608]. cuBLAS
ran the critics' weight gradients at shapes padded to multiples of 64 (1024×512 and 512×640,
batch 1024) in 7 % and 4 % less time than at the paper's, for more arithmetic
(``results/bench_wgrad_adam/``: ``probe_mosaic_gemm.py``). This benchmark asks the question
for the whole training step: ``bench_train.py``'s ``full_step`` with the learner's
``networks.Layout.hidden_align`` set to ``--align`` whatever the program would choose
(``program.program_layout``, ``ALIGNED_WIDTHS``): hidden widths of at least 8 × align padded
to its multiples (``gemm_layers.padded``), the inputs to 8. The padding columns stay 0, so the
function is the same; the sums' order, and so the rounding, may differ.

    python experiments/bench_width_align.py --align 8 64 32 8 --agents 64   # one GPU
    python experiments/bench_width_align.py --align 16 --preset quick --agents 1 --chunk 20  # CPU

On a CPU the learner keeps its flax modules (``program.layers_in_gemm``), which no padding
touches: a CPU run exercises the script, not the question. Each alignment runs in a process
of its own (its own compile, nothing shared), one after another in the order given; repeat
one (``8 64 32 8``) to see the drift. Writes ``--out``/``--name``.json and .md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp

from advisor_jax.agent import gemm_layers
from advisor_jax.agent.config import preset
from advisor_jax.agent.networks import init_critics, make_critic
from advisor_jax.bench import measure, writing
from advisor_jax.fileio import atomic_write_json
from advisor_jax.training import program


def _check(align: int) -> None:
    if align < 1 or align % gemm_layers.ALIGN:
        raise ValueError(f"--align {align} must be a positive multiple of {gemm_layers.ALIGN}")


def pad_widths_to(align: int) -> None:
    """From now on, in this process, every program's learners pad their hidden widths to
    ``align`` (``Layout.hidden_align``)."""
    _check(align)
    chosen = program.program_layout
    program.program_layout = lambda *a, **k: chosen(*a, **k)._replace(hidden_align=align)


def critic_shapes(preset_name: str, align: int, agent: str = "ATD3+AfDP") -> list[list[int]]:
    """The critic's GEMM matrices' shapes at ``preset_name`` and ``align``."""
    critic = make_critic(preset(preset_name, agent)[0].agent)
    params = jax.eval_shape(lambda k: init_critics(critic, k, 1), jax.random.key(0))
    params = jax.tree.map(lambda leaf: jnp.zeros(leaf.shape[1:], leaf.dtype), params)
    return [list(m.shape) for m in gemm_layers.critic_matrices(params, jnp.float32, align)]


def one(align: int, args: argparse.Namespace) -> dict:
    """``full_step`` of ``args``' population with the widths padded to ``align``."""
    from advisor_jax.bench.full_step import full_step

    pad_widths_to(align)
    row = full_step(args.preset, args.agent, args.agents, 1, args.precision, args.chunk,
                    args.repeats, chunk_program=args.program)  # fmt: skip
    return dict(align=align, critic_shapes=critic_shapes(args.preset, align, args.agent), **row)


def report(result: dict, command: str) -> list[str]:
    first = result["rows"][0]["agent_steps_per_s"]
    table = writing.markdown_table(
        ("order", "align", "critic GEMMs", "program", "agent env-steps/s", "× the first row"),
        [(i + 1, r["align"], " → ".join(str(s[1]) for s in r["critic_shapes"][:-1]),
          r["program"], r["agent_steps_per_s"], r["agent_steps_per_s"] / first)
         for i, r in enumerate(result["rows"])],
        formats=("", "", "", "", ",.0f", ".3f"),
        align="rrlrrr",
    )  # fmt: skip
    return [
        "# The full step with hidden widths padded to multiples of `align`", "",
        f"{result['agent']}, preset `{result['preset']}`, {result['agents']} agents, "
        f"{result['precision']}, {result['chunk']}-step chunks, best of {result['repeats']}; "
        f"{result['device']}, jax {result['jax']}, {result['date']}. One process per row, in "
        "this order.", "", *table, "", f"Command: `{command}`", "",
    ]  # fmt: skip


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--align", type=int, nargs="+", default=[8, 64, 32, 8],
                        help="one process per value, in this order")  # fmt: skip
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--agent", default="ATD3+AfDP")
    parser.add_argument("--agents", type=int, default=64)
    parser.add_argument("--precision", default="bf16", choices=["bf16", "fp32"])
    parser.add_argument("--chunk", type=int, default=1000, help="env steps per jitted call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--program", default="auto")
    parser.add_argument("--name", default="bench_width_align", help="report file name")
    parser.add_argument("--out", type=Path, default=Path("results"))
    parser.add_argument("--one", type=Path, help=argparse.SUPPRESS)  # a child: its row's file
    args = parser.parse_args(argv)
    try:
        for align in args.align:
            _check(align)
    except ValueError as e:
        parser.error(str(e))
    if args.one is not None:
        atomic_write_json(args.one, one(args.align[0], args))
        return {}
    rows, options = [], list(argv if argv is not None else sys.argv[1:])
    with tempfile.TemporaryDirectory() as tmp:
        for i, align in enumerate(args.align):
            path = Path(tmp) / f"{i}.json"
            child = [sys.executable, __file__, *options, "--align", str(align), "--one", str(path)]
            subprocess.run(child, check=True)
            rows.append(json.loads(path.read_text()))
            print(f"align {align}: {rows[-1]['agent_steps_per_s']:,.0f} agent env-steps/s",
                  flush=True)  # fmt: skip
    keys = ("preset", "agent", "agents", "precision", "chunk", "repeats", "program")
    result = dict(**measure.provenance(), **{k: getattr(args, k) for k in keys}, rows=rows)
    command = writing.command_line("experiments/bench_width_align.py", options)
    atomic_write_json(args.out / f"{args.name}.json", {**result, "command": command})
    writing.write_markdown(args.out / f"{args.name}.md", report(result, command), echo=True)
    return result


if __name__ == "__main__":
    main()
