"""PNG pictures of images: the pixels alone in a colour map (numpy and zlib), or a figure with axes in metres
and a colour bar (matplotlib's object interface: no screen, no pyplot state)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: matplotlib's "inferno" colour map as it turns values into bytes (``colormaps["inferno"](i, bytes=True)``),
#: [256, 3] uint8 RGB, black to pale yellow: the figure's colours without importing matplotlib.
INFERNO_RGB = np.frombuffer(bytes.fromhex(
    "00000300000400000601000701010901010b02010e02021003021204031404031605041806041b07051d08061f090621"
    "0a07230b07260d08280e082a0f092d10092f120a32130a34140b36160b39170b3b190b3e1a0b401c0c431d0c451f0c47"
    "200c4a220b4c240b4e260b50270b52290b542b0a562d0a582e0a5a300a5c32095d34095f3509603709613909623b0964"
    "3c09653e0966400966410967430a68450a69460a69480b6a4a0b6a4b0c6b4d0c6b4f0d6c500d6c520e6c530e6d550f6d"
    "570f6d58106d5a116d5b116e5d126e5f126e60136e62146e63146e65156e66156e68166e6a176e6b176e6d186e6e186e"
    "70196e72196d731a6d751b6d761b6d781c6d7a1c6d7b1d6c7d1d6c7e1e6c801f6b811f6b83206b85206a86216a88216a"
    "8922698b22698d23698e24689024689125679325679526669626669827659928649b28649c29639e2963a02a62a12b61"
    "a32b61a42c60a62c5fa72d5fa92e5eab2e5dac2f5cae305baf315bb1315ab23259b43358b53357b73456b83556ba3655"
    "bb3754bd3753be3852bf3951c13a50c23b4fc43c4ec53d4dc73e4cc83e4bc93f4acb4049cc4148cd4247cf4446d04544"
    "d14643d24742d44841d54940d64a3fd74b3ed94d3dda4e3bdb4f3adc5039dd5238de5337df5436e05634e25733e35832"
    "e45a31e55b30e65c2ee65e2de75f2ce8612be9622aea6428eb6527ec6726ed6825ed6a23ee6c22ef6d21f06f1ff0701e"
    "f1721df2741cf2751af37719f37918f47a16f57c15f57e14f68012f68111f78310f7850ef8870df8880cf88a0bf98c09"
    "f98e08f99008fa9107fa9306fa9506fa9706fb9906fb9b06fb9d06fb9e07fba007fba208fba40afba60bfba80dfbaa0e"
    "fbac10fbae12fbb014fbb116fbb318fbb51afbb71cfbb91efabb21fabd23fabf25fac128f9c32af9c52cf9c72ff8c931"
    "f8cb34f8cd37f7cf3af7d13cf6d33ff6d542f5d745f5d948f4db4bf4dc4ff3de52f3e056f3e259f2e45df2e660f1e864"
    "f1e968f1eb6cf1ed70f1ee74f1f079f1f27df2f381f2f485f3f689f4f78df5f891f6fa95f7fb99f9fc9dfafda0fcfea4"
), np.uint8).reshape(256, 3)
#: The pixel picture is enlarged by a whole factor until its longer side has at least this many pixels.
MIN_PICTURE_SIDE_PX = 512

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
        db = magnitude_db(image)
        if db.shape != (self.y_m.size, self.x_m.size):
            raise ValueError(f"image of shape {db.shape} on a picture of the grid {self.y_m.size} x {self.x_m.size}")
        from PIL import Image

        self.artist.set_data(db)
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


def magnitude_db(image: np.ndarray) -> np.ndarray:
    """|image| [ny, nx] (a volume [nz, ny, nx]: its largest magnitude over height) in dB, its peak 0 dB."""
    mag = np.abs(image)
    if mag.ndim == 3:  # the largest magnitude over height (numpy's max of complex values orders by real part)
        mag = mag.max(axis=0)
    return 20 * np.log10(mag / mag.max() + 1e-12)


def colour_mapped(db: np.ndarray, dynamic_range_db: float = 40.0) -> np.ndarray:
    """Values in dB [ny, nx] as RGB bytes [ny, nx, 3] of ``INFERNO_RGB``: 0 dB and above the last colour,
    ``-dynamic_range_db`` and below the first; the steps of matplotlib's ``Normalize`` and colour map, in
    the values' own precision, so each value takes the colour matplotlib gives it."""
    db = np.asarray(db)
    scaled = (db - db.dtype.type(-dynamic_range_db)) / db.dtype.type(dynamic_range_db)
    scaled = scaled * len(INFERNO_RGB)
    index = np.zeros(scaled.shape, np.intp)  # below the range, and NaN (an image of zeros): the first colour
    inside = scaled >= 0
    index[inside] = np.minimum(scaled[inside], len(INFERNO_RGB) - 1).astype(np.intp)
    return INFERNO_RGB[index]


def save_image_pixels_png(path: str | Path, image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, *,
                          title: str = "", dynamic_range_db: float = 40.0) -> Path:
    """Save |image| in dB (peak 0 dB, ``dynamic_range_db`` down to black) as its pixels alone: one square
    of ``scale`` x ``scale`` screen pixels per grid point, x to the right and y up, in the colours of the
    figure (``ImagePicture``); what the figure's axes and colour bar said is in the file's text (its title
    and description)."""
    x_m, y_m = np.asarray(x_m), np.asarray(y_m)
    db = magnitude_db(image)
    if db.shape != (y_m.size, x_m.size):
        raise ValueError(f"image of shape {db.shape} on a picture of the grid {y_m.size} x {x_m.size}")
    scale = max(1, math.ceil(MIN_PICTURE_SIDE_PX / max(db.shape)))
    rgb = colour_mapped(db[::-1], dynamic_range_db)  # the picture's top row is the grid's last y
    if scale > 1:
        rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    description = (f"|image| in dB, inferno colour map from -{dynamic_range_db:g} dB (black) to 0 dB (the peak, "
                   f"pale yellow); x {x_m[0]:g} to {x_m[-1]:g} m left to right, y {y_m[0]:g} to {y_m[-1]:g} m "
                   f"bottom to top, {scale} x {scale} screen pixels per grid point")
    from imaging.io.png import write_png

    return write_png(path, rgb, text={"Title": title, "Description": description, "Software": "sarbot"}, dpi=DPI)


def save_image_png(path: str | Path, image: np.ndarray, x_m: np.ndarray, y_m: np.ndarray, *, title: str = "",
                   dynamic_range_db: float = 40.0, marks: dict[str, tuple[float, float]] | None = None) -> Path:
    """Save |image| in dB (peak 0 dB, ``dynamic_range_db`` down to black) with world-frame axes."""
    return ImagePicture(x_m, y_m, dynamic_range_db=dynamic_range_db, marks=marks).save(path, image, title=title)
