"""PNG pictures of images (matplotlib's object interface: no screen, no pyplot state)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Dots per inch of the pictures.
DPI = 110
#: Stands in for the title while the figure is laid out: one line of text is as tall whatever it says.
_TITLE_PLACEHOLDER = "Ag"


class ImagePicture:
    """The figure of an image on the grid ``x_m``, ``y_m``: axes, labels, colour bar and layout.

    Everything but the pixels is known from the grid, so the figure can be built and laid out while the
    image is still being formed (in a thread beside the backprojection, whose kernel releases the GIL);
    :meth:`save` then only draws it. Used from one thread at a time.
    """

    def __init__(self, x_m: np.ndarray, y_m: np.ndarray, *, dynamic_range_db: float = 40.0,
                 marks: dict[str, tuple[float, float]] | None = None):
        from matplotlib.figure import Figure

        self.x_m, self.y_m = np.asarray(x_m), np.asarray(y_m)
        self.dynamic_range_db = dynamic_range_db
        aspect = (self.y_m[-1] - self.y_m[0]) / max(self.x_m[-1] - self.x_m[0], 1e-9)
        self.figure = Figure(figsize=(9, max(2.5, min(9, 9 * aspect + 1.2))))
        ax = self.axes = self.figure.subplots()
        extent = (self.x_m[0], self.x_m[-1], self.y_m[0], self.y_m[-1])
        self.artist = ax.imshow(np.zeros((1, 1)), origin="lower", extent=extent, cmap="inferno",
                                vmin=-dynamic_range_db, vmax=0, aspect="equal", interpolation="nearest")
        #: drawn over the pixels when saving: the marks, the frame (on the image's edge) and the title
        self.overlays = []
        for label, (mx, my) in (marks or {}).items():
            self.overlays += ax.plot(mx, my, "c+", ms=10)
            self.overlays.append(ax.annotate(label, (mx, my), color="c", xytext=(4, 4), textcoords="offset points", fontsize=8))
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(_TITLE_PLACEHOLDER)
        self.figure.colorbar(self.artist, ax=ax, label="dB", shrink=0.8)
        self.figure.tight_layout()
        # Render everything but the pixels and the title now, so that saving draws only those onto a copy
        # of it (matplotlib's blitting): the axes' ticks and labels are most of a figure's drawing time.
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        self.canvas = FigureCanvasAgg(self.figure)
        self.figure.set_dpi(DPI)
        self.overlays += [*ax.spines.values(), ax.title]
        for artist in [self.artist, *self.overlays]:
            artist.set_animated(True)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(self.figure.bbox)

    def save(self, path: str | Path, image: np.ndarray, *, title: str = "") -> Path:
        """Draw |image| [ny, nx] (a volume [nz, ny, nx]: its maximum over height) in dB, peak 0 dB, down to
        ``dynamic_range_db`` black, and write the PNG."""
        mag = np.abs(image)
        if mag.ndim == 3:  # the largest magnitude over height (numpy's max of complex values orders by real part)
            mag = mag.max(axis=0)
        if mag.shape != (self.y_m.size, self.x_m.size):
            raise ValueError(f"image of shape {mag.shape} on a picture of the grid {self.y_m.size} x {self.x_m.size}")
        from PIL import Image

        self.artist.set_data(20 * np.log10(mag / mag.max() + 1e-12))
        self.axes.set_title(title)
        self.canvas.restore_region(self.background)
        for artist in [self.artist, *self.overlays]:
            self.axes.draw_artist(artist)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        # Opaque, so RGB; and zlib's fastest level: half the encoding time of its default for a file 5 % larger.
        rgba = Image.frombuffer("RGBA", self.canvas.get_width_height(), self.canvas.buffer_rgba(), "raw", "RGBA", 0, 1)
        rgba.convert("RGB").save(path, format="png", dpi=(DPI, DPI), compress_level=1)
        return path


def save_image_png(path: str | Path, image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, *, title: str = "",
                   dynamic_range_db: float = 40.0, marks: dict[str, tuple[float, float]] | None = None) -> Path:
    """Save |image| in dB (peak 0 dB, ``dynamic_range_db`` down to black) with world-frame axes."""
    return ImagePicture(x_m, y_m, dynamic_range_db=dynamic_range_db, marks=marks).save(path, image, title=title)
