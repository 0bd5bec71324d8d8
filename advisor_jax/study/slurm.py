"""A study on a cluster: a Slurm job array whose task i trains piece i (``advisor-jax sweep
STUDY --out DIR --piece i``); resubmitting it resumes (finished pieces are skipped)."""

from __future__ import annotations

import os
import shlex
from pathlib import Path

from advisor_jax.fileio import atomic_write_text
from advisor_jax.study.plan import Plan
from advisor_jax.study.spec import Study
from advisor_jax.study.sweep import piece_command


def slurm_script(study: Study, out: Path, plan: Plan, extra: list[str]) -> str:
    """A Slurm job array whose task i trains piece i (resubmit it to resume)."""
    longest = max((p.seconds or 0.0) for p in plan.pieces)
    hours = max(1.0, 1.5 * longest / 3600)  # room for a slower device than planned
    h, m = int(hours), int(60 * (hours - int(hours)))
    lines = [
        "#!/bin/bash",
        f"#SBATCH --job-name={study.name}",
        f"#SBATCH --array=0-{len(plan.pieces) - 1}",
        "#SBATCH --gres=gpu:1",
        "#SBATCH --cpus-per-task=4",
        f"#SBATCH --time={h:02d}:{m:02d}:00",
        f"#SBATCH --output={out.resolve()}/logs/slurm-%A_%a.log",
        *(f"#SBATCH --{option.lstrip('-')}" for option in extra),
        "",
        f"# {study.name}: {len(plan.pieces)} pieces ({plan.explained[0]}).",
        "# Task i trains piece i into the same directory; a finished piece is skipped and an",
        "# interrupted one resumes from its checkpoint, so the same script can be resubmitted.",
        "set -euo pipefail",
        f"cd {shlex.quote(str(Path.cwd()))}  # where the study and --out paths start",
        piece_command(study, out, "$SLURM_ARRAY_TASK_ID", plan).replace(
            "'$SLURM_ARRAY_TASK_ID'", '"$SLURM_ARRAY_TASK_ID"'
        ),
    ]
    return "\n".join(lines) + "\n"


def write_slurm(path: Path, study: Study, out: Path, plan: Plan, extra: list[str]) -> None:
    (out / "logs").mkdir(parents=True, exist_ok=True)  # Slurm does not make --output's folder
    atomic_write_text(path, slurm_script(study, out, plan, extra))
    os.chmod(path, 0o755)
