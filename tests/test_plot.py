"""The PNG pictures of an image. The figure: laid out and drawn but for the pixels before the image exists,
then only those drawn over a copy; the result is what a full draw of the same figure gives. The pixels
alone: written by numpy and zlib, read back by Pillow as the same pixels, in matplotlib's colours."""

import matplotlib.image as mpimg
import numpy as np
import pytest

from imaging.io.png import encode_png, write_png
from imaging.plot import DPI, INFERNO_RGB, ImagePicture, colour_mapped, save_image_pixels_png, save_image_png


def full_draw(picture: ImagePicture, path, image, title):
    """The same figure drawn the ordinary way: every artist, in matplotlib's order."""
    for artist in [picture.artist, *picture.overlays]:
        artist.set_animated(False)
    picture.artist.set_data(20 * np.log10(np.abs(image) / np.abs(image).max() + 1e-12))
    picture.axes.set_title(title)
    picture.figure.savefig(path, dpi=DPI)


@pytest.mark.parametrize("marks", [None, {"rod": (0.0, 2.0), "reflector": (0.3, 1.8)}])
def test_a_picture_drawn_over_its_prepared_figure_equals_a_full_draw(tmp_path, marks):
    rng = np.random.default_rng(0)
    x, y = np.linspace(-0.5, 0.5, 101), np.linspace(1.5, 2.5, 121)
    image = rng.standard_normal((121, 101)) + 1j * rng.standard_normal((121, 101))
    picture = ImagePicture(x, y, marks=marks)
    picture.save(tmp_path / "fast.png", image, title="left_front frames 0:16 (tdbp-linear)")
    again = picture.save(tmp_path / "again.png", 2 * image[::-1], title="another")  # a picture saves more than once
    full_draw(ImagePicture(x, y, marks=marks), tmp_path / "full.png", image, "left_front frames 0:16 (tdbp-linear)")
    fast, full = mpimg.imread(tmp_path / "fast.png"), mpimg.imread(tmp_path / "full.png")
    assert np.all(full[..., 3] == 1)  # opaque, which is why the picture is written as RGB
    full = full[..., :3]
    assert fast.shape == full.shape and fast.shape[1] == round(9 * DPI)
    np.testing.assert_allclose(fast, full, atol=2 / 255)
    assert np.abs(mpimg.imread(again) - fast).max() > 0.5  # the other image and title were drawn


def test_a_volume_is_shown_as_its_largest_magnitude_over_height(tmp_path):
    x, y = np.linspace(0, 1, 40), np.linspace(0, 1, 30)
    volume = np.zeros((2, 30, 40), complex)
    volume[0, 10, 10] = 1.0  # the larger real part
    volume[1, 10, 10] = 0.1 + 5j  # the larger magnitude: numpy's max of complex values would pick the other
    volume[1, 20, 30] = 2.0
    save_image_png(tmp_path / "vol.png", volume, x, y, dynamic_range_db=40.0)
    picture = ImagePicture(x, y)
    picture.save(tmp_path / "plane.png", np.abs(volume).max(axis=0))
    np.testing.assert_array_equal(mpimg.imread(tmp_path / "vol.png"), mpimg.imread(tmp_path / "plane.png"))
    with pytest.raises(ValueError, match="grid 30 x 40"):
        picture.save(tmp_path / "wrong.png", np.ones((40, 30)))


def test_a_png_written_without_a_library_reads_back_as_the_same_pixels(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    path = write_png(tmp_path / "sub" / "p.png", rgb, text={"Title": "left_front frames 0:16", "Software": "sarbot"},
                     dpi=DPI)
    with Image.open(path) as png:
        assert png.mode == "RGB" and png.size == (53, 37)
        np.testing.assert_array_equal(np.asarray(png), rgb)
        assert png.text == {"Title": "left_front frames 0:16", "Software": "sarbot"}
        assert png.info["dpi"] == pytest.approx((DPI, DPI), abs=0.01)
    with pytest.raises(ValueError, match="uint8 pixels"):
        encode_png(rgb.astype(np.uint16))


def test_the_colour_map_is_matplotlibs_inferno():
    import matplotlib

    np.testing.assert_array_equal(INFERNO_RGB, matplotlib.colormaps["inferno"](np.arange(256), bytes=True)[:, :3])


def test_the_pixel_picture_has_matplotlibs_colours_for_the_same_image(tmp_path):
    """Against matplotlib drawing the same dB values with the figure's colour map and range, one pixel per
    grid point (``imsave``): the same colour for every pixel (at most one step of the colour map apart, where
    a value falls on a step's edge in another rounding); and each grid point a square of screen pixels."""
    from PIL import Image

    rng = np.random.default_rng(2)
    x, y = np.linspace(-0.5, 0.5, 101), np.linspace(1.5, 2.5, 121)
    image = (rng.standard_normal((121, 101)) + 1j * rng.standard_normal((121, 101))).astype(np.complex64)
    image[60, 50] = 30  # a peak, so that the picture spans the whole 40 dB
    path = save_image_pixels_png(tmp_path / "px.png", image, x, y, title="t")
    db = 20 * np.log10(np.abs(image) / np.abs(image).max() + 1e-12)
    mpimg.imsave(tmp_path / "mpl.png", db, cmap="inferno", vmin=-40, vmax=0, origin="lower")
    with Image.open(path) as png, Image.open(tmp_path / "mpl.png") as ref:
        scale = 5  # 121 rows: 5 x 5 screen pixels per grid point give 605 >= 512
        assert png.size == (101 * scale, 121 * scale) and png.text["Title"] == "t"
        assert "-40 dB" in png.text["Description"] and "y 1.5 to 2.5 m" in png.text["Description"]
        ours = np.asarray(png)[::scale, ::scale].astype(int)
        np.testing.assert_array_equal(np.asarray(png)[scale - 1::scale, scale - 1::scale], ours[:, :])
        theirs = np.asarray(ref.convert("RGB")).astype(int)
    assert ours.shape == theirs.shape
    assert np.mean(np.all(ours == theirs, axis=-1)) > 0.999
    assert np.abs(ours - theirs).max() <= np.abs(np.diff(INFERNO_RGB.astype(int), axis=0)).max()


def test_the_colour_map_ends_and_an_empty_image():
    db = np.array([[0.0, 5.0, -40.0, -41.0, -20.0, np.nan]], np.float32)
    rgb = colour_mapped(db, 40.0)
    np.testing.assert_array_equal(rgb[0, :4], INFERNO_RGB[[255, 255, 0, 0]])
    np.testing.assert_array_equal(rgb[0, 4], INFERNO_RGB[128])
    np.testing.assert_array_equal(rgb[0, 5], INFERNO_RGB[0])  # an image of zeros: black, not an error


def test_a_volumes_pixel_picture_is_its_largest_magnitude_over_height(tmp_path):
    from PIL import Image

    x, y = np.linspace(0, 1, 40), np.linspace(0, 1, 30)
    volume = np.zeros((2, 30, 40), complex)
    volume[0, 10, 10] = 1.0
    volume[1, 10, 10] = 0.1 + 5j
    volume[1, 20, 30] = 2.0
    save_image_pixels_png(tmp_path / "vol.png", volume, x, y)
    save_image_pixels_png(tmp_path / "plane.png", np.abs(volume).max(axis=0), x, y)
    with Image.open(tmp_path / "vol.png") as a, Image.open(tmp_path / "plane.png") as b:
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    with pytest.raises(ValueError, match="grid 30 x 40"):
        save_image_pixels_png(tmp_path / "wrong.png", np.ones((40, 30)), x, y)
