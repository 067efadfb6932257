"""PNG pictures of images (matplotlib, no screen needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def save_image_png(path: str | Path, image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, *, title: str = "",
                   dynamic_range_db: float = 40.0, marks: dict[str, tuple[float, float]] | None = None) -> Path:
    """Save |image| in dB (peak 0 dB, ``dynamic_range_db`` down to black) with world-frame axes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mag = np.abs(image if image.ndim == 2 else image.max(axis=0))
    db = 20 * np.log10(mag / mag.max() + 1e-12)
    aspect = (y_m[-1] - y_m[0]) / max(x_m[-1] - x_m[0], 1e-9)
    fig, ax = plt.subplots(figsize=(9, max(2.5, min(9, 9 * aspect + 1.2))))
    extent = (x_m[0], x_m[-1], y_m[0], y_m[-1])
    im = ax.imshow(db, origin="lower", extent=extent, cmap="inferno", vmin=-dynamic_range_db, vmax=0, aspect="equal",
                   interpolation="nearest")
    for label, (mx, my) in (marks or {}).items():
        ax.plot(mx, my, "c+", ms=10)
        ax.annotate(label, (mx, my), color="c", xytext=(4, 4), textcoords="offset points", fontsize=8)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label="dB", shrink=0.8)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
