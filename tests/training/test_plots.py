"""Figures are written as palette PNGs: the same picture in fewer bytes."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

from advisor_jax.training.plots import palette_png, save_png  # noqa: E402


def _figure():
    fig, ax = plt.subplots(figsize=(4, 3))
    x = np.linspace(0, 1, 200)
    for k in range(5):
        ax.plot(x, np.sin(6 * x + k), label=f"line {k}")
        ax.fill_between(x, np.sin(6 * x + k) - 0.1, np.sin(6 * x + k) + 0.1, alpha=0.2)
    ax.legend()
    return fig


def test_save_png_writes_a_smaller_palette_image_of_the_same_picture(tmp_path):
    fig = _figure()
    raw = io.BytesIO()
    fig.savefig(raw, dpi=90, format="png")
    path = save_png(fig, tmp_path / "f.png", dpi=90)
    written = Image.open(path)
    assert written.mode == "P" and len(path.read_bytes()) < len(raw.getvalue())
    original = np.asarray(Image.open(io.BytesIO(raw.getvalue())).convert("RGB"), float)
    assert written.size == original.shape[1::-1]
    # Antialiasing shades merge; no pixel moves far from its colour.
    diff = np.abs(np.asarray(written.convert("RGB"), float) - original)
    assert diff.mean() < 2.0 and np.percentile(diff, 99.9) < 40


def test_palette_png_keeps_a_file_it_cannot_shrink():
    tiny = io.BytesIO()
    Image.new("P", (2, 2)).save(tiny, format="PNG", optimize=True)
    assert palette_png(tiny.getvalue()) == tiny.getvalue()
