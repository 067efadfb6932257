"""`sarbot experiment paper --quick`: the reference study's numbers, reproduced (a reduced set of apertures,
phases and amplitudes; the full run writes docs/results/paper/)."""

import json
import subprocess
import sys

import pytest


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper")
    res = subprocess.run([sys.executable, "-m", "acquisition.cli", "experiment", "paper", "--quick", "-o", str(out)],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    for figure in ("range_profiles", "cross_range_width_truth", "cross_range_profiles_truth", "vibration",
                   "integration_gain", "rio_aperture", "cross_range_width_rio", "failure", "autofocus_aperture",
                   "autofocus_vibration", "autofocus_integration_gain", "autofocus_breakdown", "autofocus_failure"):
        assert (out / f"{figure}.png").stat().st_size > 5000, figure
    assert "## 6. Where methods fail" in (out / "report.md").read_text()
    assert "## 7. With autofocus" in (out / "report.md").read_text()
    return json.loads((out / "report.json").read_text())


def test_range_and_cross_range_widths_follow_theory(report):
    for row in report["range"]["rows"]:
        assert row["ratio"] == pytest.approx(1.0, abs=0.03), row
    for case, res in report["cross_range"].items():
        for row in res["rows"]:
            assert row["ratio"] == pytest.approx(1.0, abs=0.06), (case, row)


def test_sections_1_and_2_again_with_autofocus_change_nothing_on_an_error_free_track(report):
    """Every study again with autofocus (issue 13): where the track has no error the range and cross-range
    images keep their widths and peaks."""
    rows = report["range"]["rows"] + [row for res in report["cross_range"].values() for row in res["rows"]]
    for row in rows:
        af = row["autofocus"]
        assert af["peak_change_db"] > -0.1, row
        assert abs(af["range_width_change"]) < 0.02 and abs(af["cross_range_width_change"]) < 0.03, row


def test_vibration_is_inferred_from_its_side_lobes(report):
    v = report["vibration"]
    assert v["sidelobe_offset_m"] == pytest.approx(0.04, rel=0.03)
    assert v["sidelobe_level_db"] == pytest.approx(-4.3, abs=0.3)
    assert v["f_vib_hz"] == pytest.approx(v["scene_f_vib_hz"], rel=0.03)
    assert v["a_vib_m"] == pytest.approx(v["scene_a_vib_m"], rel=0.05)
    assert v["resimulated_sidelobe_level_db"] == pytest.approx(v["sidelobe_level_db"], abs=0.5)


def test_integration_gain_lies_between_the_limits(report):
    assert 0.5 < report["integration_gain"]["alpha"] < 1.05


def test_usable_aperture_shrinks_with_trajectory_error_as_the_bend_limit_says(report):
    rows = report["failure"]["acceleration"]
    usable = [r["usable_aperture_m"] for r in rows]
    assert usable == sorted(usable, reverse=True) and usable[0] > usable[-1]
    for r in rows[1:]:
        # Measured on a coarse aperture grid: never longer than the lambda/8 bend allows (plus one grid step).
        assert r["usable_aperture_m"] <= 1.6 * r["theory_m"], r


def test_rio_trajectory_images_like_the_truth_over_short_apertures(report):
    for case, res in report["rio"]["widths_rio"].items():
        assert res["rows"][0]["ratio"] < 1.1, case


def test_autofocus_takes_the_usable_aperture_past_a_metre(report):
    """The paper's vibration on the odometry's trajectory: plain, the side lobes end the aperture at a few
    centimetres; autofocused, both targets stay usable to 1 m at 0.4 and 1.0 m/s."""
    for case, res in report["autofocus"]["usable"].items():
        assert res["usable_plain_m"] < 0.34, case
        assert res["usable_autofocus_m"] >= 1.0, case
        # With a Taylor taper over the aperture the focused side lobes go below -13 dB at every aperture
        # (a uniform aperture cannot: its sinc's are -13.3 dB), the width within 10 % of the taper's theory.
        assert res["usable_autofocus_taylor_m"] >= 1.0, case
        for row in res["rows"]:
            assert row["autofocus_taylor"]["pslr_db"] <= -13.0, (case, row)
            assert row["plain"]["pslr_db"] > -10.0 or row["aperture_m"] < 0.1, (case, row)
        long = res["rows"][-1]["autofocus"]
        assert long["pslr_db"] < -11.0 and long["ratio"] < 1.06, (case, long)


def test_vibration_read_off_autofocus_within_two_percent(report):
    for method in ("pga", "entropy"):
        v = report["autofocus"]["vibration"][method]
        assert abs(v["frequency_error"]) < 0.02 and abs(v["amplitude_error"]) < 0.02, (method, v)


def test_autofocus_restores_integration_gain_and_never_blurs(report):
    g = report["autofocus"]["integration_gain"]
    assert g["autofocus"]["alpha"] > g["plain"]["alpha"] + 0.1
    assert g["autofocus"]["alpha"] >= 0.95  # the goal (the full run: 0.98 over 1-32 frames)
    # The exactly known track is coherent: with the peak measured finer than the image's pixels, N^1 (it read
    # 0.92 on the 4 mm pixels, which miss a 6 mm peak by up to 1.7 dB).
    assert 0.95 < g["known"]["alpha"] < 1.15
    b = report["autofocus"]["breakdown"]
    for row in b["snr"] + b["scatterers"]:
        assert row["entropy_focused"] <= row["entropy_plain"], row
    assert not b["scatterers"][0]["applied"]  # diffuse clutter only: nothing to focus on
    assert not b["snr"][0]["applied"] and b["snr"][-1]["applied"]


def test_autofocus_lifts_the_limits_of_section_6(report):
    """A track bent by an uncompensated acceleration limits the plain image to v sqrt(lambda / a); autofocus
    takes 10 mm/s^2 to at least 1 m (four times that limit). Vibration of half a millimetre, which ends the
    plain aperture at a few centimetres, leaves 1 m usable."""
    f = report["autofocus"]["failure"]
    acc = {round(r["accel_mps2"], 4): r for r in f["acceleration"]}
    assert acc[0.01]["usable_autofocus_m"] >= 1.0 > 3 * acc[0.01]["limit_without_m"]
    plain_vib = {round(r["amplitude_m"], 5): r["usable_aperture_m"] for r in report["failure"]["vibration"]}
    for r in f["vibration"]:
        assert r["usable_autofocus_m"] >= 1.0, r
    assert plain_vib[0.0005] < 0.2
