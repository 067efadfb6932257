"""The PNG picture of an image: laid out and drawn but for the pixels before the image exists, then only
those drawn over a copy; the result is what a full draw of the same figure gives."""

import matplotlib.image as mpimg
import numpy as np
import pytest

from imaging.plot import DPI, ImagePicture, save_image_png


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
